"""``python -m jaxsim report``: see ``jaxsim._report``."""

from .._report import run

__all__ = ["run"]
