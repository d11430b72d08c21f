"""A scene's static solver layout, derived once from its topology and kept apart from its
physics (the ``put_model`` pattern of MuJoCo MJX).

A :class:`~jaxsim.cloth.Cloth` holds physics and colliders only.  How the solver walks its
springs is a layout, built by :func:`layout_of` from the concrete spring table before any
tracing, and passed beside the scene:

* :class:`PlanarLayout`: the springs are a regular grid's families in order (``grid``,
  ``lab_cloth``; ``_layout.stencil``).  Spring differences and per-particle sums are shifted
  slices, PCG runs on planes (``_layout.planes``) and the two-level preconditioner's aggregates
  are square blocks of the grid.  Static: no arrays.
* :class:`ParticleLayout`: any other spring table.  Per-particle sums gather through an
  incidence table (scatter-adds when it is absent), PCG runs on ``(N, 3)`` vectors and the
  aggregates are the cells of a voxel grid over the rest shape (``_layout.aggregates.aggregate``).

Both give the same sums (tested equal); the layout only decides how they are computed.
"""

from .build import Layout, batch_layout, layout_of, spring_diff, spring_sum
from .particles import ParticleLayout
from .planar import PlanarLayout

__all__ = ["Layout", "ParticleLayout", "PlanarLayout", "layout_of", "batch_layout", "spring_diff", "spring_sum"]
