"""Inverse kinematics for joint chains: forward kinematics, CCD and FABRIK."""

from ._chain import Chain, Pose, lab_arm, straight_chain
from ._fk import fk
from ._result import IKResult
from ._solve import ccd, fabrik, solve
from ._track import jitter, rotation_change, track

__all__ = ["Chain", "Pose", "IKResult", "lab_arm", "straight_chain", "fk", "ccd", "fabrik", "solve", "track", "jitter", "rotation_change"]
