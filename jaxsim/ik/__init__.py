"""Inverse kinematics for joint chains and skeletons: forward kinematics, CCD, FABRIK and LM, with joint limits."""

from ._api import ccd, fabrik, solve
from ._chain import Chain, Pose, lab_arm, straight_chain
from ._fk import fk
from ._humanoid import HUMANOID_EFFECTORS, humanoid
from ._limits import Fixed, Free, Hinge, SwingTwist, limit_violation, project_limits
from ._result import IKResult
from ._settings import CCD, FABRIK, LevenbergMarquardt
from ._skeleton import Skeleton
from ._track import jitter, rotation_change, track

__all__ = ["Chain", "Skeleton", "Pose", "IKResult", "FABRIK", "CCD", "LevenbergMarquardt", "Free", "Fixed", "Hinge",
           "SwingTwist", "lab_arm", "straight_chain", "humanoid", "HUMANOID_EFFECTORS", "fk", "ccd", "fabrik", "solve",
           "track", "jitter", "rotation_change", "limit_violation", "project_limits"]
