"""Adaptive substeps: a step whose Newton solve does not converge is retried as two halves.

``ImplicitEuler(max_substep_depth=D)``.  The step ``[0, h]`` is walked in units of
``h / 2^D``.  An attempt covers ``[pos, pos + 2^(D - level))`` from the state reached at
``pos``; it is accepted when Newton converged (or, at ``level = D``, when it was at least
taken), else it is retried at ``level + 1``.  After an accepted attempt the next one is
the pending right half of the recursion, whose size is the lowest set bit of ``pos``:
``level = D - ctz(pos)``.  So recursive bisection runs as one bounded ``lax.while_loop``
(at most ``2^(D+1) - 1`` attempts), with the stack of pending intervals held in ``pos``.

Newton runs on ``stop_gradient`` data (its derivatives come from the implicit function
theorem, ``implicit_diff``).  The accepted deviations ``w_k`` are recorded, and
:func:`replay` rebuilds each accepted substep's problem from the differentiable inputs
and applies ``implicit_diff.solution`` to it, in a ``lax.scan`` over ``2^D`` slots whose
inactive slots are skipped by a ``lax.cond``; a step taken whole (the first attempt, the
whole step, converged) replays its one slot without the scan.  Each slot is
rematerialised in reverse mode, so the backward pass keeps the slot's state, not its
linearisation.

Each substep after the first starts Newton from the constant-acceleration extrapolation
``x + h_k v + h_k^2 a`` with ``a`` the last accepted substep's ``(v_new - v) / h``
(the step's own extrapolated start gives the first one's), where that lowers the
incremental potential.  Moving colliders are interpolated linearly between the step's
start and end (a plane's normal renormalised).  BDF2 (``_implicit.bdf2``) carries its
memory through the substeps: each substep's coefficients come from its ratio to the
substep before it.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jax import lax

from ..._dataclass import pytree_dataclass
from .._explicit import bounded
from .._model.colliders import Plane
from . import bdf2
from . import problem as pr
from .implicit_diff import solution
from .newton import newton
from .trace import NewtonTrace
from .._self.pairs import PairSet, empty_pairs


def between(prev, cur, t):
    """Colliders a fraction ``t`` (``()``) of the way from ``prev`` to ``cur`` (tuples of one structure)."""
    out = jax.tree_util.tree_map(lambda a, b: a + t * (b - a), prev, cur)
    return tuple(dataclasses.replace(c, normal=c.normal / jnp.linalg.norm(c.normal)) if isinstance(c, Plane) else c
                 for c in out)


def substep_scene(cloth, prev, pos, size, D):
    """``(cloth, prev)`` for the substep ``[pos, pos + size)`` (units of ``h / 2^D``): the
    scene with the colliders at its end, and those at its start (``None``: static)."""
    if prev is None:
        return cloth, None
    unit = 1.0 / 2**D
    c0 = between(prev, cloth.colliders, pos * unit)
    c1 = between(prev, cloth.colliders, (pos + size) * unit)
    return dataclasses.replace(cloth, colliders=c1), c0


def pins_at(x0, pins, pos, size, D):
    """``(N, 3)`` the pins' positions at the end of the substep ``[pos, pos + size)`` (units
    of ``h / 2^D``) of a step from ``x0`` to ``pins``, moving linearly (exactly ``pins`` at
    the step's end); ``None`` where the pins stay."""
    if pins is None:
        return None
    t = ((pos + size) / 2**D).astype(x0.dtype)
    return jnp.where(pos + size >= 2**D, pins, x0 + t * (pins - x0))


def advance(p: pr.StepProblem, w):
    """``(x, v)`` at the end of the step ``p`` with deviation ``w (N, 3)``; pins stay put, or
    end exactly on ``p.pin_to`` with the velocity of the step's motion there."""
    free = p.free > 0
    if p.pin_to is None:
        return p.x0 + jnp.where(free, p.displacement(w), 0.0), jnp.where(free, p.velocity(w), 0.0)
    x = jnp.where(free, p.x0 + p.displacement(w), p.pin_to)
    return x, jnp.where(free, p.velocity(w), (p.pin_to - p.x0) / p.h)


@pytree_dataclass
class Totals:
    """The step's diagnostics over its attempts (``StepInfo``'s fields).

    ``newton_iters``, ``cg_iters`` and ``backtracks`` are summed over every attempt,
    including those retried as halves; ``rel_grad``, ``grad_norm`` and ``cond_bound`` are
    the largest over the accepted substeps; ``step_size``, ``residual`` and ``trace`` are the
    last attempt's; ``converged``: every accepted substep converged; ``overflow``: an
    attempt met more self-contact pairs than slots (``None`` without self-contact).
    """

    newton_iters: jax.Array
    cg_iters: jax.Array
    backtracks: jax.Array
    rel_grad: jax.Array
    grad_norm: jax.Array
    cond_bound: jax.Array
    step_size: jax.Array
    residual: jax.Array
    converged: jax.Array
    trace: NewtonTrace | None
    overflow: jax.Array | None = None


@pytree_dataclass
class SubstepLoop:
    """The substep loop's carry.

    Attributes:
      x, v: ``(N, 3)`` the state reached at ``pos``.
      pos: ``()`` int32 time reached, in units of ``h / 2^D``.
      level: ``()`` int32 the next attempt covers ``h / 2^level``.
      count: ``()`` int32 accepted substeps.
      tries: ``()`` int32 attempts made.
      accel: ``(N, 3)`` the acceleration of the extrapolated start (m/s^2).
      ws: ``(2^D, N, 3)`` the accepted substeps' deviations ``w``.
      levels: ``(2^D,)`` int32 their levels.
      failed: ``()`` bool, an attempt at ``level = D`` could not be taken (the step fails).
      totals: the diagnostics so far (:class:`Totals`).
      before: the memory at ``pos`` (BDF2's ``_implicit.bdf2.Before``, or a TR-BDF2 stage's,
        ``_implicit.trbdf2``), ``None`` for backward Euler.
      pairs: the self-contact pairs the last accepted substep ended with (its candidates
        may serve the next attempt's start), ``None`` without self-contact.
    """

    x: jax.Array
    v: jax.Array
    pos: jax.Array
    level: jax.Array
    count: jax.Array
    tries: jax.Array
    accel: jax.Array
    ws: jax.Array
    levels: jax.Array
    failed: jax.Array
    totals: Totals
    before: bdf2.Before | None = None
    pairs: PairSet | None = None


#: An attempt at the deepest level (``max_substep_depth``), which is kept converged or not,
#: runs up to ``LAST_NEWTON * newton_iters`` Newton iterations (a float64 substep of the 64x64
#: drape at h/16 converged in its 20th).
LAST_NEWTON = 2


def _trailing_zeros(n):
    """``()`` int32 trailing zero bits of ``n > 0``."""
    return lax.population_count((n & -n) - 1)


def _acceleration(w, p, x, v, h, g, euler: bool):
    """``(N, 3)`` the acceleration ``a`` of the start ``w`` of the step problem ``p`` from
    ``(x, v)`` over ``h``: its positions are ``x + h v + h^2 a`` (m/s^2)."""
    if euler:
        return w / h**2 + g
    # BDF2: the deviation is on the shifted problem (``p.x0``, ``p.v0`` over ``p.h``)
    return ((p.x0 - x) + (p.h * p.v0 - h * v) + w) / h**2 + (p.h / h)**2 * g


def search(cloth, x0, v0, h, integ, rtol, prev, layout, start, tight, before, pins=None, memory=None):
    """Find the substeps (on ``stop_gradient`` inputs): the final :class:`SubstepLoop`.

    ``start``: the first attempt's Newton start (``p -> w``, the step's extrapolation), or
    ``None`` (every attempt starts from the lab's ``x^n``); ``tight``: its ``tight_first``;
    ``before``: BDF2's memory at the step's start, ``None`` for backward Euler; ``pins``:
    ``(N, 3)`` the pinned particles' positions at the step's end, or ``None``; ``memory``:
    a rollout's :class:`Memory` (:func:`remember` of the step before; ``None``: the whole
    step first), whose ``level`` is the coarsest the step attempts.  The first attempt
    covers ``h / 2^level``; a step whose first attempt converges makes no other.
    """
    D = integ.max_substep_depth
    dtype = x0.dtype
    g = cloth.gravity
    floor = jnp.int32(0) if memory is None else jnp.clip(memory.level, 0, D)

    def attempt(c: SubstepLoop):
        size = jnp.left_shift(1, D - c.level)
        hk = h * (size.astype(dtype) / 2**D)
        ck, pk = substep_scene(cloth, prev, c.pos, size, D)
        p = bdf2.step_problem(ck, c.x, c.v, hk, pk, layout, c.before, pins_at(x0, pins, c.pos, size, D))
        w0, accel = None, c.accel
        if start is not None and not p.touches:
            if before is None:
                later = hk**2 * (c.accel - g)
            else:  # the same positions x + h_k v + h_k^2 a, as a deviation on BDF2's problem
                later = (c.x - p.x0) + (hk * c.v - p.h * p.v0) + hk**2 * c.accel - p.h**2 * g
            first = start(p)
            w0 = jnp.where(c.tries == 0, first, later)
            # the first attempt is the whole step: its start's acceleration is where a
            # retried half starts from
            accel = jnp.where(c.tries == 0, _acceleration(first, p, c.x, c.v, hk, g, before is None), c.accel)
        # the deepest level has no halves to fall back on: LAST_NEWTON times the iterations
        s = newton(p, integ, rtol, w0, tight_first=tight & (c.tries == 0),
                   limit=jnp.where(c.level == D, LAST_NEWTON * integ.newton_iters, integ.newton_iters),
                   size=LAST_NEWTON * integ.newton_iters, pairs=c.pairs)
        end = s.iterate
        x, v = advance(p, end.w)
        ok = ~s.fail & bounded(cloth, x, v)
        conv = ok & (end.rel <= rtol)
        accept = conv | (ok & (c.level == D))
        failed = ~ok & (c.level == D)
        t = c.totals
        gnorm = jnp.linalg.norm(end.grad)
        gnorm = jnp.where(jnp.isfinite(gnorm), gnorm, jnp.inf)
        keep = lambda new, old: jnp.where(accept, new, old)  # noqa: E731
        totals = Totals(t.newton_iters + s.it, t.cg_iters + s.cg, t.backtracks + s.bt,
                        keep(jnp.maximum(t.rel_grad, end.rel), t.rel_grad),
                        keep(jnp.maximum(t.grad_norm, gnorm), t.grad_norm),
                        keep(jnp.maximum(t.cond_bound, pr.condition_bound(p, end.terms)), t.cond_bound),
                        s.alpha, s.res, t.converged & (conv | ~accept), s.trace,
                        None if s.overflow is None else t.overflow | s.overflow)
        pos = jnp.where(accept, c.pos + size, c.pos)
        level = jnp.where(accept, jnp.maximum(D - _trailing_zeros(jnp.maximum(pos, 1)), floor), c.level + 1)
        level = jnp.clip(level, 0, D)
        slot = jnp.minimum(c.count, 2**D - 1)
        put = lambda a, new: lax.dynamic_update_index_in_dim(a, keep(new, lax.dynamic_index_in_dim(a, slot, 0, keepdims=False)), slot, 0)  # noqa: E731 (no scatter)
        return SubstepLoop(x=keep(x, c.x), v=keep(v, c.v), pos=pos, level=level, count=c.count + accept,
                           tries=c.tries + 1, accel=keep((v - c.v) / hk, accel),
                           ws=put(c.ws, end.w), levels=put(c.levels, c.level),
                           failed=failed, totals=totals,
                           before=None if c.before is None else c.before.after(c.x, c.v, hk, accept, p, end.w),
                           pairs=None if c.pairs is None else jax.tree_util.tree_map(keep, end.pairs, c.pairs))

    z = jnp.zeros((), dtype)
    trace = NewtonTrace.empty(LAST_NEWTON * integ.newton_iters, dtype) if integ.trace else None
    c0 = SubstepLoop(x=x0, v=v0, pos=jnp.int32(0), level=floor, count=jnp.int32(0), tries=jnp.int32(0),
                     accel=jnp.zeros_like(x0), ws=jnp.zeros((2**D,) + x0.shape, dtype), levels=jnp.zeros(2**D, jnp.int32),
                     failed=jnp.array(False),
                     totals=Totals(jnp.int32(0), jnp.int32(0), jnp.int32(0), z, z, z, z, z, jnp.array(True), trace,
                                   jnp.array(False) if cloth.self_contact else None),
                     before=before,
                     pairs=empty_pairs(cloth.self_contact_pairs, cloth.contact_faces, cloth.contact_edges, x0) if cloth.self_contact else None)
    return lax.while_loop(lambda c: (c.pos < 2**D) & ~c.failed & (c.tries < 2 ** (D + 1)), attempt, c0)


#: A coarser level tried that failed, or that cost more than the finer one before it, is not
#: tried again for ``patience`` steps: 1, then twice as many after each further such try, at
#: most ``MAX_WAIT``; a coarser level that pays resets it to 1.
MAX_WAIT = 16


@pytree_dataclass
class Memory:
    """Adaptive substeps' memory between a rollout's steps (``StepInfo.memory``).

    Attributes:
      level: ``()`` int32 the level the next step first attempts (``h / 2^level``).
      trying: ``()`` bool, that level is one coarser than the step before accepted.
      wait: ``()`` int32 steps to take before a coarser level is tried again.
      patience: ``()`` int32 the wait after the next coarser level that does not pay.
      cost: ``()`` int32 the step's Newton plus PCG iterations (every attempt's).
    """

    level: jax.Array
    trying: jax.Array
    wait: jax.Array
    patience: jax.Array
    cost: jax.Array

    @staticmethod
    def start() -> "Memory":
        """A rollout's first step: the whole step first."""
        return Memory(jnp.int32(0), jnp.array(False), jnp.int32(0), jnp.int32(1), jnp.int32(0))


def remember(found: SubstepLoop, mem: Memory | None, integ) -> Memory:
    """The memory after the step ``found`` that began from ``mem`` (``None``: a step alone).

    The next step first attempts the coarsest level this step accepted, or one coarser
    where every attempt was accepted and no wait is pending.  A coarser level tried pays
    when its first attempt converged and the step cost no more Newton and PCG iterations
    than the step before at the finer level; one that did not pay sends the next step back
    to the finer level, waits ``patience`` steps and doubles it (on a drape, a frame of two
    half steps can cost more than four quarters even where both converge)."""
    D = integ.max_substep_depth
    mem = Memory.start() if mem is None else mem
    taken = jnp.arange(2**D) < found.count
    coarsest = jnp.min(jnp.where(taken, found.levels, D))
    cost = found.totals.newton_iters + found.totals.cg_iters
    first_ok = found.levels[0] <= jnp.clip(mem.level, 0, D)
    paid = mem.trying & first_ok & (cost <= mem.cost)
    lost = mem.trying & ~paid
    wait = jnp.where(lost, mem.patience, jnp.maximum(mem.wait - 1, 0))
    patience = jnp.where(lost, jnp.minimum(2 * mem.patience, MAX_WAIT), jnp.where(paid, 1, mem.patience))
    grow = (found.tries == found.count) & (wait == 0) & (coarsest > 0) & ~lost
    level = jnp.where(lost, jnp.maximum(coarsest, mem.level + 1), coarsest - grow.astype(jnp.int32))
    return Memory(jnp.clip(level, 0, D).astype(jnp.int32), grow, wait.astype(jnp.int32),
                  patience.astype(jnp.int32), cost.astype(jnp.int32))


def replay(cloth, x0, v0, h, integ, prev, layout, found: SubstepLoop, before=None, pins=None):
    """``(x, v, before)`` after the accepted substeps of ``found``, rebuilt from the
    (differentiable) inputs, each through ``implicit_diff.solution``; ``before``: BDF2's
    memory at the step's start and, returned, at its last substep (``None``: backward Euler)."""
    D = integ.max_substep_depth

    @jax.checkpoint
    def one(carry, slot):
        x, v, pos, mem = carry
        w, level = slot
        size = jnp.left_shift(1, D - level)
        hk = h * (size.astype(x.dtype) / 2**D)
        ck, pk = substep_scene(cloth, prev, pos, size, D)
        p = bdf2.step_problem(ck, x, v, hk, pk, layout, mem, pins_at(x0, pins, pos, size, D))
        w = solution(integ, w, p)
        x1, v1 = advance(p, w)
        return x1, v1, pos + size, None if mem is None else mem.after(x, v, hk, True, p, w)

    def body(carry, slot):
        i, w, level = slot
        carry = lax.cond(i < found.count, lambda: one(carry, (w, level)), lambda: carry)
        return carry, None

    first = (x0, v0, jnp.int32(0), before)

    def substepped():
        slots = (jnp.arange(2**D), found.ws, found.levels)
        return lax.scan(body, first, slots)[0]

    # a step taken whole (the common case) replays its one slot without the scan's
    # 2^D slot tests (unbatched; under vmap both branches run)
    whole = (found.count == 1) & (found.levels[0] == 0)
    x, v, _, last = lax.cond(whole, lambda: one(first, (found.ws[0], found.levels[0])), substepped)
    return x, v, last
