"""Mass-spring cloth: one energy definition, implicit Euler by Newton (dense or CG), explicit baseline."""

from ._batch import batch_rollout, stack_scenes
from ._model.colliders import Capsule, Plane, Sphere
from ._implicit.contact import FRICTION_EPS_V
from ._diagnostics import EnergyReport, energy_report
from . import reference
from ._model.energy import energy, forces, kinetic_energy, spring_energy, total_energy
from ._model.grids import grid_triangles
from ._model.mesh import disk, from_mesh, mesh_springs
from ._model.obj import TABLECLOTH_OBJ, read_obj, write_obj, write_obj_sequence
from ._integrators import AUTO_DENSE_MAX_PARTICLES, BDF2, TRBDF2, ExplicitEuler, ImplicitEuler
from ._linear import CG, Auto, Cholesky, Jacobi, TwoLevel
from ._model.scene import Cloth, State, grid, lab_cloth, pin_mask, replace
from ._model.grids import grid_springs
from ._info import StepInfo
from ._step import rollout, step
from ._implicit.trace import HESSIANS, NewtonTrace

__all__ = [
    "Cloth", "State", "StepInfo", "NewtonTrace", "HESSIANS", "EnergyReport", "energy_report", "ExplicitEuler", "ImplicitEuler", "BDF2", "TRBDF2", "AUTO_DENSE_MAX_PARTICLES",
    "Cholesky", "CG", "Auto", "Jacobi", "TwoLevel",
    "grid", "grid_springs", "lab_cloth", "pin_mask", "replace", "energy", "spring_energy", "forces",
    "Plane", "Sphere", "Capsule", "FRICTION_EPS_V", "from_mesh", "mesh_springs", "grid_triangles", "disk",
    "read_obj", "write_obj", "write_obj_sequence", "TABLECLOTH_OBJ", "kinetic_energy", "total_energy", "reference", "step", "rollout", "batch_rollout", "stack_scenes",
]

#: Names that moved to :mod:`jaxsim.cloth.reference`; kept here for one release, with a warning.
_MOVED = {"spring_hessian": "reference", "element_blocks": "reference"}


def __getattr__(name):
    if name in _MOVED:
        import warnings

        warnings.warn(f"jaxsim.cloth.{name} moved to jaxsim.cloth.reference.{name} (cross-check internals); "
                      f"the old name goes in the next release", DeprecationWarning, stacklevel=2)
        return getattr(reference, name)
    raise AttributeError(f"module 'jaxsim.cloth' has no attribute {name!r}")
