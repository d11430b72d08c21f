"""The grid operator (``_layout.stencil``): found automatically, and equal to the general one."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import cloth as C
from jaxsim.cloth._implicit import coarse as _coarse
from jaxsim.cloth._model import energy as en
from jaxsim.cloth._layout import planes as pl
from jaxsim.cloth._implicit.linsolve import block_inverse
from jaxsim.cloth._layout import ParticleLayout, PlanarLayout, batch_layout, layout_of
from jaxsim.cloth._layout import aggregates as agg
from jaxsim.cloth._layout import spring_diff as _diff
from jaxsim.cloth._layout import spring_sum as _sum
from jaxsim.cloth._layout.stencil import Stencil, detect
from jaxsim.cloth._vec import matvec
from _helpers import all_eqns, step_jaxpr


def stencil_of(c):
    """The grid layout that the solver finds for ``c``, or ``None``."""
    lay = layout_of(c.springs, c.rest)
    return lay.stencil if isinstance(lay, PlanarLayout) else None


def spring_diff(c, v):
    return _diff(c, v, layout_of(c.springs, c.rest))


def spring_sum(c, f, signed=True):
    return _sum(c, f, signed, layout_of(c.springs, c.rest))


def permuted(c, seed=0):
    """The same scene with its springs in random order: no grid layout, the general operator."""
    perm = np.random.default_rng(seed).permutation(c.num_springs)
    out = C.replace(c, springs=np.asarray(c.springs)[perm], rest_length=c.rest_length[perm],
                    stiffness=c.stiffness[perm])
    return out, perm


def numpy_sum(springs, f, n, signed):
    out = np.zeros((n,) + f.shape[1:])
    np.add.at(out, springs[:, 1], f)
    np.add.at(out, springs[:, 0], -f if signed else f)
    return out


@pytest.mark.parametrize("n", [1, 2, 5, 10])
def test_grid_scenes_get_the_grid_operator(n):
    c = C.grid(n, dtype=np.float64)
    m = n + 1
    st = stencil_of(c)
    assert st is not None and (st.rows, st.cols) == (m, m)
    np.testing.assert_array_equal(st.springs(), np.asarray(c.springs))
    # the families keep grid_springs' kinds, pairs and counts
    springs, kind = C.grid_springs(n)
    np.testing.assert_array_equal(springs, np.asarray(c.springs))
    if n >= 2:
        assert np.bincount(kind).tolist() == [2 * m * n, 2 * n * n, 2 * m * (n - 1)]


def test_other_layouts_keep_the_general_operator():
    lab = C.lab_cloth(dtype=np.float64)
    assert stencil_of(lab) is not None
    assert stencil_of(permuted(lab)[0]) is None
    disk = C.from_mesh(*C.read_obj(C.TABLECLOTH_OBJ), dtype=np.float64)
    assert stencil_of(disk) is None
    assert detect(np.zeros((0, 2), int), 4) is None
    # the springs with one spring removed are no longer whole families
    assert detect(np.asarray(lab.springs)[1:], lab.num_particles) is None


def test_replacing_springs_recomputes_the_layout():
    lab = C.lab_cloth(dtype=np.float64)
    shuffled, perm = permuted(lab)
    back = C.replace(shuffled, springs=np.asarray(shuffled.springs)[np.argsort(perm)],
                     rest_length=lab.rest_length, stiffness=lab.stiffness)
    assert stencil_of(back) == stencil_of(lab)
    # the layout follows the springs alone: the shuffled scene gathers through its own incidence
    lay = layout_of(shuffled.springs, shuffled.rest)
    assert isinstance(lay, ParticleLayout) and lay.incidence.shape[0] == lab.num_particles
    assert layout_of(shuffled.springs, shuffled.rest) is lay  # built once per topology


def unusual_grid():
    """A non-square grid with unusual families, given as a plain spring list."""
    st = Stencil(5, 7, ((0, -1), (-1, 0), (-1, 2), (-3, -1), (2, 1)))
    springs = st.springs()
    assert detect(springs, 35) == st
    rest = np.stack([np.arange(35) // 7, np.zeros(35), np.arange(35) % 7], 1) * 0.1
    L = np.linalg.norm(rest[springs[:, 1]] - rest[springs[:, 0]], axis=1)
    c = C.Cloth(rest=rest, springs=springs, rest_length=L, stiffness=np.full(len(L), 10.0), mass=np.ones(35),
                pinned=np.zeros(35, bool), gravity=np.zeros(3), damping=np.asarray(0.1))
    assert stencil_of(c) == st
    return c, st, springs


@pytest.mark.parametrize("shape", [(), (3,), (3, 3)])
@pytest.mark.parametrize("signed", [True, False])
def test_grid_operator_equals_gathers_and_numpy(shape, signed):
    c, st, springs = unusual_grid()
    rng = np.random.default_rng(1)
    g, perm = permuted(c, seed=2)
    f = rng.normal(size=(len(springs),) + shape)
    ref = numpy_sum(springs, f, 35, signed)
    np.testing.assert_allclose(spring_sum(c, jnp.asarray(f), signed), ref, rtol=0, atol=1e-13)
    np.testing.assert_allclose(spring_sum(g, jnp.asarray(f[perm]), signed), ref, rtol=0, atol=1e-13)
    v = rng.normal(size=(35,) + shape)
    np.testing.assert_array_equal(spring_diff(c, jnp.asarray(v)), v[springs[:, 1]] - v[springs[:, 0]])


@pytest.mark.parametrize("project_psd", [False, True])
def test_planes_equal_the_particle_layout(project_psd):
    """PCG's planar layout (``_layout.planes``): blocks, operator, block sums and block inverses
    equal the ``(N, 3)`` ones, including a compressed spring's negative eigenvalue."""
    c, st, springs = unusual_grid()
    rng = np.random.default_rng(3)
    S = len(springs)
    e = rng.normal(size=(S, 3))
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    along, across = rng.uniform(0.5, 2.0, S), rng.uniform(-1.0, 1.0, S)
    e0 = rng.normal(size=(S, 3))
    A = en.radial_blocks(*map(jnp.asarray, (e, along, across, e0)), 0.3, project_psd=project_psd)
    P = pl.radial_blocks(*map(jnp.asarray, (e, along, across, e0)), 0.3, project_psd=project_psd)
    np.testing.assert_allclose(P, A.transpose(1, 2, 0), rtol=0, atol=1e-15)
    v = jnp.asarray(rng.normal(size=(35, 3)))
    V = pl.to_planes(st, v)
    np.testing.assert_array_equal(pl.from_planes(V), v)
    ref = spring_sum(c, matvec(A, spring_diff(c, v)))
    np.testing.assert_allclose(pl.from_planes(pl.operator(st, P, V)), ref, rtol=0, atol=1e-13)
    D = spring_sum(c, A, signed=False) + 10.0 * jnp.eye(3)
    np.testing.assert_allclose(pl.block_sums(st, P) + 10.0 * jnp.eye(3)[:, :, None, None],
                               pl.particle_planes(st, D), rtol=0, atol=1e-13)
    np.testing.assert_allclose(block_inverse(pl.particle_planes(st, D), planar=True),
                               pl.particle_planes(st, np.linalg.inv(np.asarray(D))),
                               rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(pl.from_planes(pl.matvec(pl.particle_planes(st, D), V)), matvec(D, v),
                               rtol=0, atol=1e-13)


@pytest.mark.parametrize("integ", [C.ImplicitEuler(linear_solver=C.CG()), C.ImplicitEuler(linear_solver=C.Cholesky()),
                                   C.ExplicitEuler(substeps=10), C.ImplicitEuler(linear_solver=C.CG(), project_psd=False),
                                   C.ImplicitEuler(linear_solver=C.CG(C.TwoLevel()))],
                         ids=["cg", "dense", "explicit", "cg-exact", "cg-two-level"])
@pytest.mark.slow
def test_steps_with_the_grid_operator_equal_the_general_operator(integ):
    lab = C.lab_cloth(dtype=np.float64)
    gen, _ = permuted(lab)
    a, ia = C.rollout(lab, C.State.at_rest(lab), 1 / 60, 5, integ)
    b, ib = C.rollout(gen, C.State.at_rest(gen), 1 / 60, 5, integ)
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.v, b.v, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(ia.newton_iters, ib.newton_iters)
    assert bool(jnp.all(ia.converged))


@pytest.mark.slow
def test_gradient_through_the_grid_operator_equals_the_general_one():
    lab = C.lab_cloth(dtype=np.float64)
    gen, perm = permuted(lab)
    integ = C.ImplicitEuler(linear_solver=C.CG())

    def loss(k, c):
        c = C.replace(c, stiffness=k)
        s, _ = C.step(c, C.State.at_rest(c), 1 / 60, integ)
        return jnp.sum(s.x[:, 1])

    ga = jax.grad(loss)(lab.stiffness, lab)
    gb = jax.grad(loss)(gen.stiffness, gen)
    np.testing.assert_allclose(ga[perm], gb, rtol=1e-9, atol=1e-14)


def test_grid_step_compiles_without_gathers_or_scatters():
    """The grid scene's step reads its springs by slices only; the same scene in another
    spring order gathers (the test can fail both ways)."""
    lab = C.lab_cloth(dtype=np.float64)
    integ = C.ImplicitEuler(linear_solver=C.CG())
    prims = {e.primitive.name for e in all_eqns(step_jaxpr(lab, integ))}
    assert not {p for p in prims if "gather" in p or "scatter" in p}, prims
    prims_gen = {e.primitive.name for e in all_eqns(step_jaxpr(permuted(lab)[0], integ))}
    assert "gather" in prims_gen


def test_stacked_scenes_keep_a_shared_layout():
    a = C.grid(4, dtype=np.float64)
    b = C.replace(a, stiffness=50.0)
    same = C.stack_scenes([a, b])
    assert batch_layout(same.springs, same.rest) == (layout_of(a.springs, a.rest), False)
    mixed = C.stack_scenes([a, permuted(a)[0]])
    lay, batched = batch_layout(mixed.springs, mixed.rest)
    assert batched and isinstance(lay, ParticleLayout) and lay.incidence.shape[:2] == (2, a.num_particles)


@pytest.mark.slow
def test_contact_steps_on_planes_equal_the_general_operator():
    """A grid over a sphere: the contact blocks join PCG's planes."""
    c = C.grid(6, 0.05, origin=(-0.15, 0.12, -0.15), gravity=9.8, pins=[], dtype=np.float64,
               colliders=(C.Sphere(np.zeros(3), 0.1),))
    assert stencil_of(c) is not None
    gen, _ = permuted(c)
    integ = C.ImplicitEuler(linear_solver=C.CG())
    a, ia = C.rollout(c, C.State.at_rest(c), 1 / 60, 8, integ)
    b, ib = C.rollout(gen, C.State.at_rest(gen), 1 / 60, 8, integ)
    assert bool(jnp.all(ia.converged))
    assert float(jnp.min(jnp.linalg.norm(a.x[-1], axis=-1))) < 0.105  # on the sphere
    np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(ia.newton_iters, ib.newton_iters)


@pytest.mark.parametrize("b", [2, 3])
def test_coarse_space_on_planes_equals_the_general_one(b):
    """The two-level preconditioner's coarse matrix and correction on grid blocks
    (``_layout.planes``) equal the general Galerkin product over the same aggregates, with partial
    blocks, pins (a block of pins too) and families reaching across two blocks."""
    c, st, springs = unusual_grid()
    pinned = np.zeros(35, bool)
    pinned[[0, 1, 7, 8, 20]] = True  # with b = 2 the first block is all pins
    rng = np.random.default_rng(5)
    S = len(springs)
    e = rng.normal(size=(S, 3))
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    A = en.radial_blocks(*map(jnp.asarray, (e, rng.uniform(0.5, 2.0, S), rng.uniform(0.0, 1.0, S))), project_psd=True)
    free = (~pinned).astype(np.float64)
    diag = spring_sum(c, A, signed=False) + jnp.asarray(rng.uniform(1.0, 2.0, 35))[:, None, None] * jnp.eye(3)
    ids = agg.block_ids(st.rows, st.cols, b)
    count = int(ids.max()) + 1
    ref = _coarse.coarse_matrix(jnp.asarray(ids), count, c.springs, A, diag - spring_sum(c, A, signed=False),
                                jnp.asarray(free))
    got = pl.coarse_matrix(st, b, A.transpose(1, 2, 0), pl.particle_planes(st, diag), pl.particle_planes(st, jnp.asarray(free)))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-13)
    factor = jax.scipy.linalg.cho_factor(ref, lower=True)
    r = jnp.asarray(rng.normal(size=(35, 3)))
    want = _coarse.coarse_correction(jnp.asarray(ids), count, factor, jnp.asarray(free)[:, None])(r)
    have = pl.coarse_correction(st, b, factor, pl.particle_planes(st, jnp.asarray(free))[None])(pl.to_planes(st, r))
    np.testing.assert_allclose(pl.from_planes(have), want, rtol=0, atol=1e-12)


