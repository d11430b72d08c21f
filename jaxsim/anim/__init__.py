"""Character animation on real rigs: BVH clips in and out, and their poses by batched FK."""

from ._attach import body_capsules, bone_local, bone_points, resample
from ._bvh import CHANNELS, CMU_SCALE, CMU_WALK, cmu_walk, read_bvh, write_bvh
from ._contacts import contact_spans, foot_contacts, foot_slide
from ._lock import LockInfo, lock_feet
from ._retarget import Retargeted, retarget
from ._euler import ORDERS, continuous_euler, euler_to_quat, quat_to_euler
from ._motion import Motion, global_rotations, positions

__all__ = ["Motion", "read_bvh", "write_bvh", "positions", "global_rotations", "euler_to_quat", "quat_to_euler",
           "continuous_euler", "ORDERS", "CHANNELS", "cmu_walk", "CMU_WALK", "CMU_SCALE", "foot_contacts", "foot_slide", "contact_spans", "lock_feet", "LockInfo", "retarget", "Retargeted",
           "resample", "bone_points", "bone_local", "body_capsules"]
