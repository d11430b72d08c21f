"""Two small optimisers for inverse problems through the solvers (pure JAX).

* :func:`adam`: Adam (Kingma & Ba 2015) on a scalar loss, the whole run one
  compiled ``lax.scan``.
* :func:`levenberg_marquardt`: damped Gauss-Newton on a residual vector, for a few
  parameters (Jacobian by ``jax.jacfwd``) or a few residuals (by ``jax.jacrev``,
  with the minimum-norm step ``-J^T (J J^T + lambda I)^{-1} r``).

Parameters may be any pytree of float arrays.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.flatten_util import ravel_pytree

from ._validate import check_int, check_real


@dataclasses.dataclass(frozen=True)
class OptResult:
    """Result of an optimiser run.

    Attributes:
      params: the final parameters (same pytree as the start).
      history: ``(steps,)`` loss (Adam) or squared residual norm (LM) per iteration.
      iterations: iterations performed.
      converged: LM reached ``tol``; Adam: always ``False`` (it runs a fixed count).
    """

    params: object
    history: np.ndarray
    iterations: int
    converged: bool


def adam(loss, params, *, steps: int, lr: float, final_lr: float | None = None, b1: float = 0.9,
         b2: float = 0.999, eps: float = 1e-12) -> OptResult:
    """Minimise ``loss(params)`` with Adam; the learning rate decays geometrically from
    ``lr`` to ``final_lr`` (default: constant).

    Raises:
      ValueError: ``steps`` not an int ``>= 1``, a non-positive ``lr``, ``final_lr`` or
        ``eps``, or ``b1``, ``b2`` outside ``[0, 1)``.
    """
    steps = check_int("steps", steps, 1)
    lr = check_real("lr", lr, minimum=0.0, strict=True)
    if final_lr is not None:
        final_lr = check_real("final_lr", final_lr, minimum=0.0, strict=True)
    for name, b in (("b1", b1), ("b2", b2)):
        if not 0.0 <= check_real(name, b) < 1.0:
            raise ValueError(f"{name} must lie in [0, 1), got {b!r}")
    check_real("eps", eps, minimum=0.0, strict=True)
    x0, unravel = ravel_pytree(params)
    decay = 1.0 if final_lr is None else (final_lr / lr) ** (1.0 / steps)
    vg = jax.value_and_grad(lambda x: loss(unravel(x)))

    @jax.jit
    def run(x0):
        def body(c, k):
            x, m, v = c
            val, g = vg(x)
            m = b1 * m + (1 - b1) * g
            v = b2 * v + (1 - b2) * g * g
            t = k + 1.0
            step = lr * decay**k * (m / (1 - b1**t)) / (jnp.sqrt(v / (1 - b2**t)) + eps)
            return (x - step, m, v), val

        z = jnp.zeros_like(x0)
        (x, _, _), hist = lax.scan(body, (x0, z, z), jnp.arange(steps, dtype=x0.dtype))
        return x, hist

    x, hist = run(x0)
    return OptResult(unravel(x), np.asarray(hist), steps, False)


def levenberg_marquardt(residual, params, *, steps: int = 50, tol: float = 1e-20, damping: float = 1.0) -> OptResult:
    """Minimise ``|residual(params)|^2`` by Levenberg-Marquardt.

    A step is kept only if it lowers the cost; ``damping`` is then divided by 3, else
    multiplied by 4.  Stops when the cost is below ``tol``.

    Raises:
      ValueError: ``steps`` not an int ``>= 0``, ``tol < 0`` or ``damping <= 0``.
    """
    steps = check_int("steps", steps, 0)
    tol = check_real("tol", tol, minimum=0.0)
    damping = check_real("damping", damping, minimum=0.0, strict=True)
    x, unravel = ravel_pytree(params)
    res = lambda x: jnp.ravel(residual(unravel(x)))  # noqa: E731
    m = jax.eval_shape(res, x).shape[0]
    jac = jax.jacfwd(res) if x.shape[0] <= m else jax.jacrev(res)
    f = jax.jit(lambda x: (res(x), jac(x)))  # one compiled function, also for trial points
    lam, hist = damping, []
    r, J = f(x)
    cost = float(r @ r)
    k, conv = 0, cost <= tol
    while k < steps and not conv:
        k += 1
        if x.shape[0] <= m:  # normal equations with Marquardt's diagonal scaling
            A = J.T @ J
            dx = jnp.linalg.solve(A + lam * jnp.diag(jnp.diag(A) + 1e-30), -J.T @ r)
        else:  # fewer residuals than parameters: the minimum-norm step
            dx = -J.T @ jnp.linalg.solve(J @ J.T + lam * jnp.eye(m, dtype=J.dtype), r)
        r_new, J_new = f(x + dx)
        new = float(r_new @ r_new)
        if new < cost:
            x, lam, r, J, cost = x + dx, max(lam / 3.0, 1e-12), r_new, J_new, new
        else:
            lam *= 4.0
        hist.append(cost)
        conv = cost <= tol
    return OptResult(unravel(x), np.asarray(hist), k, bool(conv))