def test_grid_scenes_take_block_aggregates():
    c = C.grid(31, 0.2)
    lay = layout_of(c.springs, c.rest)
    assert isinstance(lay, PlanarLayout) and lay.block == 4 and lay.num_aggregates == 64
    lab = C.lab_cloth()
    lay = layout_of(lab.springs, lab.rest)
    assert lay.block == agg.grid_block(11, 11) and lay.num_aggregates <= agg.MAX_AGGREGATES
    gen, _ = permuted(c)
    lay = layout_of(gen.springs, gen.rest)  # the general coarse space: voxel cells
    assert isinstance(lay, ParticleLayout) and lay.num_aggregates <= agg.MAX_AGGREGATES
    np.testing.assert_array_equal(lay.aggregates, agg.aggregate(np.asarray(gen.rest))[0])


def test_the_scene_holds_physics_and_the_layout_is_derived_apart():
    """``Cloth`` has no solver caches; ``layout_of`` derives them, once per topology."""
    fields = {f.name for f in dataclasses.fields(C.Cloth)}
    assert fields == {"rest", "springs", "rest_length", "stiffness", "mass", "pinned", "gravity", "damping", "damped",
                      "colliders", "contact_gap", "contact_stiffness", "contact_faces", "contact_edges", "self_contact",
                      "self_contact_pairs", "wind", "drag", "lift", "aero"}
    lab, again = C.lab_cloth(dtype=np.float64), C.lab_cloth(dtype=np.float64)
    assert layout_of(lab.springs, lab.rest) == layout_of(again.springs, again.rest)  # found by content
    assert isinstance(layout_of(lab.springs, lab.rest), PlanarLayout)


@pytest.mark.slow
def test_a_scene_traced_whole_steps_as_a_concrete_one():
    """Under ``jit`` over the whole scene the springs are not known: the step sums by
    scatter-adds (a ``ParticleLayout`` without incidence) and gives the same state."""
    lab = C.lab_cloth(dtype=np.float64)
    s = C.State.at_rest(lab)
    integ = C.ImplicitEuler(linear_solver=C.CG())
    want, info = C.step(lab, s, 1 / 60, integ)
    got, info_j = jax.jit(lambda c: C.step(c, s, 1 / 60, integ))(lab)
    np.testing.assert_allclose(got.x, want.x, rtol=0, atol=1e-12)
    assert int(info_j.newton_iters) == int(info.newton_iters) and bool(info_j.converged)
    traced = []
    jax.eval_shape(lambda c: traced.append(layout_of(c.springs, c.rest)), lab)
    assert isinstance(traced[0], ParticleLayout) and traced[0].incidence is None
