import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from jax.test_util import check_grads

from jaxsim import cloth as C


@pytest.fixture(scope="module")
def lab():
    return C.lab_cloth(dtype=np.float64)


def perturbed(c, scale, seed=0):
    rng = np.random.default_rng(seed)
    return np.asarray(c.rest) + scale * rng.normal(size=c.rest.shape)


def test_lab_scene(lab):
    assert lab.num_particles == 121 and lab.num_springs == 618
    np.testing.assert_allclose(lab.rest[3 * 11 + 7], [0.6, 1.5, 0.2 * 7 - 1])
    assert np.flatnonzero(np.asarray(lab.pinned)).tolist() == [0, 10]
    np.testing.assert_allclose(lab.mass, 1.0)
    np.testing.assert_allclose(lab.stiffness, 100.0)
    np.testing.assert_allclose(lab.gravity, [0, -0.3, 0])
    assert float(lab.damping) == pytest.approx(0.2) and lab.damped
    springs, kind = C.grid_springs(10)
    assert np.bincount(kind).tolist() == [220, 200, 198]
    L = np.asarray(lab.rest_length)
    np.testing.assert_allclose(sorted(set(np.round(L, 9))), [0.2, np.round(0.2 * np.sqrt(2), 9), 0.4])


def bad_cloth_kwargs(lab):
    base = dict(rest=np.asarray(lab.rest), springs=np.asarray(lab.springs), rest_length=np.asarray(lab.rest_length),
                stiffness=np.asarray(lab.stiffness), mass=np.asarray(lab.mass), pinned=np.asarray(lab.pinned),
                gravity=np.asarray(lab.gravity), damping=np.asarray(0.2))
    rest_nan = base["rest"].copy()
    rest_nan[3, 1] = np.nan
    rest_inf = base["rest"].copy()
    rest_inf[0, 0] = np.inf
    mass0 = base["mass"].copy()
    mass0[5] = 0.0
    massneg = base["mass"].copy()
    massneg[5] = -1.0
    springs_oob = base["springs"].copy()
    springs_oob[0, 1] = 121
    L0 = base["rest_length"].copy()
    L0[2] = 0.0
    return {
        "nan position": ({**base, "rest": rest_nan}, "finite"),
        "inf position": ({**base, "rest": rest_inf}, "finite"),
        "zero mass": ({**base, "mass": mass0}, "mass"),
        "negative mass": ({**base, "mass": massneg}, "mass"),
        "spring out of range": ({**base, "springs": springs_oob}, "spring ids"),
        "zero rest length": ({**base, "rest_length": L0}, "rest_length"),
        "wrong rest shape": ({**base, "rest": base["rest"][:, :2]}, "shape"),
        "wrong mass shape": ({**base, "mass": base["mass"][:-1]}, "mass"),
        "wrong springs shape": ({**base, "springs": base["springs"][:, :1]}, "springs"),
        "negative damping": ({**base, "damping": np.asarray(-1.0)}, "damping"),
    }


@pytest.mark.parametrize("case", list(bad_cloth_kwargs(C.lab_cloth())))
def test_bad_scene_raises(case):
    kwargs, match = bad_cloth_kwargs(C.lab_cloth())[case]
    with pytest.raises(ValueError, match=match):
        C.Cloth(**kwargs)


def test_bad_step_inputs_raise(lab):
    s = C.State.at_rest(lab)
    with pytest.raises(ValueError, match="dt"):
        C.step(lab, s, 0.0, C.ExplicitEuler())
    with pytest.raises(ValueError, match="dt"):
        C.step(lab, s, -0.1, C.ExplicitEuler())
    with pytest.raises(ValueError, match="finite"):
        C.step(lab, C.State(s.x.at[0, 0].set(jnp.nan), s.v), 0.1, C.ExplicitEuler())
    with pytest.raises(ValueError, match="shape"):
        C.step(lab, C.State(s.x[:-1], s.v[:-1]), 0.1, C.ExplicitEuler())
    with pytest.raises(ValueError, match="pin ids"):
        C.grid(3, pins=[0, 16])
    with pytest.raises(ValueError, match="linear_solver must be"):
        C.ImplicitEuler(linear_solver="lu")
    with pytest.raises(ValueError, match="substeps"):
        C.ExplicitEuler(substeps=0)


