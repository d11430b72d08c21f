"""Implicit-function derivatives of a converged IK solution (no memory per sweep).

A solution ``q*`` of the skeleton ``(offsets)`` for its targets is a stationary point of
``f(q) = 1/2 sum_k w_k |effector_k(q) - target_k|^2`` (one effector, the end, on a chain).  Perturb each local rotation on the right,
``q_i(w) = q*_i (1, w_i/2) / |.|`` (``w (J, 3)`` in radians), and differentiate the
stationarity ``grad_w f(0; theta) = 0``:

    dw = -H^+ (d/dtheta grad_w f) dtheta,     H = d^2 f / dw^2 at w = 0.

IK is redundant (``3J`` angles, 3 position constraints), so ``H`` is singular along
motions that keep the end in place; the pseudo-inverse picks the least-change
derivative, the one with no component along them.  For a reachable target ``end = target``
and ``H`` is the Gauss-Newton ``J^T J``; for an unreachable one the full Hessian
(which bends the straight chain) is used.  The end position's derivative
(``d end/d target = I`` when reachable, the straight-line map when not) is unique and
equals the limit of the unrolled derivative; the rotations' derivative along the
redundant directions is a convention (least change), whereas the unrolled one follows
the path the sweeps took.  First derivatives only.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._geometry import quat as _quat
from ._fk import joint_positions


def _qmul(a, b):
    return _quat.stack(_quat.mul(_quat.unstack(a, axis=-1), _quat.unstack(b, axis=-1)), axis=-1)


def _perturbed(q, w):
    """``q_i (1, w_i/2) / |.|``: ``q (J, 4)``, ``w (J, 3)``."""
    d = jnp.concatenate([jnp.ones_like(w[..., :1]), 0.5 * w], axis=-1)
    d = d / jnp.sqrt(jnp.sum(d * d, axis=-1, keepdims=True))
    return _qmul(q, d)


def _effectors(topo, offsets, q):
    """``(E, 3)`` effector positions of local rotations ``q (J, 4)`` (a chain by the rolled
    FK, whose second derivatives compile several times faster)."""
    return joint_positions(topo.parents, offsets, q)[np.asarray(topo.effectors)]


def _grad_w(topo, w, q, offsets, targets, weights):
    def f(w):
        r = _effectors(topo, offsets, _perturbed(q, w)) - targets
        return 0.5 * jnp.sum(weights[:, None] * r * r)

    return jax.grad(f)(w)


def _hessian(topo, q, offsets, targets, weights, gauss_newton):
    J = q.shape[0]
    w0 = jnp.zeros((J, 3), q.dtype)
    Jac = jax.jacfwd(lambda w: _effectors(topo, offsets, _perturbed(q, w)))(w0).reshape(-1, 3 * J)
    gn = Jac.T @ (jnp.repeat(weights, 3)[:, None] * Jac)
    full = jax.jacfwd(functools.partial(_grad_w, topo))(w0, q, offsets, targets, weights).reshape(3 * J, 3 * J)
    return jnp.where(gauss_newton, gn, 0.5 * (full + full.T))


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def implicit_rotations(topo, q, offsets, targets, weights, gauss_newton):
    """Identity on a converged ``q (J, 4)``, with implicit-function derivatives.

    Args:
      topo: static ``Topology`` (a chain: parents ``(-1, 0, ...)``, effector ``J-1``).
      q: ``(J, 4)``; offsets: ``(J, 3)``; targets: ``(E, 3)``; weights: ``(E,)``.
      gauss_newton: bool, use ``J^T W J`` (targets met) rather than the full Hessian.
    """
    return q


@implicit_rotations.defjvp
def _implicit_rotations_jvp(topo, primals, tangents):
    q, offsets, targets, weights, gauss_newton = primals
    _, off_dot, tgt_dot, _, _ = tangents
    J = q.shape[0]
    w0 = jnp.zeros((J, 3), q.dtype)
    H = _hessian(topo, q, offsets, targets, weights, gauss_newton)
    rtol = jnp.sqrt(jnp.finfo(q.dtype).eps)
    Hp = jnp.linalg.pinv(H, rtol=rtol)
    rhs = jax.jvp(lambda o, t: _grad_w(topo, w0, q, o, t, weights), (offsets, targets), (off_dot, tgt_dot))[1]
    dw = -(Hp @ rhs.reshape(-1)).reshape(J, 3)
    dq = _qmul(q, jnp.concatenate([jnp.zeros_like(dw[:, :1]), 0.5 * dw], axis=-1))
    return q, dq
