"""Inverse kinematics for joint chains and skeletons: forward kinematics, CCD and FABRIK."""

from ._api import ccd, fabrik, solve
from ._chain import Chain, Pose, lab_arm, straight_chain
from ._fk import fk
from ._humanoid import HUMANOID_EFFECTORS, humanoid
from ._result import IKResult
from ._settings import CCD, FABRIK
from ._skeleton import Skeleton
from ._track import jitter, rotation_change, track

__all__ = ["Chain", "Skeleton", "Pose", "IKResult", "FABRIK", "CCD", "lab_arm", "straight_chain", "humanoid",
           "HUMANOID_EFFECTORS", "fk", "ccd", "fabrik", "solve", "track", "jitter", "rotation_change"]