def test_analytic_hessian_equals_autodiff(lab):
    """(17.27) against jax.hessian of the one energy definition, stretched and compressed springs."""
    for seed, scale in ((0, 0.05), (1, 0.15)):
        x = jnp.asarray(perturbed(lab, scale, seed))
        l = np.linalg.norm(np.diff(np.asarray(x)[np.asarray(lab.springs)], axis=1)[:, 0], axis=-1)
        assert np.any(l < np.asarray(lab.rest_length)) and np.any(l > np.asarray(lab.rest_length))
        H_ad = jax.jit(jax.hessian(C.spring_energy, argnums=1))(lab, x).reshape(363, 363)
        H_an, blocks = C.reference.spring_hessian(lab, x)
        rel = np.max(np.abs(H_ad - H_an)) / np.max(np.abs(H_an))
        assert rel < 1e-9
        A = C.reference.element_blocks(lab, x, project_psd=False)
        np.testing.assert_allclose(A, blocks, rtol=1e-9, atol=1e-9 * np.abs(blocks).max())


def test_cross_check_internals_moved_to_reference():
    """The old names still work for one release, with a DeprecationWarning naming the new place."""
    for name in ("spring_hessian", "element_blocks"):
        with pytest.warns(DeprecationWarning, match=f"jaxsim.cloth.reference.{name}"):
            old = getattr(C, name)
        assert old is getattr(C.reference, name)
        assert name not in C.__all__
    with pytest.raises(AttributeError, match="no attribute 'spring_hessians'"):
        C.spring_hessians  # noqa: B018


def test_linear_solver_settings_and_their_old_keywords():
    """The linear solve is a settings object; the old string keywords give the same (equal,
    equally hashed) settings for one release, with a DeprecationWarning."""
    I = C.ImplicitEuler
    assert I() == I(linear_solver="auto") == I(linear_solver=C.Auto(C.CG(C.Jacobi())))
    assert I().linear(16) == C.Cholesky() and I().linear(17) == C.CG()
    assert I(linear_solver=C.Auto(C.CG(tol=1e-9))).linear(100) == C.CG(tol=1e-9)
    old_new = [(dict(solver="dense"), C.Cholesky()),
               (dict(solver="cg", preconditioner="two_level", cg_tol=1e-8), C.CG(C.TwoLevel(), tol=1e-8)),
               (dict(cg_forcing=0.0, cg_max_iters=9), C.Auto(C.CG(forcing=0.0, max_iters=9)))]
    for old, new in old_new:
        with pytest.warns(DeprecationWarning, match="linear_solver=cloth.Cholesky"):
            a = I(newton_iters=5, **old)
        b = I(newton_iters=5, linear_solver=new)
        assert a == b and hash(a) == hash(b) and a.solver is None
    with pytest.raises(ValueError, match="not both"):
        I(linear_solver=C.CG(), solver="cg")
    with pytest.raises(ValueError, match="solver must be one of"), pytest.warns(DeprecationWarning):
        I(solver="lu")
    with pytest.raises(ValueError, match="preconditioner must be one of"), pytest.warns(DeprecationWarning):
        I(preconditioner="multigrid")
    for bad in (dict(tol=-1.0), dict(max_iters=0), dict(forcing=1.0)):
        with pytest.raises(ValueError, match="CG " + next(iter(bad))):
            C.CG(**bad)
    with pytest.raises(ValueError, match="Auto cg must be"):
        C.Auto(C.Cholesky())


