"""Inverse kinematics on skeletons (a chain is one): forward kinematics, CCD, FABRIK and LM, with joint limits."""

from ._driver.api import ccd, fabrik, solve
from ._model.fk import Pose, fk
from ._model.limits import Fixed, Free, Hinge, SwingTwist
from ._model.limit_checks import limit_violation, project_limits
from ._model.result import IKResult
from ._model.rigs import HUMANOID_EFFECTORS, Chain, humanoid, lab_arm, straight_chain
from ._solvers.settings import CCD, FABRIK, LevenbergMarquardt
from ._model.skeleton import Skeleton
from ._driver.track import jitter, rotation_change, track
from ._solvers.two_bone import TwoBone, two_bone

__all__ = ["Skeleton", "Chain", "Pose", "IKResult", "FABRIK", "CCD", "LevenbergMarquardt", "Free", "Fixed", "Hinge",
           "SwingTwist", "lab_arm", "straight_chain", "humanoid", "HUMANOID_EFFECTORS", "fk", "ccd", "fabrik", "solve",
           "track", "jitter", "rotation_change", "limit_violation", "project_limits", "two_bone", "TwoBone"]
