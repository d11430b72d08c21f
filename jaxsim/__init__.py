"""jaxsim: differentiable character-animation physics in JAX (IK chains and mass-spring cloth)."""

from . import cloth, ik

__version__ = "0.1.0"
__all__ = ["ik", "cloth"]
