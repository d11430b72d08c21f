"""Cloth self-contact: IPC's barrier on point–triangle and edge–edge distances (Li et al.
2020), a fixed-capacity broadphase, and additive CCD (Li et al. 2021) for the line search."""
