"""jaxsim: differentiable character-animation physics in JAX (IK chains and mass-spring cloth).

The subpackages are imported on first use (``jaxsim.ik``, ``jaxsim.cloth``, ...), so that
``import jaxsim`` and the command line's ``--help`` do not wait for JAX.
"""

import importlib

__version__ = "0.1.0"
__all__ = ["ik", "cloth", "anim", "curves", "viz", "optim", "retain_host_memory"]

_SUBPACKAGES = ("ik", "cloth", "anim", "curves", "viz", "optim")


def __getattr__(name):
    if name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)
    if name == "retain_host_memory":
        from ._host_memory import retain_host_memory

        return retain_host_memory
    raise AttributeError(f"module 'jaxsim' has no attribute {name!r}")


def __dir__():
    return sorted(__all__ + ["__version__"])
