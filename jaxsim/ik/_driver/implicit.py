"""Implicit-function derivatives of a converged IK solution (no memory per sweep).

A solution ``q*`` is a stationary point of ``f(q) = 1/2 |r(q)|^2``, with ``r`` LM's
residual (``residual``: ``sqrt(w_k) (p_k - t_k)`` per effector and, with orientation
targets, its frame-axis rows), over LM's parameters: each moving joint's local rotation
turned on the right, ``q_i (1, d_i / 2) / |.|``, three per ball joint and one per hinge
(``residual.Dofs``).  With limits, the bounds the solution sits on are held fixed (the
active set): a hinge at an end of its range loses its parameter, and a swing-twist joint
on its cone or at an end of its twist range keeps only the motions tangent to that
bound.  With ``A`` the active bounds' normals (rows), ``Pi = I - A^+ A`` the projection
onto their tangent space and ``grad_d f = A^T mu`` their multipliers, differentiating the
stationarity on the held bounds gives

    dd = -(Pi H Pi)^+ Pi (d/dtheta grad_d f) dtheta,   H = d^2 f / dd^2 - sum_i mu_i d^2 c_i / dd^2

at ``d = 0``, for ``theta`` the offsets, targets, target orientations and poles: ``H`` is the
Hessian of the Lagrangian, with ``c_i`` the held bounds as functions of ``d``, so that it
is the curvature of ``f`` restricted to them (Fiacco 1976, sensitivity of a constrained
minimum).  IK is redundant, so ``H`` is
singular along motions that keep the effectors in place; the pseudo-inverse picks the
least-change derivative.  When every target is met ``H`` is the Gauss-Newton ``J^T J``
(``r = 0``); otherwise the full Hessian.  The effectors' derivative is unique (``d
end/d target = I`` when met) and equals the limit of the unrolled derivative; the
rotations' derivative along the redundant directions is a convention (least change).  A
bound is held while the targets move: the derivative of a solution whose bound would be
left under the perturbation is the one-sided one that keeps it.  First derivatives only;
the limits themselves are not differentiated.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..._geometry import quat as _quat
from .._model.projection import _twist, _twist_angle, hinge_angle
from .._solvers.residual import Dofs, LMProblem, _perturb, _residual, turned


def _swing_twist(q, a):
    """``(swing angle, twist angle)`` of the unit quaternion ``q (4,)`` about the unit axis ``a (3,)``
    (``q = swing * twist``); NaN-free where the swing vanishes."""
    qc, t = _twist(_quat.unstack(q), _quat.unstack(a))
    s = _quat.mul(qc, _quat.conj(t))
    sv = _quat.safe_norm(s[1:])
    return 2.0 * jnp.arctan2(sv, jnp.abs(s[0])), _twist_angle(t, _quat.unstack(a))


def _swing_twist_turned(v, L, a):
    """``(2,)`` swing and twist angles of ``L (4,)`` turned on the right by ``v (3,)``, about ``a (3,)``."""
    return jnp.stack(_swing_twist(turned(L, v), a))


def active_bounds(L, dofs: Dofs, table, dtype):
    """The bounds ``L (J, 4)`` sits on, in parameter space: their normals ``A (k, n)`` and
    curvatures ``C (k, n, n)`` (zero rows for a bound not reached; ``k`` is static: one per
    hinge, two per swing-twist joint).  A bound is reached within ``1e3`` machine epsilons
    (LM and the sweeps' projections put a clamped joint on it exactly).  A hinge's bound
    is its own parameter (no curvature); a swing-twist joint's are its swing and twist
    angles as functions of its turn ``d`` (all such joints at once)."""
    n, eps = dofs.n, 1e3 * jnp.finfo(dtype).eps
    A, C = [jnp.zeros((0, n), dtype)], [jnp.zeros((0, n, n), dtype)]
    if table is not None:
        hj = [(j, c[0]) for j, h, c in zip(dofs.joints, dofs.hinge, dofs.cols) if h]
        if hj:
            js, cs = (np.asarray(x) for x in zip(*hj))
            phi = hinge_angle(_quat.unstack(L[js], axis=-1), _quat.unstack(table.axis[js], axis=-1))
            on = (phi <= table.lo[js] + eps) | (phi >= table.hi[js] - eps)
            A.append(jnp.zeros((len(js), n), dtype).at[np.arange(len(js)), cs].set(on.astype(dtype)))
            C.append(jnp.zeros((len(js), n, n), dtype))
        sj = [(j, c) for j, h, c in zip(dofs.joints, dofs.hinge, dofs.cols) if not h and table.kinds[j] == "swing"]
        if sj:
            js, cs = np.asarray([j for j, _ in sj]), np.asarray([c for _, c in sj])  # (m,), (m, 3)
            m, v0, ax = len(js), jnp.zeros((len(js), 3), dtype), table.axis[js]
            sw, tw = jax.vmap(_swing_twist_turned)(v0, L[js], ax).T
            grads = jax.vmap(jax.jacfwd(_swing_twist_turned))(v0, L[js], ax)  # (m, 2, 3)
            curv = jax.vmap(jax.hessian(_swing_twist_turned))(v0, L[js], ax)  # (m, 2, 3, 3)
            on = jnp.stack([sw >= table.swing[js] - eps, (tw <= table.lo[js] + eps) | (tw >= table.hi[js] - eps)], -1)
            on = on & jnp.all(jnp.isfinite(grads), axis=-1) & jnp.all(jnp.isfinite(curv), axis=(-2, -1))
            rows = np.arange(m)[:, None, None], np.arange(2)[None, :, None]
            A.append(jnp.zeros((m, 2, n), dtype).at[(*rows, cs[:, None, :])].set(
                jnp.where(on[..., None], grads, 0.0)).reshape(2 * m, n))
            C.append(jnp.zeros((m, 2, n, n), dtype).at[(*(r[..., None] for r in rows), cs[:, None, :, None],
                                                         cs[:, None, None, :])].set(
                jnp.where(on[..., None, None], curv, 0.0)).reshape(2 * m, n, n))
    return jnp.concatenate(A), jnp.concatenate(C)


def _tangent_projector(A, n, dtype):
    """``(n, n)`` the projection onto the null space of the rows of ``A (k, n)``."""
    eye = jnp.eye(n, dtype=dtype)
    if A.shape[0] == 0:
        return eye
    return eye - jnp.linalg.pinv(A, rtol=jnp.sqrt(jnp.finfo(dtype).eps)) @ A


def _objective_grad(topo, dofs, table, d, L, offsets, prob):
    def f(d):
        r, _ = _residual(topo, offsets, _perturb(L, d, dofs, table), prob)
        return 0.5 * jnp.sum(r * r)

    return jax.grad(f)(d)


def _hessian(topo, dofs, table, L, offsets, prob, gauss_newton):
    d0 = jnp.zeros((dofs.n,), L.dtype)
    Jac = jax.jacfwd(lambda d: _residual(topo, offsets, _perturb(L, d, dofs, table), prob)[0])(d0)
    full = jax.jacfwd(lambda d: _objective_grad(topo, dofs, table, d, L, offsets, prob))(d0)
    return jnp.where(gauss_newton, Jac.T @ Jac, 0.5 * (full + full.T))


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def implicit_rotations(topo, dofs: Dofs, q, offsets, prob: LMProblem, table, gauss_newton):
    """Identity on a converged ``q (J, 4)``, with implicit-function derivatives.

    Args:
      topo: static ``Topology``; dofs: static ``Dofs`` (``residual._dofs``).
      q: ``(J, 4)``; offsets: ``(J, 3)``; prob: the set's ``LMProblem`` (targets ``(E, 3)``,
        weights, orientations ``(E, 4)`` or ``None``); table: the ``LimitTable`` or ``None``.
      gauss_newton: ``()`` bool, use ``J^T J`` (every target met) rather than the full Hessian.
    """
    return q


@implicit_rotations.defjvp
def _implicit_rotations_jvp(topo, dofs, primals, tangents):
    q, offsets, prob, table, gauss_newton = primals
    _, off_dot, prob_dot, _, _ = tangents
    n, dtype = dofs.n, q.dtype
    if n == 0:
        return q, jnp.zeros_like(q)
    d0 = jnp.zeros((n,), dtype)
    rtol = jnp.sqrt(jnp.finfo(dtype).eps)
    # the targets, orientations and poles move (the weights are not differentiated)
    prob_dot = dataclasses.replace(prob_dot, weights=jnp.zeros_like(prob.weights), orient_weights=(
        None if prob.orient_weights is None else jnp.zeros_like(prob.orient_weights)))
    g, rhs = jax.jvp(lambda o, p: _objective_grad(topo, dofs, table, d0, q, o, p), (offsets, prob),
                     (off_dot, prob_dot))
    H = _hessian(topo, dofs, table, q, offsets, prob, gauss_newton)
    A, C = active_bounds(q, dofs, table, dtype)
    Pi = _tangent_projector(A, n, dtype)
    if A.shape[0]:  # the Lagrangian's Hessian: grad f = A^T mu on the held bounds
        H = H - jnp.einsum("k,kij->ij", jnp.linalg.pinv(A.T, rtol=rtol) @ g, C)
    dd = -(jnp.linalg.pinv(Pi @ H @ Pi, rtol=rtol, hermitian=True) @ (Pi @ rhs))
    return q, jax.jvp(lambda d: _perturb(q, d, dofs, table), (d0,), (dd,))[1]
