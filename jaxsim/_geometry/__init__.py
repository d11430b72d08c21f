"""Rotations and vectors as component tuples, shared by the IK solvers and skinned content.

``quat``: vector and unit-quaternion arithmetic on tuples of arrays (NaN-free at zero
vectors); ``horn``: the rotation best aligning weighted vector pairs (Horn 1987).
"""