def test_radial_blocks_equal_element_hessian():
    """The radial form ``psi'' e e^T + psi'/l (I - e e^T)`` (+ damping) is jax.hessian of the element."""
    from jaxsim.cloth._model import energy as en

    rng = np.random.default_rng(7)
    S = 64
    d0 = rng.normal(size=(S, 3))
    l0 = np.linalg.norm(d0, axis=-1)
    L = l0 * rng.uniform(0.5, 1.5, S)  # stretched and compressed
    k = rng.uniform(1.0, 1e3, S)
    dd = 0.1 * rng.normal(size=(S, 3))
    e0 = d0 / l0[:, None]
    for damp in (None, 0.7):
        args = (d0, l0, l0 - L, k, e0, damp) if damp is not None else (d0, l0, l0 - L, k)
        hess = jax.hessian(en.step_element)
        axes = (0, 0, 0, 0, 0, 0, None)[:len(args) + 1]
        H = jax.jit(jax.vmap(hess, in_axes=axes))(jnp.asarray(dd), *map(jnp.asarray, args))
        A = en.blocks_from_elements(d0, l0, l0 - L, k, jnp.asarray(dd), *((e0, damp) if damp else ()),
                                    project_psd=False)
        np.testing.assert_allclose(A, H, rtol=1e-12, atol=1e-12 * np.abs(H).max())
        P = en.blocks_from_elements(d0, l0, l0 - L, k, jnp.asarray(dd), *((e0, damp) if damp else ()),
                                    project_psd=True)
        assert np.min(np.linalg.eigvalsh(np.asarray(P))) > -1e-9 * np.abs(H).max()
        assert np.min(np.linalg.eigvalsh(np.asarray(A))) < -1.0  # the compressed ones were indefinite
    # a zero-length spring: finite blocks (no NaN), only the along-spring law is lost
    z = en.blocks_from_elements(np.zeros((1, 3)), np.zeros(1), -np.ones(1), np.ones(1), jnp.zeros((1, 3)),
                                project_psd=False)
    assert np.all(np.isfinite(np.asarray(z)))


@pytest.mark.slow
@pytest.mark.parametrize("scene", ["lab", "undamped", "contact"])
def test_radial_gradient_and_scale_equal_autodiff_of_the_objective(scene):
    """Newton's gradient (per-spring forces ``psi'(s) e`` + damping, summed at both ends)
    is ``jax.grad`` of the one objective, and its force scale is the one computed alone."""
    from jaxsim.cloth._implicit import problem as pr

    c = C.lab_cloth(dtype=np.float64)
    if scene == "undamped":
        c = C.replace(c, damping=0.0)
    if scene == "contact":
        c = C.grid(7, 0.1, origin=(-0.35, 0.5, -0.35), gravity=9.8, pins=[0], dtype=np.float64,
                   colliders=(C.Sphere(np.array([0.0, 0.2, 0.0]), 0.29, friction=0.3),))
    rng = np.random.default_rng(3)
    x0 = perturbed(c, 0.01)
    v0 = rng.normal(size=x0.shape)
    p = pr.StepProblem.build(c, jnp.asarray(x0), jnp.asarray(v0), jnp.asarray(1 / 60))
    assert (p.e0 is None) == (scene == "undamped") and (p.contact is None) == (scene != "contact")
    w = -p.prediction + 0.003 * rng.normal(size=x0.shape)
    t = pr.spring_terms(w, p)
    ref = jax.grad(pr.incremental_potential)(w, p)
    np.testing.assert_allclose(pr.gradient(w, p, t), ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
    np.testing.assert_allclose(pr.objective(w, p, t), pr.incremental_potential(w, p), rtol=1e-14)
    np.testing.assert_allclose(pr.force_scale(w, p, t), pr.force_scale(w, p), rtol=1e-14)


def test_projected_blocks_are_psd(lab):
    x = jnp.asarray(perturbed(lab, 0.15, 2))
    A = C.reference.element_blocks(lab, x, project_psd=True)
    assert np.min(np.linalg.eigvalsh(np.asarray(A))) > -1e-9
    A_raw = C.reference.element_blocks(lab, x, project_psd=False)
    assert np.min(np.linalg.eigvalsh(np.asarray(A_raw))) < -1.0  # compressed springs were indefinite


def test_forces_match_lab_formula(lab):
    x = perturbed(lab, 0.05, 3)
    F = np.zeros_like(x)
    for (i, j), L, k in zip(np.asarray(lab.springs), np.asarray(lab.rest_length), np.asarray(lab.stiffness)):
        d = x[j] - x[i]
        l = np.linalg.norm(d)
        f = k * (l - L) * d / l
        F[i] += f
        F[j] -= f
    F += np.asarray(lab.mass)[:, None] * np.asarray(lab.gravity)
    np.testing.assert_allclose(C.forces(lab, jnp.asarray(x)), F, atol=1e-10)


def numpy_lab_explicit(c, x, v, dt, substeps, frames):
    """The lab's explicit reference: v += (g + F/m) ddt, x += v ddt, pins fixed."""
    x, v = np.array(x, float), np.array(v, float)
    springs, L, k = np.asarray(c.springs), np.asarray(c.rest_length), np.asarray(c.stiffness)
    m, g, d = np.asarray(c.mass), np.asarray(c.gravity), float(c.damping)
    pinned = np.asarray(c.pinned)
    h = dt / substeps
    out = []
    for _ in range(frames):
        for _ in range(substeps):
            d01 = x[springs[:, 1]] - x[springs[:, 0]]
            l = np.linalg.norm(d01, axis=1)
            e = d01 / l[:, None]
            v01 = v[springs[:, 1]] - v[springs[:, 0]]
            f = (k * (l - L) + d * np.sum(v01 * e, axis=1))[:, None] * e
            F = np.zeros_like(x)
            np.add.at(F, springs[:, 0], f)
            np.add.at(F, springs[:, 1], -f)
            v = v + (g + F / m[:, None]) * h
            v[pinned] = 0
            x = x + v * h
        out.append(x.copy())
    return np.array(out)


def test_explicit_matches_numpy_lab_loop(lab):
    s = C.State.at_rest(lab)
    states, infos = C.rollout(lab, s, 1 / 60, 5, C.ExplicitEuler(substeps=1000))
    ref = numpy_lab_explicit(lab, s.x, s.v, 1 / 60, 1000, 5)
    np.testing.assert_allclose(states.x, ref, atol=1e-10)
    assert bool(jnp.all(infos.stable))


def scipy_newton_step(c, x0, v0, h, iters=30):
    """Independent reference: Newton on (17.19) with the analytic Hessian in scipy.sparse."""
    springs, L, k = np.asarray(c.springs), np.asarray(c.rest_length), np.asarray(c.stiffness)
    m, g = np.asarray(c.mass), np.asarray(c.gravity)
    free = ~np.asarray(c.pinned)
    fd = np.repeat(free, 3)
    N = len(m)
    y = x0 + h * v0 + h * h * g
    x = x0.copy()
    for _ in range(iters):
        d01 = x[springs[:, 1]] - x[springs[:, 0]]
        l = np.linalg.norm(d01, axis=1)
        e = d01 / l[:, None]
        f = (k * (l - L))[:, None] * e
        gradE = np.zeros_like(x)
        np.add.at(gradE, springs[:, 0], -f)
        np.add.at(gradE, springs[:, 1], f)
        grad = (m[:, None] * (x - y) / h**2 + gradE).reshape(-1)
        eeT = e[:, :, None] * e[:, None, :]
        He = k[:, None, None] * eeT + (k * (1 - L / l))[:, None, None] * (np.eye(3) - eeT)
        rows, cols, vals = [], [], []
        for (i, j), B in zip(springs, He):
            for (a, b, s) in ((i, i, 1), (j, j, 1), (i, j, -1), (j, i, -1)):
                r, cc = np.meshgrid(3 * a + np.arange(3), 3 * b + np.arange(3), indexing="ij")
                rows.append(r.ravel()); cols.append(cc.ravel()); vals.append((s * B).ravel())
        H = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * N, 3 * N)).tocsr()
        H = H + sp.diags(np.repeat(m, 3) / h**2)
        Hf = H[fd][:, fd]
        dx = np.zeros(3 * N)
        dx[fd] = spla.spsolve(Hf.tocsc(), -grad[fd])
        x = x + dx.reshape(N, 3)
        if np.max(np.abs(dx)) < 1e-14:
            break
    return x


