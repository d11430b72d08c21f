"""Helpers shared by the test modules (no test module imports another)."""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxsim import cloth as C
from jaxsim import anim, ik
from jaxsim.cloth._implicit.substeps import LAST_NEWTON
from jaxsim._report._humanoid import random_poses
from jaxsim.cloth import _step
from jaxsim.cloth._layout import layout_of

#: IK settings objects by the solver's short name.
SETTINGS = {"fabrik": ik.FABRIK, "ccd": ik.CCD, "lm": ik.LevenbergMarquardt}

#: Tolerances per dtype for quantities of order one.
TOL = {np.dtype(np.float32): 1e-5, np.dtype(np.float64): 1e-10}


def random_unit_quaternions(rng, shape):
    q = rng.normal(size=shape + (4,))
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def as_users_compile(fn, *args):
    """``jax.jit(fn)`` compiled for ``args`` with XLA:CPU's default options (the suite's
    processes compile with faster ones, ``_compile_flags``), called on ``args``."""
    from _compile_flags import USERS_COMPILER_OPTIONS

    return jax.jit(fn).lower(*args).compile(compiler_options=USERS_COMPILER_OPTIONS)(*args)


def users_jit(fn):
    """``fn`` jitted with XLA:CPU's default options, compiled once per input shape: for the
    tests that are run-time bound (the suite's faster compile options make slower code)."""
    from _compile_flags import USERS_COMPILER_OPTIONS

    compiled = {}

    def call(*args):
        leaves, tree = jax.tree_util.tree_flatten(args)
        key = (tree, tuple((np.shape(a), getattr(a, "dtype", None) or np.result_type(a)) for a in leaves))
        if key not in compiled:
            compiled[key] = jax.jit(fn).lower(*args).compile(compiler_options=USERS_COMPILER_OPTIONS)
        return compiled[key](*args)

    return call


