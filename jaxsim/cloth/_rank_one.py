"""Hessian blocks of the Gauss–Newton form ``c g g^T`` on small groups of particles.

Self-contact pairs (four particles, ``_self.terms``) and aerodynamic triangles (three,
``_model.aero``) add such blocks to the step's Hessian: rank one and PSD where ``c >= 0``.
PCG applies them as a matrix-free product, its preconditioner takes their diagonal
blocks, and the dense solve assembles them.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

from .._dataclass import pytree_dataclass, static_field


@pytree_dataclass
class RankOne:
    """``sum_e c_e g_e g_e^T`` over groups ``e`` of ``k`` particles.

    Attributes:
      ids: ``(E, k)`` int32 particle ids.
      g: ``(E, 3k)`` each group's vector over its particles (0 on pins and unused slots).
      c: ``(E,)`` each group's weight (0 where no term acts).
      count: ``()`` int32, the groups at and after this row are zero (``c = 0``), or ``None``
        (any row may act).
      chunk: static; with ``count``, :meth:`matvec` applies the rows in chunks of this many
        (``E`` a multiple of it), only those before ``count``: a scene's self-contact slots
        are mostly empty, and PCG applies the blocks once per iteration.
    """

    ids: jax.Array
    g: jax.Array
    c: jax.Array
    count: jax.Array | None = None
    chunk: int = static_field(default=0)

    def matvec(self, v):
        """``(N, 3) -> (N, 3)``: the blocks applied to ``v``."""
        v = jnp.asarray(v)
        if self.count is None or not self.chunk:
            return _apply(self.ids, self.g, self.c, v, jnp.zeros_like(v))
        n = self.chunk

        def body(i, out):
            rows = lambda a: lax.dynamic_slice_in_dim(a, i * n, n)  # noqa: E731
            return _apply(rows(self.ids), rows(self.g), rows(self.c), v, out)

        return lax.fori_loop(0, (self.count + n - 1) // n, body, jnp.zeros_like(v))

    def diagonal(self, N):
        """``(N, 3, 3)`` the blocks' 3x3 diagonal blocks summed per particle (with ``count``,
        in chunks up to it, as :meth:`matvec`)."""
        out = jnp.zeros((N, 3, 3), self.g.dtype)
        if self.count is None or not self.chunk:
            return _diagonal(self.ids, self.g, self.c, out)
        n = self.chunk

        def body(i, out):
            rows = lambda a: lax.dynamic_slice_in_dim(a, i * n, n)  # noqa: E731
            return _diagonal(rows(self.ids), rows(self.g), rows(self.c), out)

        return lax.fori_loop(0, (self.count + n - 1) // n, body, out)

    def dense(self, N):
        """``(3N, 3N)`` the blocks assembled."""
        E, k = self.ids.shape
        rows = (self.ids[:, :, None] * 3 + jnp.arange(3)).reshape(E, 3 * k)
        H = self.c[:, None, None] * self.g[:, :, None] * self.g[:, None, :]
        return jnp.zeros((3 * N, 3 * N), self.g.dtype).at[rows[:, :, None], rows[:, None, :]].add(H)


def _diagonal(ids, g, c, out):
    """``out`` plus the groups' 3x3 diagonal blocks, summed per particle."""
    E, k = ids.shape
    g = g.reshape(E, k, 3)
    return out.at[ids].add(c[:, None, None, None] * g[:, :, :, None] * g[:, :, None, :])


def _apply(ids, g, c, v, out):
    """``out`` plus the groups ``ids (E, k)``, ``g (E, 3k)``, ``c (E,)`` applied to ``v (N, 3)``."""
    E, k = ids.shape
    s = c * jnp.sum(g * v[ids].reshape(E, 3 * k), axis=1)
    return out.at[ids].add((s[:, None] * g).reshape(E, k, 3))


def combine(a: RankOne | None, b: RankOne | None) -> RankOne | None:
    """One :class:`RankOne` holding the groups of both (``None`` where both are); the
    smaller groups are padded with particle 0 and a zero vector.  A compacted one
    (``count``) comes last, after the other's rows (padded to whole chunks), which all count."""
    if a is None or b is None:
        return a if b is None else b
    if a.count is not None:
        a, b = b, a
    if a.count is not None:
        raise ValueError("combine: both groups are compacted")
    k = max(a.ids.shape[1], b.ids.shape[1])
    lead = a.c.shape[0] if b.count is None else -(-a.c.shape[0] // b.chunk) * b.chunk

    def pad(x, rows, cols):
        return jnp.pad(x, ((0, rows),) + ((0, cols),) * (x.ndim - 1))

    extra = lead - a.c.shape[0]
    ids = jnp.concatenate([pad(a.ids, extra, k - a.ids.shape[1]), pad(b.ids, 0, k - b.ids.shape[1])])
    g = jnp.concatenate([pad(a.g, extra, 3 * (k - a.ids.shape[1])), pad(b.g, 0, 3 * (k - b.ids.shape[1]))])
    c = jnp.concatenate([pad(a.c, extra, 0), b.c])
    return RankOne(ids, g, c, None if b.count is None else lead + b.count, b.chunk)
