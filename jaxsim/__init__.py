"""jaxsim: differentiable character-animation physics in JAX (IK chains and mass-spring cloth)."""

from . import cloth, ik
from ._host_memory import retain_host_memory

__version__ = "0.1.0"
__all__ = ["ik", "cloth", "retain_host_memory"]
