"""Frozen pytree dataclasses: arrays are data leaves, sizes and flags are static."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

import jax
import numpy as np

T = TypeVar("T")


def static_field(**kwargs: Any) -> Any:
    """A dataclass field that is pytree metadata (hashable, part of the jit cache key)."""
    return dataclasses.field(metadata={"static": True}, **kwargs)


def pytree_dataclass(cls: type[T]) -> type[T]:
    """Make ``cls`` a frozen dataclass registered with ``jax.tree_util.register_dataclass``."""
    cls = dataclasses.dataclass(frozen=True)(cls)
    return jax.tree_util.register_dataclass(cls)


def is_concrete(*leaves: Any) -> bool:
    """True when every leaf is a concrete array-like value (not a tracer or a pytree sentinel).

    ``register_dataclass`` rebuilds nodes through ``__init__`` with tracers or placeholder
    objects as leaves, so constructors only validate when this returns True.
    """
    for x in leaves:
        if isinstance(x, jax.core.Tracer):
            return False
        if not isinstance(x, (np.ndarray, np.generic, jax.Array, list, tuple, float, int)):
            return False
    return True


def in_reverse_mode(*trees: Any) -> bool:
    """True when a leaf of ``trees`` is being linearised (``jax.grad``, ``jax.vjp``,
    ``jax.linearize``), where a ``lax.while_loop`` cannot be differentiated.  False when
    it cannot tell (a ``jit`` between the caller's ``grad`` and here hides it)."""
    try:
        from jax._src.interpreters.ad import LinearizeTracer
    except ImportError:  # pragma: no cover - a JAX without the direct-linearize trace
        return False
    return any(isinstance(x, LinearizeTracer) for x in jax.tree_util.tree_leaves(trees))
