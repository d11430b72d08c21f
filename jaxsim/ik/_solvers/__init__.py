"""The IK solvers: FABRIK, CCD, Levenberg–Marquardt and the two-bone limb, their settings, and the masked sweep loop they share."""
