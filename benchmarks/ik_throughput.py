"""IK throughput: batched FABRIK and CCD on a 6-joint unit-bone chain, 100k float32 targets,
and on the humanoid (hands and ankles as effectors, 10k target sets).

Also the humanoid with its joint limits (FABRIK, CCD and LM to tol 1e-4), and a 4-hinge
chain and a 7-hinge arm with joint ranges against ikpy.

Settings: (a) exactly 10 sweeps (tol=0), (b) tol=1e-4 with max_iters=100.  Baselines in
the same run: a numpy-vectorised FABRIK written here, ``jax.vmap`` of the one-target
solver (batch leading), the rolled joint loop, and ikpy if installed.

Each ``solve`` row also records ``hlo_fusions``, the fusion count of its optimised HLO
(``jax.jit(f).lower(t).compile().as_text()``).

Run: ``python benchmarks/ik_throughput.py [--n 100000] [--only-limits | --only-arm7]``; writes
``benchmarks/results/ik_throughput.json``.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, __import__("os").path.dirname(__file__))
from _common import time_call, time_plain, write  # noqa: E402

from jaxsim import ik  # noqa: E402



def ik_settings(name, **kw):
    """``ik.FABRIK(**kw)`` or ``ik.CCD(**kw)`` by name."""
    return {"fabrik": ik.FABRIK, "ccd": ik.CCD}[name](**kw)

def numpy_fabrik(offsets, targets, iters):
    """Plain numpy FABRIK vectorised over targets (no convergence test): ``(B, J, 3)``."""
    lengths = np.linalg.norm(offsets[1:], axis=-1).astype(targets.dtype)
    J = len(offsets)
    P = np.broadcast_to(np.cumsum(offsets, axis=0).astype(targets.dtype), (len(targets), J, 3)).copy()
    root = P[:, 0].copy()
    for _ in range(iters):
        P[:, -1] = targets
        for i in range(J - 2, -1, -1):
            d = P[:, i] - P[:, i + 1]
            P[:, i] = P[:, i + 1] + lengths[i] * d / np.linalg.norm(d, axis=-1, keepdims=True)
        P[:, 0] = root
        for i in range(1, J):
            d = P[:, i] - P[:, i - 1]
            P[:, i] = P[:, i - 1] + lengths[i - 1] * d / np.linalg.norm(d, axis=-1, keepdims=True)
    return P


def random_targets(n, reach, rng):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return (d * reach * rng.uniform(0.0, 1.2, size=(n, 1)) ** (1 / 3)).astype(np.float32)


def random_poses(rng, shape, amp=np.pi):
    """Unit quaternions of random axis and an angle uniform in ``[0, amp]``."""
    ax = rng.normal(size=shape + (3,))
    ax /= np.linalg.norm(ax, axis=-1, keepdims=True)
    ang = amp * rng.uniform(size=shape + (1,))
    return np.concatenate([np.cos(ang / 2), np.sin(ang / 2) * ax], axis=-1)


def humanoid_case(record, n_sets=10_000):
    """The humanoid with hands and ankles as effectors: target sets by FK of random poses.

    float32 throughput (10 sweeps; tol 1e-4 with early exit), and the float64 share of
    500 sets solved to 1e-4 within 100 sweeps (the test's setting).
    """
    rng = np.random.default_rng(1)
    out = {}
    H32 = ik.humanoid(np.float32, limits=False)
    eff = tuple(H32.index(k) for k in ik.HUMANOID_EFFECTORS)
    T = jnp.asarray(np.asarray(ik.fk(H32, random_poses(rng, (n_sets, H32.num_joints))).positions)[:, eff], jnp.float32)
    for solver in ("fabrik", "ccd"):
        for mode, kw in (("10 sweeps", dict(max_iters=10, tol=0.0)),
                         ("tol 1e-4", dict(max_iters=100, tol=1e-4))):
            fn = jax.jit(lambda t, kw=kw, solver=solver: ik.solve(H32, t, solver=solver, effectors=eff, **kw))
            timing = time_call(fn, T, repeats=3)
            res = fn(T)
            extra = {"effectors": list(ik.HUMANOID_EFFECTORS), "mean_iterations": float(jnp.mean(res.iterations)),
                     "converged_fraction": float(jnp.mean(res.converged))}
            row = record(f"humanoid {solver} {mode} float32", "humanoid " + solver, mode, timing, n_sets, extra)
            out[f"{solver}_{mode.replace(' ', '_')}"] = {k: row[k] for k in ("solves_per_s", "compile_s",
                                                                            "mean_iterations", "converged_fraction")}
    was = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    H64 = ik.humanoid(np.float64, limits=False)
    R = random_poses(np.random.default_rng(4), (500, H64.num_joints))
    T64 = np.asarray(ik.fk(H64, R).positions)[:, eff]
    for solver in ("fabrik", "ccd"):
        res = ik.solve(H64, T64, solver=solver, effectors=eff, max_iters=100, tol=1e-4)
        out[f"{solver}_float64_500_sets"] = {"converged_fraction": float(jnp.mean(res.converged)),
                                              "mean_iterations": float(jnp.mean(res.iterations)),
                                              "mean_iterations_converged": float(jnp.mean(res.iterations[res.converged]))}
        print(f"humanoid {solver} float64 500 sets: {out[f'{solver}_float64_500_sets']}", flush=True)
    jax.config.update("jax_enable_x64", was)
    return out


def limits_case(record, n_sets=1000):
    """The humanoid with its joint limits: all three solvers to tol 1e-4 (<= 100 iterations,
    early exit) on float32 target sets made by FK of random poses projected onto the limits,
    LM from its default start and with four and eight starts (``seeds=4``, ``seeds=8``), and LM on the free
    humanoid for comparison."""
    rng = np.random.default_rng(2)
    out = {}
    H = ik.humanoid(np.float32)
    eff = tuple(H.index(k) for k in ik.HUMANOID_EFFECTORS)
    R = ik.project_limits(H, random_poses(rng, (n_sets, H.num_joints)))
    T = jnp.asarray(np.asarray(ik.fk(H, R).positions)[:, eff], jnp.float32)
    lm = ik.LevenbergMarquardt(100, 1e-4)
    for name, model, solver in (("fabrik", H, ik.FABRIK(100, 1e-4)), ("ccd", H, ik.CCD(100, 1e-4)), ("lm", H, lm),
                                ("lm_seeds4", H, ik.LevenbergMarquardt(100, 1e-4, seeds=4)),
                                ("lm_seeds8", H, ik.LevenbergMarquardt(100, 1e-4, seeds=8)),
                                ("lm_free", ik.humanoid(np.float32, limits=False), lm)):
        fn = jax.jit(lambda t, model=model, solver=solver: ik.solve(model, t, solver=solver, effectors=eff))
        timing = time_call(fn, T, repeats=5)  # every solver on the same sets
        res = fn(T)
        conv = np.asarray(res.converged)
        extra = {"mean_iterations": float(jnp.mean(res.iterations)),
                 "mean_iterations_converged": float(np.mean(np.asarray(res.iterations)[conv])) if conv.any() else None,
                 "converged_fraction": float(conv.mean()),
                 "max_limit_violation_rad": float(jnp.max(ik.limit_violation(H, res.rotations)))}
        row = record(f"humanoid limits {name} tol 1e-4 float32", "humanoid limits " + name, "tol 1e-4", timing,
                     len(T), extra)
        out[name] = {k: row[k] for k in ("solves_per_s", "compile_s", "mean_iterations", "mean_iterations_converged",
                                         "converged_fraction", "max_limit_violation_rad")}
    return out


#: A 7-hinge arm: alternating z and y axes, bones along x with the lengths of a 7-DoF
#: manipulator's links (m; none zero, as a skeleton needs), a manipulator's ranges (rad).
ARM7_AXES = [(0, 0, 1), (0, 1, 0), (0, 0, 1), (0, 1, 0), (0, 0, 1), (0, 1, 0), (0, 0, 1)]
ARM7_LENGTHS = [0.333, 0.1, 0.316, 0.0825, 0.384, 0.088, 0.107]
ARM7_RANGES = [(-2.8, 2.8), (-1.7, 1.7), (-2.8, 2.8), (-3.0, -0.07), (-2.8, 2.8), (-0.01, 3.1), (-2.8, 2.8)]


def hinge_chain_case(record, n=200, axes=None, lengths=None, ranges=None, name="hinge chain", dtype=np.float64,
                     ikpy_n=40):
    """A hinge chain, targets by FK of random in-range angles: our three solvers, and ikpy
    on the same chain when installed.  Default: 4 hinges (axes z, y, z, y; ranges [-2, 2]
    rad; unit bones), float64; the 7-hinge arm: ``ARM7_*``, float32."""
    axes = axes or [(0, 0, 1), (0, 1, 0), (0, 0, 1), (0, 1, 0)]
    H = len(axes)
    lengths = lengths or [1.0] * H
    ranges = ranges or [(-2.0, 2.0)] * H
    x64 = dtype == np.float64
    was = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", x64)
    offsets = np.array([[0, 0, 0]] + [[length, 0, 0] for length in lengths])  # bones along x
    sk = ik.Chain(offsets.astype(dtype), limits=tuple(ik.Hinge(a, lo, hi) for a, (lo, hi) in zip(axes, ranges)) + (None,))
    rng = np.random.default_rng(3)
    ang = np.stack([rng.uniform(lo, hi, size=n) for lo, hi in ranges], axis=1)
    q = np.zeros((n, H + 1, 4))
    q[..., 0] = 1.0
    for j, a in enumerate(axes):
        q[:, j, 0] = np.cos(ang[:, j] / 2)
        q[:, j, 1:] = np.sin(ang[:, j] / 2)[:, None] * np.asarray(a)
    T = np.asarray(ik.fk(sk, q.astype(dtype)).positions)[:, -1]
    out = {}
    prec = "float64" if x64 else "float32"
    for solver in ("fabrik", "ccd", "lm"):
        fn = jax.jit(lambda t, solver=solver: ik.solve(sk, t[:, None], solver=solver, effectors=(H,), max_iters=100,
                                                       tol=1e-4))
        timing = time_call(fn, T, repeats=2)
        res = fn(T)
        row = record(f"{name} {solver} tol 1e-4 {prec}", f"{name} {solver}", "tol 1e-4", timing, n,
                     {"converged_fraction": float(jnp.mean(res.converged)),
                      "mean_iterations": float(jnp.mean(res.iterations))})
        out[solver] = {k: row[k] for k in ("solves_per_s", "compile_s", "converged_fraction", "mean_iterations")}
    try:
        from ikpy.chain import Chain as IkpyChain
        from ikpy.link import OriginLink, URDFLink

        links = [OriginLink()] + [URDFLink(name=f"j{i}", origin_translation=list(offsets[i]),
                                           origin_orientation=[0, 0, 0], rotation=a, bounds=ranges[i])
                                  for i, a in enumerate(axes)]
        links.append(URDFLink(name="end", origin_translation=list(offsets[H]), origin_orientation=[0, 0, 0],
                              joint_type="fixed"))
        kc = IkpyChain(links, active_links_mask=[False] + [True] * H + [False])
        T64 = np.asarray(T, np.float64)
        kc.inverse_kinematics(T64[0])  # warm-up
        t0 = time.perf_counter()
        sols = [kc.inverse_kinematics(t) for t in T64[:ikpy_n]]
        secs = time.perf_counter() - t0
        err = np.array([np.linalg.norm(kc.forward_kinematics(s)[:3, 3] - t) for s, t in zip(sols, T64[:ikpy_n])])
        rows_extra = {"converged_fraction": float(np.mean(err <= 1e-4))}
        record(f"{name} ikpy (scipy) float64", f"{name} ikpy", "default", {"run_s": secs, "compile_s": 0.0},
               ikpy_n, rows_extra)
        out["ikpy"] = {"solves_per_s": ikpy_n / secs, **rows_extra}
    except ImportError:
        print("ikpy not installed: pip install -e '.[bench]' to compare", flush=True)
    jax.config.update("jax_enable_x64", was)
    return out


def arm7_case(record):
    """The 7-hinge arm (``ARM7_*``), 1000 float32 position targets."""
    return hinge_chain_case(record, n=1000, axes=ARM7_AXES, lengths=ARM7_LENGTHS, ranges=ARM7_RANGES,
                            name="7-hinge arm", dtype=np.float32)


def recorder(rows):
    """``record(label, solver, mode, timing, n_solves, extra)``: append a row to ``rows`` and print it."""
    def record(label, solver, mode, timing, n_solves, extra=None):
        row = {"label": label, "solver": solver, "mode": mode, "n": n_solves,
               "solves_per_s": n_solves / timing["run_s"], **timing, **(extra or {})}
        rows.append(row)
        print(f"{label:44s} {row['solves_per_s'] / 1e6:10.5f} M solves/s  run {1e3 * timing['run_s']:9.2f} ms"
              f"  compile {timing['compile_s']:6.2f} s  "
              f"{ {k: row[k] for k in ('converged_fraction', 'mean_iterations') if k in row} }", flush=True)
        return row
    return record


def only_limits(arm7_only=False):
    """Re-run the humanoid-with-limits, hinge-chain and 7-hinge arm cases (or the arm alone);
    replace their rows and summary entries in ``results/ik_throughput.json``, keeping the
    rest of the file."""
    import json
    import os

    path = os.path.join(os.path.dirname(__file__), "results", "ik_throughput.json")
    with open(path) as f:
        old = json.load(f)
    rows = []
    record = recorder(rows)
    summary = {} if arm7_only else {"humanoid_limits": limits_case(record), "hinge_chain": hinge_chain_case(record)}
    summary["arm7"] = arm7_case(record)
    labels = {r["label"] for r in rows}
    # the file's timestamp stays the full run's (the tables date its other rows by it)
    payload = {k: v for k, v in old.items() if k not in ("benchmark", "machine")}
    payload["limits_timestamp"] = time.strftime("%Y-%m-%dT%H:%M:%S")
    payload["rows"] = [r for r in old["rows"] if r["label"] not in labels] + rows
    payload["summary"] = {**old["summary"], **summary}
    write("ik_throughput", payload)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100_000)
    ap.add_argument("--humanoid-sets", type=int, default=10_000)
    ap.add_argument("--only-limits", action="store_true",
                    help="run only the joint-limit cases and update them in the existing JSON")
    ap.add_argument("--only-arm7", action="store_true", help="run only the 7-hinge arm and update it in the JSON")
    args = ap.parse_args()
    if args.only_limits or args.only_arm7:
        return only_limits(arm7_only=args.only_arm7)
    n = args.n
    chain = ik.Chain(np.asarray(ik.straight_chain(np.ones(5), direction=(0, 1, 0)).offsets, np.float32))
    rng = np.random.default_rng(0)
    targets = jnp.asarray(random_targets(n, 5.0, rng))
    rows = []
    record = recorder(rows)

    for solver in ("fabrik", "ccd"):
        for mode, kw in (("10 sweeps", dict(max_iters=10, tol=0.0)), ("tol 1e-4", dict(max_iters=100, tol=1e-4))):
            for unroll, early in ((True, False), (False, False), (True, True)):
                fn = jax.jit(lambda t, kw=kw, unroll=unroll, early=early: ik.solve(
                    chain, t[:, None], solver=ik_settings(solver, unroll=unroll, early_exit=early, **kw)))
                timing = time_call(fn, targets)
                res = fn(targets)
                hlo = fn.lower(targets).compile().as_text()  # optimised HLO: fusions in the whole solve
                extra = {"unrolled": unroll, "early_exit": early, "hlo_fusions": hlo.count(" fusion("),
                         "mean_iterations": float(jnp.mean(res.iterations)),
                         "converged_fraction": float(jnp.mean(res.converged)),
                         "reachable_fraction": float(jnp.mean(res.reachable))}
                record(f"{solver} {mode} solve unroll={unroll} early_exit={early}", solver, mode, timing, n, extra)
            # naive layout: vmap of the one-target solver (batch becomes the leading axis)
            one = {"fabrik": ik.fabrik, "ccd": ik.ccd}[solver]
            vm = jax.jit(jax.vmap(lambda t, kw=kw: one(chain, t, **kw).positions))
            record(f"{solver} {mode} vmap(one-target)", solver, mode, time_call(vm, targets, repeats=3), n)

    humanoid = humanoid_case(record, args.humanoid_sets)
    limits = limits_case(record)
    hinge_chain = hinge_chain_case(record)
    arm7 = arm7_case(record)

    # numpy baseline, 10 sweeps; timed on a slice and scaled (it is linear in n)
    m = min(n, 20_000)
    t_np = time_plain(numpy_fabrik, np.asarray(chain.offsets), np.asarray(targets[:m]), 10)
    np_rate = m / t_np["run_s"]
    rows.append({"label": "numpy fabrik 10 sweeps", "solver": "fabrik", "mode": "10 sweeps", "n": m,
                 "solves_per_s": np_rate, **t_np})
    print(f"{'numpy fabrik 10 sweeps':44s} {np_rate / 1e6:8.3f} M solves/s", flush=True)
    # agreement on reachable targets (ours answers unreachable ones with the straight line at once)
    sub = np.asarray(targets[:2000])
    sub = sub[np.linalg.norm(sub, axis=1) < 4.9][:1000]
    ref = numpy_fabrik(np.asarray(chain.offsets, np.float64), sub.astype(np.float64), 10)
    ours = ik.solve(chain, jnp.asarray(sub)[:, None], solver="fabrik", max_iters=10, tol=0.0)
    agree = float(np.max(np.abs(np.asarray(ours.positions) - ref)))

    ikpy_rate = None
    try:
        from ikpy.chain import Chain as IkpyChain
        from ikpy.link import OriginLink, URDFLink

        links = [OriginLink()]
        for i in range(5):
            for ax in ((1, 0, 0), (0, 0, 1)):
                links.append(URDFLink(name=f"j{i}{ax}", origin_translation=[0, 0, 0] if ax[0] else [0, 1, 0],
                                      origin_orientation=[0, 0, 0], rotation=ax))
        kc = IkpyChain(links)
        k = 50
        t0 = time.perf_counter()
        for t in np.asarray(targets[:k], np.float64):
            kc.inverse_kinematics(t)
        ikpy_rate = k / (time.perf_counter() - t0)
        rows.append({"label": "ikpy inverse_kinematics (2-DoF per joint)", "solver": "ikpy", "mode": "default",
                     "n": k, "solves_per_s": ikpy_rate})
        print(f"{'ikpy':44s} {ikpy_rate:10.1f} solves/s", flush=True)
    except ImportError:
        print("ikpy not installed: pip install -e '.[bench]' to compare", flush=True)

    best = {s: max(r["solves_per_s"] for r in rows if r["solver"] == s and r["mode"] == "10 sweeps" and "solve" in r["label"])
            for s in ("fabrik", "ccd")}
    summary = {
        "fabrik_10_sweeps_solves_per_s": best["fabrik"],
        "ccd_10_sweeps_solves_per_s": best["ccd"],
        "numpy_fabrik_solves_per_s": np_rate,
        "fabrik_speedup_vs_numpy": best["fabrik"] / np_rate,
        "fabrik_speedup_vs_ikpy": None if ikpy_rate is None else best["fabrik"] / ikpy_rate,
        "max_abs_diff_vs_numpy_fabrik": agree,
        "targets": {"fabrik_10": 5e6, "ccd_10": 1.5e6, "vs_numpy": 15.0},
        "humanoid": humanoid,
        "humanoid_limits": limits,
        "hinge_chain": hinge_chain,
        "arm7": arm7,
    }
    print(summary)
    write("ik_throughput", {"n_targets": n, "chain": "6 joints, unit bones", "dtype": "float32", "rows": rows, "summary": summary})


if __name__ == "__main__":
    main()
