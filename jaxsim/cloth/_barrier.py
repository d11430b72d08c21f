"""IPC's log barrier (Li et al. 2020, §4): the law shared by the colliders' contact and
self-contact, with its slope and an elementwise derivative helper."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def barrier(d, dhat):
    """IPC's ``b(d)`` (m^2): ``-(d - dhat)^2 log(d / dhat)`` on ``(0, dhat)``, 0 beyond,
    ``+inf`` at ``d <= 0``; NaN-free gradient everywhere (double ``where``)."""
    active = (d > 0) & (d < dhat)
    ds = jnp.where(active, d, dhat)
    val = -(ds - dhat) ** 2 * jnp.log(ds / dhat)
    return jnp.where(d > 0, jnp.where(active, val, 0.0), jnp.inf)


def barrier_slope(d, dhat):
    """``b'(d)`` (m), ``<= 0``: ``-(d - dhat)(2 log(d/dhat) + (d - dhat)/d)`` on ``(0, dhat)``."""
    active = (d > 0) & (d < dhat)
    ds = jnp.where(active, d, dhat)
    return jnp.where(active, -(ds - dhat) * (2.0 * jnp.log(ds / dhat) + (ds - dhat) / ds), 0.0)


def _d(f, order):
    """Elementwise ``order``-th derivative of a scalar function ``f(x, c)`` in ``x``."""
    for _ in range(order):
        f = jax.grad(f)
    return jnp.vectorize(f, excluded={1})
