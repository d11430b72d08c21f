"""Implicit-function derivatives of a converged IK solution (no memory per sweep).

A solution ``q*`` of the chain ``(offsets)`` for ``target`` is a stationary point of
``f(q) = 1/2 |end(q) - target|^2``.  Perturb each local rotation on the right,
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

import jax
import jax.numpy as jnp

from . import _quat
from ._chain import Chain
from ._fk import fk


def _qmul(a, b):
    return _quat.stack(_quat.mul(_quat.unstack(a, axis=-1), _quat.unstack(b, axis=-1)), axis=-1)


def _perturbed(q, w):
    """``q_i (1, w_i/2) / |.|``: ``q (J, 4)``, ``w (J, 3)``."""
    d = jnp.concatenate([jnp.ones_like(w[..., :1]), 0.5 * w], axis=-1)
    d = d / jnp.sqrt(jnp.sum(d * d, axis=-1, keepdims=True))
    return _qmul(q, d)


def _grad_w(w, q, offsets, target):
    def f(w):
        end = fk(Chain(offsets), _perturbed(q, w), unroll=False).positions[-1]
        return 0.5 * jnp.sum((end - target) ** 2)

    return jax.grad(f)(w)


def _hessian(q, offsets, target, reachable):
    J = q.shape[0]
    w0 = jnp.zeros((J, 3), q.dtype)
    end_of = lambda w: fk(Chain(offsets), _perturbed(q, w), unroll=False).positions[-1]  # noqa: E731
    Jac = jax.jacfwd(end_of)(w0).reshape(3, 3 * J)
    gn = Jac.T @ Jac
    full = jax.jacfwd(_grad_w)(w0, q, offsets, target).reshape(3 * J, 3 * J)
    H = jnp.where(reachable, gn, 0.5 * (full + full.T))
    return H


@jax.custom_jvp
def implicit_rotations(q, offsets, target, reachable):
    """Identity on a converged ``q (J, 4)``, with implicit-function derivatives."""
    return q


@implicit_rotations.defjvp
def _implicit_rotations_jvp(primals, tangents):
    q, offsets, target, reachable = primals
    _, off_dot, tgt_dot, _ = tangents
    J = q.shape[0]
    w0 = jnp.zeros((J, 3), q.dtype)
    H = _hessian(q, offsets, target, reachable)
    rtol = jnp.sqrt(jnp.finfo(q.dtype).eps)
    Hp = jnp.linalg.pinv(H, rtol=rtol)
    rhs = jax.jvp(lambda o, t: _grad_w(w0, q, o, t), (offsets, target), (off_dot, tgt_dot))[1]
    dw = -(Hp @ rhs.reshape(-1)).reshape(J, 3)
    dq = _qmul(q, jnp.concatenate([jnp.zeros_like(dw[:, :1]), 0.5 * dw], axis=-1))
    return q, dq