@pytest.fixture(scope="module")
def undamped():
    return C.grid(6, 0.2, damping=0.0, dtype=np.float64)


@pytest.mark.slow
def test_converged_step_matches_scipy_reference(undamped):
    c = undamped
    rng = np.random.default_rng(4)
    x0 = np.asarray(c.rest) + 0.02 * rng.normal(size=c.rest.shape)
    x0[np.asarray(c.pinned)] = np.asarray(c.rest)[np.asarray(c.pinned)]
    v0 = 0.3 * rng.normal(size=x0.shape)
    v0[np.asarray(c.pinned)] = 0
    h = 1 / 30
    ref = scipy_newton_step(c, x0, v0, h)
    for linear in (C.Cholesky(), C.CG(tol=1e-13, max_iters=2000)):
        s, info = C.step(c, C.State(jnp.asarray(x0), jnp.asarray(v0)), h,
                         C.ImplicitEuler(linear_solver=linear, tol=1e-12, newton_iters=30))
        assert bool(info.converged) and bool(info.stable)
        np.testing.assert_allclose(s.x, ref, atol=1e-8)


def test_single_newton_step_is_lab_17_23(undamped):
    """newton_iters=1 without line search: H_g(x^k) (x^{k+1} - x^k) = -grad g(x^k), exactly."""
    c = undamped
    rng = np.random.default_rng(5)
    x0 = np.asarray(c.rest) + 0.01 * rng.normal(size=c.rest.shape)
    x0[np.asarray(c.pinned)] = np.asarray(c.rest)[np.asarray(c.pinned)]
    v0 = np.zeros_like(x0)
    h = 1 / 60
    ref = scipy_newton_step(c, x0, v0, h, iters=1)
    s, info = C.step(c, C.State(jnp.asarray(x0), jnp.asarray(v0)), h,
                     C.ImplicitEuler(linear_solver=C.Cholesky(), newton_iters=1, line_search=False, project_psd=False,
                                     max_substep_depth=0))
    assert int(info.newton_iters) == 1
    np.testing.assert_allclose(s.x, ref, atol=1e-12)