def quat_matrix(q):
    """The 3x3 rotation matrix of the quaternion ``q (4,)`` (normalised first), NumPy."""
    w, x, y, z = np.asarray(q, float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def fk_reference(parents, offsets, rot, frames=False):
    """Plain NumPy FK by the lab's recursion (rotation matrices): positions ``(J, 3)``, and
    with ``frames`` the global rotation matrices ``(J, 3, 3)`` too."""
    G, P = [], []
    for i, p in enumerate(parents):
        if p < 0:
            G.append(quat_matrix(rot[i]))
            P.append(np.asarray(offsets[0], float))
        else:
            P.append(P[p] + G[p] @ np.asarray(offsets[i], float))
            G.append(G[p] @ quat_matrix(rot[i]))
    return (np.array(P), np.array(G)) if frames else np.array(P)


def all_eqns(jaxpr):
    """Every equation of ``jaxpr``, those of its sub-jaxprs (scan, cond, while) included."""
    for eqn in jaxpr.eqns:
        yield eqn
        for v in eqn.params.values():
            for j in (v if isinstance(v, (list, tuple)) else [v]):
                if hasattr(j, "jaxpr") and hasattr(j.jaxpr, "eqns"):
                    yield from all_eqns(j.jaxpr)
                elif hasattr(j, "eqns"):
                    yield from all_eqns(j)


def step_jaxpr(cloth, integ):
    """The jaxpr of one compiled cloth step of ``cloth`` with ``integ``."""
    fn = functools.partial(_step._step.__wrapped__, integrator=integ)
    layout = layout_of(cloth.springs, cloth.rest)
    return jax.make_jaxpr(fn)(cloth, layout, C.State.at_rest(cloth), jnp.asarray(1 / 60, cloth.dtype)).jaxpr


def stiff_grid(n, k=1e3, dtype=np.float64, pins=None):
    """Scene C's parameters on an (n+1)^2 grid: total mass 1, g = 9.8."""
    kw = {} if pins is None else {"pins": pins}
    return C.grid(n, 0.2, mass=1.0 / (n + 1) ** 2, stiffness=k, gravity=9.8, dtype=dtype, **kw)

#: Unit quaternions, random axis, angle uniform in ``[0, amp]``: ``random_rotations(rng, shape, amp=pi)``.
random_rotations = random_poses


def tree(limits=None):
    """Root, a swing-twist sub-base, a hinge branch ending in a fixed effector, and a
    swing-twist branch ending in a free effector: 6 joints, effectors 3 and 5."""
    offsets = np.array([[0, 0, 0], [0, 1.0, 0], [0.5, 0.3, 0], [0.5, 0, 0], [-0.4, 0.3, 0.1], [-0.5, 0, 0]])
    return ik.Skeleton(parents=(-1, 0, 1, 2, 1, 4), offsets=offsets, limits=limits)


def limited_tree(rng):
    """:func:`tree` with random limits of every kind drawn from ``rng``."""
    f = lambda a, b: float(rng.uniform(a, b))  # noqa: E731
    lo = f(-2, 0.5)
    hinge = ik.Hinge((f(0.2, 1), f(-1, 1), f(-1, 1)), lo, min(lo + f(0.05, 2.5), math.pi))
    sw1 = ik.SwingTwist(f(0.05, 1.5), (f(-2, 0), f(0, 2)))
    sw2 = ik.SwingTwist(f(0.05, 2.5), (f(-1, 0), f(0, 1)), axis=(f(0.2, 1), 0.3, -0.2))
    return tree((None, sw1, hinge, ik.Fixed(), sw2, None))


def synthetic_walk(speed, cadence, phase, dtype, T=240, fps=60.0):
    """A 9-joint biped (hips; hip, knee, ankle, toe per leg) walking along +z: the hips
    swing sinusoidally, so a planted toe slides (its speed is zero only mid-stance).
    Returns the clip and its ``(T, 2)`` stance mask (the hip swinging back)."""
    leg = [[0, -0.45, 0], [0, -0.42, 0], [0, -0.06, 0.13]]
    off = np.array([[0, 0.9, 0], [0.1, -0.05, 0]] + leg + [[-0.1, -0.05, 0]] + leg)
    sk = ik.Skeleton(parents=(-1, 0, 1, 2, 3, 0, 5, 6, 7), offsets=off.astype(dtype),
                     names=("hips", "lhip", "lknee", "lankle", "ltoe", "rhip", "rknee", "rankle", "rtoe"))
    t = np.arange(T) / fps
    w = 2 * np.pi * cadence
    about_x = lambda a: np.stack([np.cos(a / 2), np.sin(a / 2), 0 * a, 0 * a], -1)  # noqa: E731
    rot = np.zeros((T, 9, 4))
    rot[..., 0] = 1.0
    stance = np.zeros((T, 2), bool)
    for f, (j, ph) in enumerate(((1, phase), (5, phase + np.pi))):
        c = np.cos(w * t + ph)
        rot[:, j] = about_x(-speed / (0.93 * w) * np.sin(w * t + ph))  # forward swing is -x
        rot[:, j + 1] = about_x(0.15 + 0.7 * np.maximum(c, 0))  # the knee bends back, more in the swing
        rot[:, j + 2] = about_x(-0.2 * np.maximum(c, 0))
        stance[:, f] = c < -0.2
    root = np.stack([0 * t, 0.9 + 0.01 * np.cos(2 * w * t), speed * t], 1)
    return anim.Motion(skeleton=sk, rotations=rot.astype(dtype), root_positions=root.astype(dtype),
                       frame_time=1 / fps), stance


def tilted_plane_cloth(theta_deg, mu):
    """A 4x4 cloth lying on a plane tilted by ``theta_deg`` about z, friction ``mu`` (float64)."""
    th = np.radians(theta_deg)
    R = np.array([[np.cos(th), -np.sin(th), 0.0], [np.sin(th), np.cos(th), 0.0], [0.0, 0.0, 1.0]])
    V = np.stack(np.meshgrid(np.arange(4) * 0.1, [0.0], np.arange(4) * 0.1, indexing="ij"), -1).reshape(-1, 3) @ R.T
    plane = C.Plane(R @ np.array([0.0, 1.0, 0.0]), -1e-3, friction=mu)
    return C.from_mesh(V, C.grid_triangles(3), stiffness=100.0, density=1.0, colliders=(plane,), dtype=np.float64)


def check_friction_on_a_tilted_plane(integ, theta, mu=0.5):
    """Coulomb's law under ``integ``: every step converges; below ``atan(mu)`` the cloth
    comes to rest, above it it slides with acceleration ``g (sin - mu cos)`` within 5%."""
    c = tilted_plane_cloth(theta, mu)
    states, infos = C.rollout(c, C.State.at_rest(c), 1 / 60, 120, integ)
    assert bool(jnp.all(infos.converged))
    speed = np.linalg.norm(np.asarray(states.v), axis=-1).max(axis=-1)
    if theta < np.degrees(np.arctan(mu)):
        assert speed[-1] < 1e-3, speed[-1]
    else:
        th = np.radians(theta)
        accel = (speed[-1] - speed[59]) / 1.0
        np.testing.assert_allclose(accel, 9.8 * (np.sin(th) - mu * np.cos(th)), rtol=0.05)


def check_batch_equals_loop(scene, integ, steps=2):
    """``batch_rollout`` over two stiffnesses of ``scene`` equals a loop of ``rollout``s."""
    scenes = [C.replace(scene, stiffness=scene.stiffness * k) for k in (1.0, 2.0)]
    s0 = C.State.at_rest(scene)
    states, _ = C.batch_rollout(C.stack_scenes(scenes), s0, 1 / 30, steps, integ)
    for i, sc in enumerate(scenes):
        one, _ = C.rollout(sc, s0, 1 / 30, steps, integ)
        np.testing.assert_allclose(states.x[i], one.x, atol=1e-10)


def check_rollout_grads(scene, integ, steps):
    """``check_grads`` (reverse mode) of a rollout of ``scene`` under ``integ`` in the
    springs' stiffness scale and the initial velocities (float64)."""
    from jax.test_util import check_grads

    s0 = C.State.at_rest(scene)

    def loss(k, v0):
        sc = C.replace(scene, stiffness=scene.stiffness * k)
        states, _ = C.rollout(sc, C.State(s0.x, v0), 1 / 30, steps, integ)
        return jnp.sum(states.x[-1, :, 1] ** 2) + jnp.sum(states.v[-1] ** 2)

    v0 = jnp.zeros_like(s0.x).at[:, 2].set(0.1)
    check_grads(loss, (jnp.asarray(1.0), v0), order=1, modes=("rev",), atol=1e-5, rtol=1e-5)


def check_substeps_converge_a_stiff_rollout(integ, newton_iters, whole):
    """On a stiff 6x6 grid (k = 1e4, 1/36 kg) that ``newton_iters`` Newton iterations do
    not converge, adaptive substeps do; without them every step is ``whole`` substeps
    (the integrator's count for a step not halved) and some step is unconverged."""
    stiff = C.grid(5, 0.2, mass=1 / 36, stiffness=1e4, gravity=9.8, damping=0.0, dtype=np.float64)
    integ = dataclasses.replace(integ, newton_iters=newton_iters, extrapolate=0, max_substep_depth=3)
    _, infos = C.rollout(stiff, C.State.at_rest(stiff), 1 / 30, 8, integ)
    assert bool(jnp.all(infos.converged)) and int(jnp.max(infos.substeps)) > whole
    _, plain = C.rollout(stiff, C.State.at_rest(stiff), 1 / 30, 8, dataclasses.replace(integ, max_substep_depth=0))
    assert not bool(jnp.all(plain.converged))
    assert np.asarray(plain.substeps).tolist() == [whole] * 8


def _sat_axes(P, Q):
    """``(K, 17, 3)`` candidate separating axes of the triangle pairs ``P, Q (K, 3, 3)``:
    both normals, the 9 edge-edge cross products, and each edge crossed with its own
    triangle's normal (the coplanar case)."""
    eP = np.roll(P, -1, axis=1) - P
    eQ = np.roll(Q, -1, axis=1) - Q
    nP = np.cross(eP[:, 0], eP[:, 1])
    nQ = np.cross(eQ[:, 0], eQ[:, 1])
    cross = np.cross(eP[:, :, None, :], eQ[:, None, :, :]).reshape(-1, 9, 3)
    inP = np.cross(nP[:, None, :], eP)
    inQ = np.cross(nQ[:, None, :], eQ)
    return np.concatenate([nP[:, None], nQ[:, None], cross, inP, inQ], axis=1)


def triangle_pairs_intersect(P, Q):
    """``(K,)`` bool: triangles ``P[k]`` and ``Q[k]`` (``(K, 3, 3)``, float64) intersect or touch.

    The separating axis theorem (Gottschalk et al. 1996; Eberly's convex-polyhedra form):
    two triangles are disjoint iff their projections onto one of the 17 axes of
    :func:`_sat_axes` are disjoint.  Independent of the package's edge-triangle test."""
    A = _sat_axes(P, Q)
    norm = np.linalg.norm(A, axis=-1, keepdims=True)
    scale = np.max(np.abs(np.concatenate([P, Q], axis=1)), axis=(1, 2))[:, None, None] + 1e-300
    usable = norm > 1e-12 * scale**2
    A = np.where(usable, A / np.where(usable, norm, 1.0), 0.0)
    pP = np.einsum("kad,ksd->kas", A, P)
    pQ = np.einsum("kad,ksd->kas", A, Q)
    apart = (pP.max(-1) < pQ.min(-1)) | (pQ.max(-1) < pP.min(-1))
    return ~np.any(apart & usable[..., 0], axis=1)


def self_intersections(x, faces):
    """Number of pairs of triangles of ``faces`` without a common vertex that intersect at
    positions ``x (N, 3)`` (numpy, float64, every pair whose boxes overlap)."""
    x = np.asarray(x, np.float64)
    F = np.asarray(faces)
    T = x[F]
    lo, hi = T.min(1), T.max(1)
    i, j = np.triu_indices(len(F), 1)
    near = np.all((lo[i] <= hi[j]) & (lo[j] <= hi[i]), axis=1)
    i, j = i[near], j[near]
    apart = ~np.any(F[i][:, :, None] == F[j][:, None, :], axis=(1, 2))
    i, j = i[apart], j[apart]
    return int(np.sum(triangle_pairs_intersect(T[i], T[j]))) if i.size else 0


def host_bisection(cloth, state, dt, depth, max_depth, plain, colliders=None, pins=None):
    """Recursive bisection by plain steps (``plain``: no substeps) on the host, as
    ``ImplicitEuler(max_substep_depth=max_depth)`` does it compiled:
    ``(state, substeps, newton_iters, converged)``.

    ``colliders``: ``(c0, c1)`` at the start and end of ``[0, dt]``; the scene's at the
    end.  ``pins``: ``(p0, p1)``, the pinned particles' positions ``(K, 3)`` at the start
    and end of ``[0, dt]`` (moving in a straight line), or ``None``.
    """
    s, levels, iters, conv, _ = host_levels(cloth, state, dt, depth, max_depth, plain, colliders, pins)
    return s, len(levels), iters, conv


def host_levels(cloth, state, dt, depth, max_depth, plain, colliders=None, pins=None):
    """:func:`host_bisection` with the accepted substeps' levels and the PCG iterations:
    ``(state, levels, newton_iters, converged, cg_iters)``."""
    scene = cloth if colliders is None else C.replace(cloth, colliders=colliders[1])
    end = None if pins is None else pins[1]
    if depth == max_depth and max_depth > 0:  # the deepest level's budget (substeps.LAST_NEWTON)
        plain = dataclasses.replace(plain, newton_iters=LAST_NEWTON * plain.newton_iters)
    if colliders is None:
        new, info = C.step(scene, state, dt, plain, pins=end)
    else:
        new, info = C.rollout(C.replace(cloth, colliders=colliders[0]), state, dt, 1, plain,
                              colliders=tuple(jax.tree_util.tree_map(lambda a: a[None], colliders[1])),
                              pins=None if end is None else end[None])
        new, info = C.State(new.x[0], new.v[0]), jax.tree_util.tree_map(lambda a: a[0], info)
    iters, cg = int(info.newton_iters), int(info.cg_iters)
    if bool(info.converged) or depth == max_depth:
        return new, [depth], iters, bool(info.converged), cg
    mid = None if colliders is None else halfway(*colliders)
    pmid = None if pins is None else (np.asarray(pins[0]) + np.asarray(pins[1])) / 2
    s1, l1, i1, c1, g1 = host_levels(cloth, state, dt / 2, depth + 1, max_depth, plain,
                                 None if colliders is None else (colliders[0], mid),
                                 None if pins is None else (pins[0], pmid))
    s2, l2, i2, c2, g2 = host_levels(cloth, s1, dt / 2, depth + 1, max_depth, plain,
                                 None if colliders is None else (mid, colliders[1]),
                                 None if pins is None else (pmid, pins[1]))
    return s2, l1 + l2, iters + i1 + i2, c1 and c2, cg + g1 + g2


def host_rollout_bisection(cloth, state, dt, n_steps, max_depth, plain, max_wait=16, pins=None):
    """``rollout``'s adaptive substeps on the host (``_implicit.substeps.remember``): each
    step first attempts the level the step before left, in pieces of ``dt / 2^level``
    bisected by :func:`host_levels`.  After a step whose attempts were all accepted it tries
    one level coarser, unless it waits; a coarser level that failed at once, or cost more
    Newton plus PCG iterations than the step before, sends the next step back and waits
    ``patience`` steps (doubled each time, at most ``max_wait``).  ``pins``: ``(p0, path)``,
    the pinned particles' positions ``(K, 3)`` at the start and ``(n_steps, K, 3)`` at each
    step's end (straight lines within a step), or ``None``.  Per step: ``(state, substeps,
    newton_iters, converged, level)``, ``level`` the next step's."""
    level, trying, wait, patience, last_cost = 0, False, 0, 1, 0
    out, s = [], state
    for t in range(n_steps):
        levels, iters, cg, conv = [], 0, 0, True
        for k in range(2**level):
            piece = None
            if pins is not None:
                a = np.asarray(pins[0]) if t == 0 else np.asarray(pins[1][t - 1])
                b = np.asarray(pins[1][t])
                piece = (a + k / 2**level * (b - a), a + (k + 1) / 2**level * (b - a))
            s, lv, it, cv, g = host_levels(cloth, s, dt / 2**level, level, max_depth, plain, pins=piece)
            levels, iters, cg, conv = levels + lv, iters + it, cg + g, conv and cv
        cost = iters + cg
        paid = trying and levels[0] <= level and cost <= last_cost
        lost = trying and not paid
        wait = patience if lost else max(wait - 1, 0)
        patience = min(2 * patience, max_wait) if lost else (1 if paid else patience)
        grow = all(lv == level for lv in levels) and wait == 0 and min(levels) > 0 and not lost
        nxt = max(min(levels), level + 1) if lost else min(levels) - int(grow)
        level, trying, last_cost = min(max(nxt, 0), max_depth), grow, cost
        out.append((s, len(levels), iters, conv, level))
    return out


def halfway(c0, c1):
    """Colliders halfway between two poses of one structure."""
    return tuple(jax.tree_util.tree_map(lambda a, b: (a + b) / 2, c0, c1))


def compacted(r, chunk: int):
    """``r`` (``_rank_one.RankOne``) with its acting groups (``c != 0``) moved, in order, to
    the first rows, zero rows after them up to a multiple of ``chunk`` rows, and their
    ``count``: the same blocks, laid out as ``_self.terms.blocks`` lays out the pairs'."""
    E = r.c.shape[0]
    rows = -(-E // chunk) * chunk
    on = r.c != 0
    count = jnp.sum(on, dtype=jnp.int32)
    (idx,) = jnp.nonzero(on, size=rows, fill_value=0)
    keep = jnp.arange(rows) < count
    return type(r)(jnp.where(keep[:, None], r.ids[idx], 0), jnp.where(keep[:, None], r.g[idx], 0),
                   jnp.where(keep, r.c[idx], 0), count, chunk)
