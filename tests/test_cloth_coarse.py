"""The two-level preconditioner: aggregation, symmetry and definiteness, and the step it serves."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import cloth as C
from jaxsim.cloth._implicit import coarse as _coarse
from jaxsim.cloth._implicit import problem as _problem
from jaxsim.cloth._implicit.hessian import block_jacobi, particle_blocks
from jaxsim.cloth._layout import PlanarLayout, batch_layout, layout_of, spring_sum
from jaxsim.cloth._layout import aggregates as agg

from _helpers import as_users_compile, stiff_grid


def aggregates(c):
    """``(ids (N,), count)``: the two-level preconditioner's aggregates of ``c``'s layout."""
    lay = layout_of(c.springs, c.rest)
    if isinstance(lay, PlanarLayout):
        return agg.block_ids(lay.stencil.rows, lay.stencil.cols, lay.block), lay.num_aggregates
    return np.asarray(lay.aggregates), lay.num_aggregates


def test_aggregates_partition_the_particles():
    for n in (1, 3, 10, 31):
        c = C.grid(n, 0.2)
        ids, count = aggregates(c)
        assert ids.shape == (c.num_particles,) and count <= agg.MAX_AGGREGATES
        assert set(ids.tolist()) == set(range(count))  # every aggregate is used
    sizes = np.bincount(aggregates(C.grid(31, 0.2))[0])
    assert sizes.tolist() == [16] * 64  # 4 x 4 blocks on the 32 x 32 grid
    # a mesh that is not a grid, and a line of particles
    ids, count = agg.aggregate(np.random.default_rng(0).normal(size=(500, 3)), 10)
    assert count <= 10 and ids.min() == 0 and ids.max() == count - 1
    ids, count = agg.aggregate(np.c_[np.arange(100.0), np.zeros(100), np.zeros(100)], 8)
    assert count <= 8 and np.all(np.diff(ids) >= 0)
    assert agg.aggregate(np.zeros((1, 3)))[1] == 1
    disk = C.from_mesh(*C.read_obj(C.TABLECLOTH_OBJ))
    ids, count = aggregates(disk)
    assert set(ids.tolist()) == set(range(count)) and count <= agg.MAX_AGGREGATES
    # springs or a rest shape only known inside jit: runs of particle ids, still a partition
    lay = jax.jit(lambda s, r: layout_of(s, r).aggregates)(disk.springs, disk.rest)
    assert set(np.asarray(lay).tolist()) == set(range(agg.MAX_AGGREGATES)) and np.all(np.diff(np.asarray(lay)) >= 0)


@pytest.mark.parametrize("pins", [None, [0, 1, 2, 3, 4, 5, 6, 7]])  # a whole aggregate pinned, too
@pytest.mark.slow
def test_two_level_is_symmetric_positive_definite(pins):
    c = stiff_grid(7, pins=pins)
    s = C.State.at_rest(c)
    x0 = s.x + 0.05 * jax.random.normal(jax.random.PRNGKey(0), s.x.shape)
    p = _problem.StepProblem.build(c, x0, s.v, jnp.asarray(1 / 30))
    w = jnp.zeros_like(x0)  # the step's unknown (any point will do)
    A = _problem.blocks(w, p, project_psd=True)
    free = p.free
    N = c.num_particles
    ids, count = aggregates(c)
    ids = jnp.asarray(ids)
    factor = _coarse.coarse_factor(ids, count, c.springs, A, particle_blocks(p), free[:, 0],
                                   _coarse.least_mass(jax.ops.segment_sum(c.mass * free[:, 0], ids, count), p.h))
    i, j = c.springs[:, 0], c.springs[:, 1]

    def operator(v):  # the CG operator: identity on pins
        w = v * free
        out = spring_sum(c, jnp.einsum("sab,sb->sa", A, w[j] - w[i])) + (c.mass / p.h**2)[:, None] * w
        return out * free + (1.0 - free) * v

    coarse = _coarse.coarse_correction(ids, count, factor, free)
    M = _coarse.two_level(coarse, block_jacobi(p, A), operator)
    E = jnp.eye(3 * N).reshape(3 * N, N, 3)
    Mdense = np.asarray(jax.vmap(M)(E).reshape(3 * N, 3 * N))
    np.testing.assert_allclose(Mdense, Mdense.T, atol=1e-10 * np.abs(Mdense).max())
    assert np.linalg.eigvalsh(0.5 * (Mdense + Mdense.T)).min() > 0
    # a better preconditioner than block Jacobi: a smaller condition number of M A
    Adense = np.asarray(jax.vmap(operator)(E).reshape(3 * N, 3 * N))
    Jdense = np.asarray(jax.vmap(block_jacobi(p, A))(E).reshape(3 * N, 3 * N))

    def cond(P):
        ev = np.linalg.eigvals(P @ Adense).real
        assert ev.min() > 0
        return ev.max() / ev.min()

    assert cond(Mdense) < 0.2 * cond(Jdense)


@pytest.mark.parametrize("k, dtype", [(1e3, np.float64), (1e9, np.float64), (1e3, np.float32)])
def test_coarse_cholesky_factors_in_float32_and_shifts_only_where_ill_conditioned(k, dtype):
    """A float64 coarse matrix is factored in float32: exactly where its conditioning
    allows, shifted where it does not (k = 1e9: no float32 factor of ``Ac`` itself is
    accurate), never failing; the factor comes back in the matrix's dtype with a positive
    diagonal (an SPD preconditioner either way)."""
    c = stiff_grid(15, k, dtype=dtype, pins=[])  # free: the translation has only the mass
    s = C.State.at_rest(c)
    x0 = s.x + 0.01 * jax.random.normal(jax.random.PRNGKey(1), s.x.shape, dtype)
    p = _problem.StepProblem.build(c, x0, s.v, jnp.asarray(1 / 30, dtype))
    A = _problem.blocks(jnp.zeros_like(x0), p, project_psd=True)
    ids, count = aggregates(c)
    ids = jnp.asarray(ids)
    Ac = _coarse.coarse_matrix(ids, count, c.springs, A, particle_blocks(p), p.free[:, 0])
    lam_min = _coarse.least_mass(jax.ops.segment_sum(c.mass * p.free[:, 0], ids, count), p.h)
    ev = np.linalg.eigvalsh(np.asarray(Ac, np.float64))
    assert lam_min <= ev.min() + 64 * np.finfo(dtype).eps * ev.max()  # the bound holds (exactly, for a free translation)
    L, lower = jax.jit(_coarse.cholesky)(Ac, lam_min)
    assert lower and L.dtype == dtype
    L, Ac = np.asarray(L, np.float64), np.asarray(Ac, np.float64)
    assert np.all(np.isfinite(L)) and np.all(np.diag(L) > 0) and np.all(np.triu(L, 1) == 0)
    LLt = L @ L.T
    rel = np.abs(LLt - Ac).max() / np.abs(Ac).max()
    eps32 = np.finfo(np.float32).eps
    if k == 1e3:  # well conditioned: the factor of Ac, to float32's rounding (not float64's in x64)
        assert ev.max() / ev.min() * eps32 < 1e-2
        assert (1e-10 if dtype == np.float64 else 0.0) < rel < 1e-5
    else:  # shifted: the factored matrix's conditioning brought within float32's reach
        assert ev.max() / ev.min() * eps32 > 10
        ev2 = np.linalg.eigvalsh(LLt)
        assert ev2.max() / ev2.min() * eps32 < _coarse.FLOAT32_FACTOR_LIMIT
        assert ev2.min() >= ev.min()  # a positive shift


@pytest.fixture(scope="module")
def stiff_steps():
    c = stiff_grid(11)
    s = C.State.at_rest(c)
    out = {}
    for name, integ in (("jacobi", C.ImplicitEuler(linear_solver=C.CG())),
                        ("two_level", C.ImplicitEuler(linear_solver=C.CG(C.TwoLevel()))),
                        ("fixed cg_tol", C.ImplicitEuler(linear_solver=C.CG(forcing=0.0)))):
        out[name] = jax.jit(lambda s, integ=integ: C.rollout(c, s, 1 / 30, 3, integ))(s)
    return out


@pytest.mark.slow
def test_two_level_step_matches_jacobi_with_fewer_cg_iterations(stiff_steps):
    (sj, ij), (st, it) = stiff_steps["jacobi"], stiff_steps["two_level"]
    assert np.all(np.asarray(ij.converged)) and np.all(np.asarray(it.converged))
    np.testing.assert_allclose(st.x, sj.x, atol=1e-8)
    assert np.sum(it.cg_iters) < 0.5 * np.sum(ij.cg_iters)


def test_forcing_term_saves_cg_iterations_at_equal_results(stiff_steps):
    (sf, inf_f), (sx, inf_x) = stiff_steps["jacobi"], stiff_steps["fixed cg_tol"]
    assert np.all(np.asarray(inf_f.converged)) and np.all(np.asarray(inf_x.converged))
    np.testing.assert_allclose(sf.x, sx.x, atol=1e-8)
    assert np.sum(inf_f.cg_iters) < 0.9 * np.sum(inf_x.cg_iters)
    assert np.sum(inf_f.newton_iters) <= np.sum(inf_x.newton_iters) + 1


@pytest.mark.slow
def test_scene_c_k1e5_hard_step_converges_within_the_default_cap():
    """Scene C 32x32 at k = 1e5 (float64, two-level CG): its fourth step from rest is one
    where the exact Hessian stays indefinite for dozens of Newton iterations.  Falling back
    on the clamped Hessian alone, Newton crept at a relative gradient of 1e-6-1e-5 and
    needed 65 iterations (the default cap is 20); with the shifted exact Hessian first
    (``direction.SHIFT``) every one of these steps converges within the cap."""
    c = stiff_grid(31, k=1e5)
    integ = C.ImplicitEuler(linear_solver=C.CG(C.TwoLevel()))
    _, info = jax.jit(lambda s: C.rollout(c, s, 1 / 30, 5, integ))(C.State.at_rest(c))
    assert np.all(np.asarray(info.converged)), np.asarray(info.newton_iters)
    assert np.all(np.asarray(info.newton_iters) < integ.newton_iters)


@pytest.mark.slow
def test_single_newton_iteration_solves_to_cg_tol():
    c = stiff_grid(5)
    s = C.State.at_rest(c)
    one = [C.step(c, s, 1 / 30, C.ImplicitEuler(linear_solver=C.CG(forcing=f), newton_iters=1, line_search=False))
           for f in (0.0, 0.5)]
    np.testing.assert_array_equal(one[0][0].x, one[1][0].x)
    assert int(one[0][1].cg_iters) == int(one[1][1].cg_iters)


def test_preconditioner_setting_is_checked():
    with pytest.raises(ValueError, match="preconditioner must be cloth.Jacobi"):
        C.CG(preconditioner="multigrid")
    for bad in (1.0, -0.1, "0.1"):
        with pytest.raises(ValueError, match="CG forcing"):
            C.CG(forcing=bad)
    assert hash(C.ImplicitEuler(linear_solver=C.Auto(C.CG(C.TwoLevel())))) != hash(C.ImplicitEuler())


@pytest.mark.slow
def test_batched_scenes_carry_aggregates():
    a, b = stiff_grid(5), stiff_grid(5, k=2e3)
    batch = C.stack_scenes([a, b])
    assert batch_layout(batch.springs, batch.rest) == (layout_of(a.springs, a.rest), False)  # one shared layout
    integ = C.ImplicitEuler(linear_solver=C.CG(C.TwoLevel()))
    states, info = C.batch_rollout(batch, C.State.at_rest(a), 1 / 30, 2, integ)
    assert np.all(np.asarray(info.converged))
    alone, _ = C.rollout(b, C.State.at_rest(b), 1 / 30, 2, integ)
    np.testing.assert_allclose(states.x[1], alone.x, atol=1e-9)


@pytest.mark.slow
def test_newton_trace_logs_every_iteration_and_changes_nothing():
    """``ImplicitEuler(trace=True)``: the same steps and counts as without it; one entry per
    Newton iteration taken (NaN / -1 after), whose CG iterations and halvings sum to the
    step's, whose last relative gradient is the step's, and whose Hessian codes show the
    shifted fallback on the stiff 12x12 grid's first step.  Without it the compiled step
    writes no log."""
    c = stiff_grid(11, k=1e5)
    s0 = C.State.at_rest(c)
    out = {}
    for trace in (False, True):
        integ = C.ImplicitEuler(linear_solver=C.CG(), trace=trace, max_substep_depth=0)  # a trace of one solve
        out[trace] = as_users_compile(lambda s, integ=integ: C.rollout(c, s, 1 / 30, 2, integ), s0)
    (x0, i0), (x1, i1) = out[False], out[True]
    assert i0.trace is None
    # the same iterations and positions to the last bit, compiled as users' code is (the
    # suite's legacy fusion emitters group the two programs' sums apart, and this stiff
    # step's CG counts follow the rounding)
    np.testing.assert_array_equal(x0.x, x1.x)
    for name in ("newton_iters", "cg_iters", "backtracks", "rel_grad"):
        np.testing.assert_array_equal(getattr(i0, name), getattr(i1, name))
    t = i1.trace
    assert t.rel.shape == (2, 20)
    for k in range(2):
        n = int(i1.newton_iters[k])
        assert np.all(np.isfinite(t.rel[k, :n])) and np.all(np.isnan(t.rel[k, n:]))
        assert np.all(t.cg[k, n:] == -1) and np.all(t.hessian[k, n:] == -1)
        assert int(np.sum(t.cg[k, :n])) == int(i1.cg_iters[k])
        assert int(np.sum(t.backtracks[k, :n])) == int(i1.backtracks[k])
        assert float(t.rel[k, n - 1]) == float(i1.rel_grad[k])
        assert float(t.alpha[k, n - 1]) == float(i1.step_size[k])
    assert set(np.asarray(t.hessian[0, : int(i1.newton_iters[0])]).tolist()) == {0, 1}
    clamped = C.ImplicitEuler(linear_solver=C.CG(), project_psd=True, trace=True, max_substep_depth=0)
    _, info = C.step(c, s0, 1 / 30, clamped)
    assert set(np.asarray(info.trace.hessian[: int(info.newton_iters)]).tolist()) == {0}

    def updates(integ):
        return str(jax.make_jaxpr(lambda s: C.step(c, s, 1 / 30, integ))(s0)).count("dynamic_update_slice")

    # (the substep search records its substeps by dynamic_update_slice too: without it)
    assert updates(C.ImplicitEuler(linear_solver=C.CG(), max_substep_depth=0)) == 0 < updates(
        C.ImplicitEuler(linear_solver=C.CG(), trace=True, max_substep_depth=0))
