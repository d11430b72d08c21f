"""The IK model: skeletons (a chain is one), rigs, joint limits, forward kinematics and the stacked pose."""
