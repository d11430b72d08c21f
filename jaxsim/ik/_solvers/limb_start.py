"""LM's limb start: each two-bone limb's hinge bent to the target's distance, then the limb
swung onto the target.

A limb here is a hinge ``h`` (an elbow, a knee) on an effector's path, the nearest hinge
above the effector, whose parent ``b`` (the shoulder, the hip) is a ball joint.  Turning
the hinge by ``delta`` about its world axis ``omega`` moves the effector on a circle, and
the squared distance from ``b`` to the effector is, with ``u = p_h - p_b`` and
``v = p_e - p_h``,

    ``|u|^2 + |v|^2 + 2 (A cos(delta) + B sin(delta) + (u . omega)(omega . v))``,
    ``A = u . v - (u . omega)(omega . v)``,  ``B = u . (omega x v)``,

so the bend that puts the effector at the target's distance from ``b`` is closed form (the
law of cosines of two-bone IK, for any bone directions and the joints below the hinge as
they are), clamped to the hinge's range.  The ball joint then turns by the shortest arc
that takes the effector onto the line from ``b`` to the target, projected onto its limit.
Most of the limited humanoid's unconverged sets fail in their limbs (docs/notebook.md):
a bent, pointed limb starts LM in the target's basin.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from ..._geometry import quat as _quat
from .._model.projection import about, clamp_range, hinge_angle, safe_atan2
from .._model.skeleton import steps_below
from .._model.stacked import apply_bounds, bounds, take


@functools.lru_cache(maxsize=None)
def limbs(parents: tuple, effectors: tuple, kinds: tuple) -> tuple:
    """Static ``((slot, ball, hinge, effector), ...)``: per effector slot, its limb, if it has
    one, such that no limb's ball joint lies on or below another's (one FK serves all)."""
    found = []
    for k, e in enumerate(effectors):
        i = parents[e]
        while i >= 0 and kinds[i] != "hinge":
            i = parents[i]
        if i < 0 or parents[i] < 0 or kinds[parents[i]] not in ("free", "swing"):
            continue
        found.append((k, parents[i], i, e))

    return tuple(a for a in found if not any(o is not a and steps_below(parents, o[1], a[1]) is not None
                                             for o in found))


def limb_start(topo, table, L, P, G, targets, swivel=None, prob=None):
    """The start ``L (J, 4)`` (FK ``P (J, 3)``, ``G (J, 4)``) with every limb of :func:`limbs`
    bent to its target's distance and swung toward it (``targets (E, 3)``), then turned by
    ``swivel`` (rad, a scalar; ``None``: no turn) about the line from its ball joint to the
    target, or, for a limb whose hinge has a pole (``prob``'s ``poles`` and ``pole_limbs``),
    by the turn that puts the hinge on its pole's side (the plane of the line and the pole,
    as ``two_bone``); ``L`` itself when the skeleton has no limb."""
    if table is None:
        return L
    found = limbs(tuple(topo.parents), tuple(topo.effectors), tuple(table.kinds))
    if not found:
        return L
    slot, ball, hinge, eff = (tuple(int(a[c]) for a in found) for c in range(4))
    q = _quat.unstack
    pb, ph, pe = (q(take(P, idx, axis=0), axis=-1) for idx in (ball, hinge, eff))
    t = q(take(targets, slot, axis=0), axis=-1)
    axis = q(take(table.axis, hinge, axis=0), axis=-1)
    om = _quat.rotate(q(take(G, hinge, axis=0), axis=-1), axis)
    u, v, w = _quat.sub(ph, pb), _quat.sub(pe, ph), _quat.sub(t, pb)
    uo, ov = _quat.dot(u, om), _quat.dot(om, v)
    A, B = _quat.dot(u, v) - uo * ov, _quat.dot(u, _quat.cross(om, v))
    C = 0.5 * (_quat.sqnorm(w) - _quat.sqnorm(u) - _quat.sqnorm(v)) - uo * ov
    R = _quat.safe_sqrt(A * A + B * B)
    phi = safe_atan2(B, A)
    c = jnp.clip(C / jnp.maximum(R, jnp.finfo(R.dtype).tiny), -1.0, 1.0)
    off = safe_atan2(_quat.safe_sqrt(jnp.maximum(1.0 - c * c, 0.0)), c)  # arccos(c), NaN-free gradient at +-1
    theta = hinge_angle(q(take(L, hinge, axis=0), axis=-1), axis)
    lo, hi = take(table.lo, hinge, axis=0), take(table.hi, hinge, axis=0)

    def miss(new):  # |achieved - wanted| of 2 (A cos + B sin), for a new hinge angle
        d = new - theta
        return jnp.abs(A * jnp.cos(d) + B * jnp.sin(d) - C)

    a1, a2 = (clamp_range(jnp.mod(theta + phi + s * off + jnp.pi, 2 * jnp.pi) - jnp.pi, lo, hi) for s in (1, -1))
    new = jnp.where(miss(a1) <= miss(a2), a1, a2)
    # the ball joint's turn, in its parent's frame (whose world rotation is gp): the shortest arc
    # from the hinge-turned effector onto the target line, then the swivel about that line
    gp = q(jnp.where(np.asarray([topo.parents[b] >= 0 for b in ball])[:, None],
                     take(G, tuple(max(topo.parents[b], 0) for b in ball), axis=0),
                     jnp.asarray([1.0, 0.0, 0.0, 0.0], G.dtype)), axis=-1)
    to_parent = _quat.conj(gp)
    reach = _quat.rotate(to_parent, _quat.add(u, _quat.rotate(about(new - theta, om), v)))
    line = _quat.rotate(to_parent, w)
    turn = _quat.from_two_vectors(reach, line)
    ell = _quat.normalize(line, _quat.perpendicular(line))
    poled = {} if prob is None or prob.poles is None else {t[1]: k for k, t in enumerate(prob.pole_limbs)}
    has = [h in poled for h in hinge]
    if any(has):  # the turn about the line that brings the hinge to its pole's side
        pole = q(take(prob.poles, tuple(poled.get(h, 0) for h in hinge), axis=0), axis=-1)

        def across(x):
            return _quat.sub(x, _quat.scale(_quat.dot(x, ell), ell))

        m = across(_quat.rotate(turn, _quat.rotate(to_parent, u)))
        p = across(_quat.rotate(to_parent, _quat.sub(pole, pb)))
        to_pole = safe_atan2(_quat.dot(ell, _quat.cross(m, p)), _quat.dot(m, p))
        base = jnp.zeros_like(to_pole) if swivel is None else jnp.asarray(swivel, L.dtype)
        swivel = jnp.where(np.asarray(has), to_pole, base)
    if swivel is not None:
        turn = _quat.mul(about(jnp.asarray(swivel, L.dtype), ell), turn)
    Lb = _quat.mul(turn, q(take(L, ball, axis=0), axis=-1))
    L = L.at[np.asarray(hinge)].set(_quat.stack(about(new, axis), axis=-1))
    return apply_bounds(bounds(table, ball), L.at[np.asarray(ball)].set(_quat.stack(Lb, axis=-1)))
