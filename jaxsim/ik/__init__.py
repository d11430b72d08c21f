"""Inverse kinematics on skeletons (a chain is one): forward kinematics, CCD, FABRIK and LM, with joint limits."""

from ._api import ccd, fabrik, solve
from ._fk import Pose, fk
from ._limits import Fixed, Free, Hinge, SwingTwist
from ._projection import limit_violation, project_limits
from ._result import IKResult
from ._rigs import HUMANOID_EFFECTORS, Chain, humanoid, lab_arm, straight_chain
from ._settings import CCD, FABRIK, LevenbergMarquardt
from ._skeleton import Skeleton
from ._track import jitter, rotation_change, track
from ._two_bone import TwoBone, two_bone

__all__ = ["Skeleton", "Chain", "Pose", "IKResult", "FABRIK", "CCD", "LevenbergMarquardt", "Free", "Fixed", "Hinge",
           "SwingTwist", "lab_arm", "straight_chain", "humanoid", "HUMANOID_EFFECTORS", "fk", "ccd", "fabrik", "solve",
           "track", "jitter", "rotation_change", "limit_violation", "project_limits", "two_bone", "TwoBone"]
