"""Any spring table: gathers through an incidence table, PCG on ``(N, 3)`` vectors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import pytree_dataclass, static_field
from .aggregates import MAX_AGGREGATES


@pytree_dataclass
class ParticleLayout:
    """Gathers through an incidence table; PCG on ``(N, 3)`` vectors.

    Attributes:
      incidence: ``(N, D)`` int32 (``(B, N, D)`` for a batch of spring tables): entry
        ``s + 1`` where particle ``n`` is spring ``s``'s second end, ``-(s + 1)`` where it
        is the first, 0 as padding (``D`` = largest degree); ``None``: scatter-adds (a
        layout for springs only known inside ``jit``).
      aggregates: ``(N,)`` int32, each particle's aggregate for
        ``CG(preconditioner=TwoLevel())`` (``(B, N)`` with a batched incidence).
      num_aggregates: static, the number of aggregates (at most ``MAX_AGGREGATES``).
    """

    incidence: jax.Array | None
    aggregates: jax.Array
    num_aggregates: int = static_field()

    def diff(self, springs, v):
        """``v_j - v_i`` for every spring ``(i, j)``: ``(N, ...) -> (S, ...)`` (a gather)."""
        return v[springs[:, 1]] - v[springs[:, 0]]

    def sum(self, springs, f, signed: bool = True):
        """Per-particle sums of per-spring values, ``f (S, ...) -> (N, ...)``.

        ``signed``: ``+f_s`` at each spring's second end and ``-f_s`` at its first (the
        assembly of spring forces); otherwise ``+f_s`` at both ends (the block diagonal).
        """
        N = self.aggregates.shape[-1]
        if f.shape[0] == 0:
            return jnp.zeros((N,) + f.shape[1:], f.dtype)
        if self.incidence is None:
            out = jnp.zeros((N,) + f.shape[1:], f.dtype).at[springs[:, 1]].add(f)
            return out.at[springs[:, 0]].add(-f if signed else f)
        inc = self.incidence
        w = (jnp.sign(inc) if signed else jnp.abs(jnp.sign(inc))).astype(f.dtype)
        w = w.reshape(w.shape + (1,) * (f.ndim - 1))
        g = f[jnp.maximum(jnp.abs(inc) - 1, 0)]  # (N, D, ...)
        # summed slot by slot (D is static): an einsum over D is a batched dot that XLA:CPU
        # cannot fuse with the gather, and it costs as much as the rest of a CG iteration
        out = w[:, 0] * g[:, 0]
        for d in range(1, g.shape[1]):
            out = out + w[:, d] * g[:, d]
        return out


def incidence(springs: np.ndarray, n_particles: int) -> np.ndarray:
    """Signed spring ids per particle, ``(N, D)`` int32 (``ParticleLayout.incidence``)."""
    springs = np.asarray(springs).reshape(-1, 2)
    S = len(springs)
    ends = np.concatenate([springs[:, 1], springs[:, 0]])
    code = np.concatenate([np.arange(1, S + 1), -np.arange(1, S + 1)]).astype(np.int32)
    order = np.argsort(ends, kind="stable")
    ends, code = ends[order], code[order]
    deg = np.bincount(ends, minlength=n_particles)
    D = max(int(deg.max()) if S else 0, 1)
    slot = np.arange(len(ends)) - np.repeat(np.cumsum(deg) - deg, deg)
    out = np.zeros((n_particles, D), np.int32)
    out[ends, slot] = code
    return out


def index_aggregates(n_particles: int) -> tuple[np.ndarray, int]:
    """``(ids (N,), count)``: runs of consecutive particle ids, for a rest shape only known
    inside ``jit`` (any partition gives a valid two-level preconditioner)."""
    count = max(min(MAX_AGGREGATES, n_particles), 1)
    return (np.arange(n_particles) * count // max(n_particles, 1)).astype(np.int32), count
