"""A regular grid's springs in family order (``stencil``): shifted slices, PCG on planes."""

from __future__ import annotations

import numpy as np

from ..._dataclass import pytree_dataclass, static_field
from .aggregates import block_grid
from .stencil import Stencil, differences, sums


@pytree_dataclass
class PlanarLayout:
    """A regular grid's springs: shifted slices, PCG on planes, block aggregates.

    Attributes:
      stencil: static, the grid layout (``_layout.stencil.Stencil``).
      block: static, the side ``b`` of the square particle blocks that aggregate the grid
        for the two-level preconditioner (``_layout.aggregates.grid_block``).
    """

    stencil: Stencil = static_field()
    block: int = static_field()

    @property
    def num_aggregates(self) -> int:
        return int(np.prod(block_grid(self.stencil.rows, self.stencil.cols, self.block)))

    def diff(self, springs, v):
        """``v_j - v_i`` for every spring: ``(N, ...) -> (S, ...)`` (shifted slices)."""
        return differences(self.stencil, v)

    def sum(self, springs, f, signed: bool = True):
        """Per-particle sums of per-spring values (``ParticleLayout.sum``), by shifted slices."""
        return sums(self.stencil, f, signed)
