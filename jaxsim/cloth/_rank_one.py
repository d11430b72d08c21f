"""Hessian blocks of the Gauss–Newton form ``c g g^T`` on small groups of particles.

Self-contact pairs (four particles, ``_self.terms``) and aerodynamic triangles (three,
``_model.aero``) add such blocks to the step's Hessian: rank one and PSD where ``c >= 0``.
PCG applies them as a matrix-free product, its preconditioner takes their diagonal
blocks, and the dense solve assembles them.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._dataclass import pytree_dataclass


@pytree_dataclass
class RankOne:
    """``sum_e c_e g_e g_e^T`` over groups ``e`` of ``k`` particles.

    Attributes:
      ids: ``(E, k)`` int32 particle ids.
      g: ``(E, 3k)`` each group's vector over its particles (0 on pins and unused slots).
      c: ``(E,)`` each group's weight (0 where no term acts).
    """

    ids: jax.Array
    g: jax.Array
    c: jax.Array

    def matvec(self, v):
        """``(N, 3) -> (N, 3)``: the blocks applied to ``v``."""
        E, k = self.ids.shape
        s = self.c * jnp.sum(self.g * v[self.ids].reshape(E, 3 * k), axis=1)
        return jnp.zeros_like(v).at[self.ids].add((s[:, None] * self.g).reshape(E, k, 3))

    def diagonal(self, N):
        """``(N, 3, 3)`` the blocks' 3x3 diagonal blocks summed per particle."""
        E, k = self.ids.shape
        g = self.g.reshape(E, k, 3)
        d = self.c[:, None, None, None] * g[:, :, :, None] * g[:, :, None, :]
        return jnp.zeros((N, 3, 3), self.g.dtype).at[self.ids].add(d)

    def dense(self, N):
        """``(3N, 3N)`` the blocks assembled."""
        E, k = self.ids.shape
        rows = (self.ids[:, :, None] * 3 + jnp.arange(3)).reshape(E, 3 * k)
        H = self.c[:, None, None] * self.g[:, :, None] * self.g[:, None, :]
        return jnp.zeros((3 * N, 3 * N), self.g.dtype).at[rows[:, :, None], rows[:, None, :]].add(H)


def combine(a: RankOne | None, b: RankOne | None) -> RankOne | None:
    """One :class:`RankOne` holding the groups of both (``None`` where both are); the
    smaller groups are padded with particle 0 and a zero vector."""
    if a is None or b is None:
        return a if b is None else b
    k = max(a.ids.shape[1], b.ids.shape[1])

    def pad(r: RankOne):
        extra = k - r.ids.shape[1]
        return (jnp.pad(r.ids, ((0, 0), (0, extra))), jnp.pad(r.g, ((0, 0), (0, 3 * extra))))

    (ia, ga), (ib, gb) = pad(a), pad(b)
    return RankOne(jnp.concatenate([ia, ib]), jnp.concatenate([ga, gb]), jnp.concatenate([a.c, b.c]))
