"""The work-queue loop (``_loop.refill_sweeps``) against the masked batch loop it stands in for."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsim import ik
from jaxsim.ik._solvers import lm as _lm, loop as _loop
from jaxsim.ik._solvers.loop import masked_sweeps, refill_sweeps

from _helpers import all_eqns, limited_tree, random_rotations


def _quat_mul(a, b):
    w1, v1, w2, v2 = a[0], a[1:], b[0], b[1:]
    return jnp.concatenate([jnp.array([w1 * w2 - v1 @ v2]), w1 * v2 + w2 * v1 + jnp.cross(v1, v2)])


def _halving(items):
    """A toy sweep: ``x <- a x`` per item, squared error ``x^2``."""
    x, a = items
    return (x * a, a), (x * a) ** 2


@pytest.mark.parametrize("lanes", [1, 3, 7, 40])
def test_refill_sweeps_equals_masked_sweeps(lanes):
    """Items that start done, converge after 1 to 30 sweeps, or never (``a = 1``): each gets
    the state and count of the masked loop, whatever the number of lanes."""
    rng = np.random.default_rng(lanes)
    N, tol, max_iters = 40, 1e-3, 25
    x0 = rng.uniform(0.5, 2.0, N)
    x0[:5] = 1e-4  # done at the start
    a = rng.uniform(0.3, 0.9, N)
    a[5:9] = 1.0  # never within tol: stop at max_iters
    items0 = (jnp.asarray(x0), jnp.asarray(a))
    e2 = jnp.asarray(x0) ** 2
    got, iters = jax.jit(lambda it, e: refill_sweeps(jax.vmap(lambda i: _halving(i)), it, e, tol,
                                                     max_iters=max_iters, lanes=lanes))(items0, e2)
    ref, ref_iters, _ = masked_sweeps(_halving, items0, jnp.sqrt(e2), jnp.zeros(N, jnp.int32), e2 <= tol * tol, tol,
                                      max_iters=max_iters, trace=False, early_exit=True)
    np.testing.assert_array_equal(iters, ref_iters)
    np.testing.assert_array_equal(got[0], ref[0])
    assert np.all(np.asarray(iters)[:5] == 0) and np.all(np.asarray(iters)[5:9] == max_iters)


def _halving_seeds(items):
    x, a, xs, As = items
    return (x * a, a, xs, As), (x * a) ** 2


@pytest.mark.parametrize("lanes", [1, 5, 30])
def test_refill_sweeps_retries_further_starts_where_a_start_fails(lanes):
    """Three starts per item (rates drawn so that some starts never converge): an item runs
    its starts in turn until one converges, keeps it (else the one of least error), and
    counts the sweeps of every start it ran; against a plain loop.  With 30 lanes, about half
    the first starts end together at ``max_iters``, far more than the ``lanes //
    RESTART_SHARE`` restarts computed per sweep: the others wait, and nothing changes."""
    assert 30 // _loop.RESTART_SHARE < 10
    rng = np.random.default_rng(10 + lanes)
    N, S, tol, max_iters = 30, 3, 1e-3, 12
    xs = rng.uniform(0.5, 2.0, (N, S))
    As = np.where(rng.uniform(size=(N, S)) < 0.5, 1.0 - rng.uniform(0.0, 0.05, (N, S)), rng.uniform(0.2, 0.6, (N, S)))
    x_ref, it_ref = np.zeros(N), np.zeros(N, int)
    for i in range(N):
        best, total = None, 0
        for k in range(S):
            x = xs[i, k]
            for n in range(1, max_iters + 1):
                x = x * As[i, k]
                if x * x <= tol * tol:
                    break
            total += n
            if x * x <= tol * tol:
                best = x
                break
            best = x if best is None or x * x < best * best else best
        x_ref[i], it_ref[i] = best, total
    items0 = tuple(jnp.asarray(v) for v in (xs[:, 0], As[:, 0], xs, As))

    def restart(items, k):
        x, a, xs_, As_ = items
        pick = lambda v: jnp.take_along_axis(v, k[:, None], axis=1)[:, 0]  # noqa: E731
        return pick(xs_), pick(As_), xs_, As_

    got, iters = jax.jit(lambda it: refill_sweeps(jax.vmap(_halving_seeds), it, it[0] ** 2, tol, max_iters=max_iters,
                                                  lanes=lanes, seeds=S, restart=restart))(items0)
    np.testing.assert_array_equal(iters, it_ref)
    np.testing.assert_array_equal(got[0], x_ref)
    assert len(set(it_ref.tolist())) > 3 and np.any(np.abs(x_ref) > tol)  # several starts ran; some never met tol


def test_lm_queue_equals_the_vmapped_loop():
    """LM with ``early_exit`` on ``QUEUE_MIN`` sets (a limited tree, orientation targets on one
    effector, some sets solved at the start) runs as a work queue: the same iterations,
    poses and flags as the fixed-length vmapped scan, float64."""
    rng = np.random.default_rng(3)
    sk = limited_tree(rng)
    N = _lm.QUEUE_MIN
    R = np.asarray(ik.project_limits(sk, random_rotations(rng, (N, sk.num_joints), 1.2)))
    fk = ik.fk(sk, R)
    T = np.asarray(fk.positions)[:, [3, 5]]
    # starts near the solutions (LM converges fast and far from chaos, so two programs that
    # round apart take the same sweeps); the first ten are the solutions: no iteration
    turn = random_rotations(rng, R.shape[:2], 0.4)
    start = np.array(ik.project_limits(sk, np.asarray(jax.vmap(jax.vmap(_quat_mul))(R, turn))))
    start[:10] = R[:10]
    orients = np.asarray(fk.rotations)[:, [3, 5]]
    kw = dict(solver=ik.LevenbergMarquardt(40, 1e-8), effectors=(3, 5), rotations=start, orientations=orients,
              orientation_weights=(0.0, 0.3))
    lm = kw.pop("solver")
    queue = ik.solve(sk, T, solver=dataclasses.replace(lm, early_exit=True), **kw)
    scan = ik.solve(sk, T, solver=dataclasses.replace(lm, early_exit=False), **kw)
    np.testing.assert_array_equal(queue.iterations, scan.iterations)
    np.testing.assert_array_equal(queue.converged, scan.converged)
    ok = np.asarray(scan.converged)  # unconverged sets end on a bound or wander: not compared
    assert ok.mean() > 0.5
    np.testing.assert_allclose(np.asarray(queue.rotations)[ok], np.asarray(scan.rotations)[ok], atol=1e-6)
    def prims(early_exit):
        jaxpr = jax.make_jaxpr(lambda t: ik.solve(sk, t, solver=dataclasses.replace(lm, early_exit=early_exit), **kw))(T).jaxpr
        return {e.primitive.name for e in all_eqns(jaxpr)}

    assert "sort" in prims(True) and "sort" not in prims(False)  # the queue orders the sets to solve
    it = np.asarray(queue.iterations)
    assert np.all(it[:10] == 0) and it[10:].max() > 5  # the sets' counts differ: the queue refills


def test_lm_queue_runs_further_starts_only_where_earlier_ones_failed():
    """``seeds=3`` in the queue (``early_exit``, ``QUEUE_MIN`` sets, 4 iterations: no start
    stalls): per set the first start that converged, else the closest, with the iterations
    of the starts it ran; against each start solved alone."""
    from jaxsim.ik._solvers.starts import default_start, extra_starts

    sk = ik.Chain(np.array([[0, 0, 0], [0.5, 0, 0], [0.4, 0, 0], [0.3, 0, 0.0]]),
                  limits=(ik.SwingTwist(1.2), ik.Hinge((0, 0, 1), 0.0, 2.5), ik.Hinge((0, 1, 0), -1.0, 1.0), None))
    rng = np.random.default_rng(3)
    N, K = _lm.QUEUE_MIN, 3
    t = np.asarray(ik.fk(sk, ik.project_limits(sk, random_rotations(rng, (N, 4), 2.0))).positions)[:, -1:]
    starts = np.concatenate([np.asarray(default_start(sk))[None], np.asarray(extra_starts(sk, K))])
    settings = ik.LevenbergMarquardt(4, 1e-6)
    runs = [ik.solve(sk, t, solver=settings, rotations=starts[k]) for k in range(K)]
    many = ik.solve(sk, t, solver=ik.LevenbergMarquardt(4, 1e-6, seeds=K, early_exit=True))
    conv = np.stack([np.asarray(r.converged) for r in runs], axis=1)
    worst = np.stack([np.asarray(r.error).max(-1) for r in runs], axis=1)
    pick = np.where(conv.any(1), np.argmax(conv, axis=1), np.argmin(worst, axis=1))
    ran = np.where(conv.any(1), np.argmax(conv, axis=1) + 1, K)  # starts run per set
    its = np.stack([np.asarray(r.iterations) for r in runs], axis=1)
    assert len(set(pick)) == K and len(set(ran)) == K  # the case tests every choice
    np.testing.assert_array_equal(many.converged, conv.any(1))
    np.testing.assert_array_equal(many.iterations, [its[b, :ran[b]].sum() for b in range(N)])
    np.testing.assert_allclose(many.rotations, np.stack([runs[pick[b]].rotations[b] for b in range(N)]), atol=1e-9)


def test_forward_mode_through_the_queue():
    """``early_exit`` is forward-mode differentiable: ``jax.jvp`` through the queue (128 sets
    of the lab arm) equals it through the scan."""
    arm = ik.lab_arm()
    rng = np.random.default_rng(0)
    t = jnp.asarray(np.asarray(arm.root) + 0.5 * rng.normal(size=(_lm.QUEUE_MIN, 1, 3)))

    def end(tt, early_exit):
        return ik.solve(arm, tt, solver=ik.LevenbergMarquardt(50, 1e-10, early_exit=early_exit)).positions[:, -1]

    v = jnp.full_like(t, 1e-3)
    _, tq = jax.jvp(lambda tt: end(tt, True), (t,), (v,))
    _, ts = jax.jvp(lambda tt: end(tt, False), (t,), (v,))
    assert float(jnp.max(jnp.abs(ts))) > 1e-4  # the tangents are not all zero
    np.testing.assert_allclose(tq, ts, atol=1e-12)