@pytest.mark.slow
def test_dense_and_cg_agree(lab):
    s = C.State(jnp.asarray(perturbed(lab, 0.03, 6)).at[np.asarray(lab.pinned)].set(lab.rest[np.asarray(lab.pinned)]),
                jnp.zeros_like(lab.rest))
    a, ia = C.step(lab, s, 1 / 30, C.ImplicitEuler(linear_solver=C.Cholesky(), tol=1e-10, newton_iters=30))
    b, ib = C.step(lab, s, 1 / 30, C.ImplicitEuler(linear_solver=C.CG(tol=1e-12, max_iters=2000), tol=1e-10, newton_iters=30))
    assert int(ib.cg_iters) > 0 and int(ia.cg_iters) == 0
    np.testing.assert_allclose(a.x, b.x, atol=1e-6)


def test_free_fall_matches_backward_euler_recursion():
    c = C.Cloth(rest=np.array([[0.0, 1.0, 0.0], [1.0, 2.0, 0.5]]), springs=np.zeros((0, 2), np.int32),
                rest_length=np.zeros(0), stiffness=np.zeros(0), mass=np.array([1.0, 2.0]),
                pinned=np.zeros(2, bool), gravity=np.array([0.0, -9.8, 0.0]), damping=np.asarray(0.0))
    x, v = np.asarray(c.rest), np.array([[0.1, 0.0, 0.0], [0.0, 1.0, 0.0]])
    h = 0.05
    states, infos = C.rollout(c, C.State(jnp.asarray(x), jnp.asarray(v)), h, 10, C.ImplicitEuler(linear_solver=C.CG()))
    for n in range(10):
        v = v + h * np.array([0, -9.8, 0])
        x = x + h * v
        np.testing.assert_allclose(states.x[n], x, atol=1e-10)
        np.testing.assert_allclose(states.v[n], v, atol=1e-9)


@pytest.mark.slow
def test_stiff_damped_case_implicit_stable_explicit_flagged():
    c = C.grid(10, 0.2, mass=0.5, stiffness=300.0, damping=10.0, dtype=np.float64)
    s = C.State.at_rest(c)
    states, infos = C.rollout(c, s, 1 / 60, 120, C.ImplicitEuler())
    assert bool(jnp.all(infos.stable)) and bool(jnp.all(jnp.isfinite(states.x)))
    e0 = float(C.total_energy(c, s.x, s.v))
    assert float(C.total_energy(c, states.x[-1], states.v[-1])) <= e0
    ex_states, ex_infos = C.rollout(c, s, 1 / 60, 120, C.ExplicitEuler(substeps=1))
    assert not bool(jnp.all(ex_infos.stable))  # detected
    assert bool(jnp.all(jnp.isfinite(ex_states.x))) and bool(jnp.all(jnp.isfinite(ex_states.v)))  # no NaN


@pytest.mark.slow
def test_pins_exactly_fixed_and_grad_check(lab):
    states, _ = C.rollout(lab, C.State.at_rest(lab), 1 / 60, 20, C.ImplicitEuler(linear_solver=C.CG()))
    pinned = np.asarray(lab.pinned)
    assert np.array_equal(np.asarray(states.x[:, pinned]), np.broadcast_to(np.asarray(lab.rest)[pinned], (20, 2, 3)))
    check_grads(lambda x: C.energy(lab, x), (jnp.asarray(perturbed(lab, 0.05, 7)),), order=2, modes=("fwd", "rev"))
