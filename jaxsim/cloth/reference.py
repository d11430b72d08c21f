"""Cross-check references for the cloth solver: the lab's closed forms, kept beside the one
energy definition so the tests and notebooks can compare against them.

* :func:`spring_hessian`: the lab's analytic spring Hessian (17.27), assembled as in
  (17.28): ``H_e = k e e^T + k (1 - L/l)(I - e e^T)`` per spring.  The solver never uses
  it; its Hessian comes from autodiff of :func:`jaxsim.cloth.energy` (equal to this one
  to 1e-9 relative in the tests).
* :func:`element_blocks`: the per-spring ``(S, 3, 3)`` blocks of the potential's Hessian
  from the radial form (with ``project_psd=True``, each projected onto the positive
  semi-definite cone), the blocks the matrix-free CG operator and block Jacobi use.
"""

from ._model.energy import element_blocks, spring_hessian

__all__ = ["spring_hessian", "element_blocks"]
