"""IK A/B: this checkout's solvers against a baseline revision's, alternated in one process.

The baseline's ``jaxsim`` package is extracted from git (``git archive REV jaxsim``) and
imported as ``jaxsim_baseline`` beside this checkout's ``jaxsim``.  Each case is compiled
in both (compile times and optimised-HLO fusion counts recorded apart), then timed in
alternating rounds (baseline, current, baseline, current, ...), so machine noise hits
both alike; the paired ratio per round is ``current rate / baseline rate``, and the JSON
keeps every round, the median ratio and its spread.

Cases: the 6-joint unit chain, 100k float32 targets, FABRIK and CCD, exactly 10 sweeps
(the throughput benchmark's headline), unrolled and on the rolled joint loop; the free
humanoid (hands and ankles), 10k sets, 10 sweeps and tol 1e-4 with early exit, and LM to
tol 1e-4 on 1000 of its sets; the humanoid with limits, 1000 sets, FABRIK and CCD and LM to
tol 1e-4 (early exit), and LM with ``seeds=8``; the 7-hinge arm of ``ik_throughput.py``,
1000 float32 targets, FABRIK, CCD and LM to tol 1e-4 (early exit).

Run: ``python benchmarks/ik_ab.py --baseline 93626e0 [--rounds 5]``; writes
``benchmarks/results/ik_ab.json``.
"""

from __future__ import annotations

import os
import statistics
import sys
import time

import warnings

import jax
import jax.numpy as jnp
import numpy as np

#: The cases call ``solve`` with the keywords both revisions take (``early_exit=``, ``unroll=``);
#: since those moved onto the settings objects the current one warns about them, to no purpose here.
warnings.filterwarnings("ignore", "solve\\(.*moved onto the solver's settings", DeprecationWarning)

sys.path.insert(0, os.path.dirname(__file__))
from _common import ab_arguments, baseline_package, run_once, write  # noqa: E402

import jaxsim  # noqa: E402


def random_poses(rng, shape, amp=np.pi):
    ax = rng.normal(size=shape + (3,))
    ax /= np.linalg.norm(ax, axis=-1, keepdims=True)
    ang = amp * rng.uniform(size=shape + (1,))
    return np.concatenate([np.cos(ang / 2), np.sin(ang / 2) * ax], axis=-1)


def arm7(ik, n=1000):
    """``ik_throughput.py``'s 7-hinge arm (float32) and ``n`` targets from in-range angles."""
    from ik_throughput import ARM7_AXES, ARM7_LENGTHS, ARM7_RANGES

    offsets = np.array([[0, 0, 0]] + [[length, 0, 0] for length in ARM7_LENGTHS], np.float32)
    arm = ik.Chain(offsets, limits=tuple(ik.Hinge(a, lo, hi) for a, (lo, hi) in zip(ARM7_AXES, ARM7_RANGES)) + (None,))
    rng = np.random.default_rng(3)
    ang = np.stack([rng.uniform(lo, hi, size=n) for lo, hi in ARM7_RANGES], axis=1)
    q = np.zeros((n, 8, 4), np.float32)
    q[..., 0] = 1.0
    for j, a in enumerate(ARM7_AXES):
        q[:, j, 0] = np.cos(ang[:, j] / 2)
        q[:, j, 1:] = np.sin(ang[:, j] / 2)[:, None] * np.asarray(a)
    return arm, jnp.asarray(np.asarray(ik.fk(arm, q).positions)[:, -1])


def cases(pkg, n_chain, n_sets):
    """``{name: (jitted fn, argument, solves per call)}`` for one package."""
    ik = pkg.ik
    out = {}
    chain = ik.Chain(np.asarray(ik.straight_chain(np.ones(5), direction=(0, 1, 0)).offsets, np.float32))
    rng = np.random.default_rng(0)
    d = rng.normal(size=(n_chain, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = jnp.asarray(d * 5.0 * rng.uniform(0, 1.2, size=(n_chain, 1)) ** (1 / 3), jnp.float32)
    one_model = isinstance(chain, ik.Skeleton)  # this API takes a chain's targets as (..., 1, 3)
    for s in ("fabrik", "ccd"):
        for unroll, label in ((True, ""), (False, " rolled")):
            def f(t, s=s, unroll=unroll):
                return ik.solve(chain, t[:, None] if one_model else t, solver=s, max_iters=10, tol=0.0, unroll=unroll)
            out[f"chain {s}{label} 10 sweeps"] = (jax.jit(f), t, n_chain)
    H = ik.humanoid(np.float32, limits=False)
    eff = tuple(H.index(k) for k in ik.HUMANOID_EFFECTORS)
    T = jnp.asarray(np.asarray(ik.fk(H, random_poses(np.random.default_rng(1), (n_sets, 24))).positions)[:, eff])
    for s in ("fabrik", "ccd"):
        out[f"humanoid {s} 10 sweeps"] = (jax.jit(lambda t, s=s: ik.solve(H, t, solver=s, effectors=eff, max_iters=10,
                                                                          tol=0.0)), T, n_sets)
        out[f"humanoid {s} tol 1e-4"] = (jax.jit(lambda t, s=s: ik.solve(H, t, solver=s, effectors=eff, max_iters=100,
                                                                         tol=1e-4, early_exit=True)), T, n_sets)
    out["humanoid lm tol 1e-4"] = (jax.jit(lambda t: ik.solve(H, t, solver="lm", effectors=eff, max_iters=100, tol=1e-4,
                                                              early_exit=True)), T[:1000], 1000)
    HL = ik.humanoid(np.float32)
    R = ik.project_limits(HL, random_poses(np.random.default_rng(2), (1000, 24)))
    TL = jnp.asarray(np.asarray(ik.fk(HL, R).positions)[:, eff])
    for s, m in (("fabrik", 1000), ("ccd", 1000), ("lm", 1000)):
        out[f"humanoid limits {s} tol 1e-4"] = (jax.jit(lambda t, s=s: ik.solve(HL, t, solver=s, effectors=eff,
                                                                                max_iters=100, tol=1e-4,
                                                                                early_exit=True)), TL[:m], m)
    arm, Ta = arm7(ik)
    for s in ("fabrik", "ccd", "lm"):
        def f(t, s=s):
            return ik.solve(arm, t[:, None], solver=s, effectors=(7,), max_iters=100, tol=1e-4, early_exit=True)
        out[f"arm7 {s} tol 1e-4"] = (jax.jit(f), Ta, 1000)
    lm8 = ik.LevenbergMarquardt(100, 1e-4, seeds=8)
    out["humanoid limits lm seeds=8 tol 1e-4"] = (jax.jit(lambda t: ik.solve(HL, t, solver=lm8, effectors=eff,
                                                                            early_exit=True)), TL, 1000)
    return out


def main():
    ap = ab_arguments()
    ap.add_argument("--n", type=int, default=100_000, help="chain targets")
    ap.add_argument("--sets", type=int, default=10_000, help="free-humanoid target sets")
    ap.add_argument("--only", default=None, help="run only the cases whose name contains this")
    args = ap.parse_args()
    base = baseline_package(args.baseline)
    pkgs = {"baseline": base, "current": jaxsim}
    built = {k: cases(p, args.n, args.sets) for k, p in pkgs.items()}
    rows = []
    for name in built["current"]:
        if args.only and args.only not in name:
            continue
        row = {"case": name, "solves": built["current"][name][2]}
        for k in pkgs:
            fn, arg, _ = built[k][name]
            row[f"{k}_compile_s"] = run_once(fn, arg)
            row[f"{k}_hlo_fusions"] = fn.lower(arg).compile().as_text().count(" fusion(")
            res = fn(arg)
            row[f"{k}_converged"] = float(jnp.mean(res.converged))
            row[f"{k}_mean_iterations"] = float(jnp.mean(res.iterations))
        reps = 1 if "lm" in name else 3  # per round: the best of a few calls
        times = {k: [] for k in pkgs}
        with_numpy = name == "chain fabrik 10 sweeps"  # and ik_throughput.py's numpy FABRIK in the same rounds
        if with_numpy:
            from ik_throughput import numpy_fabrik

            tnp = np.asarray(built["current"][name][1])[:20_000]
            offs = np.asarray(jaxsim.ik.straight_chain(np.ones(5), direction=(0, 1, 0)).offsets, np.float32)
            times["numpy"] = []
        for _ in range(args.rounds):
            for k in pkgs:  # alternated: baseline, current, (numpy,) baseline, current, ...
                fn, arg, _ = built[k][name]
                times[k].append(min(run_once(fn, arg) for _ in range(reps)))
            if with_numpy:
                t0 = time.perf_counter()
                numpy_fabrik(offs, tnp, 10)
                times["numpy"].append((time.perf_counter() - t0) * row["solves"] / len(tnp))  # scaled to the batch
        ratios = [b / c for b, c in zip(times["baseline"], times["current"])]  # current rate / baseline rate
        row.update({f"{k}_solves_per_s": row["solves"] / statistics.median(v) for k, v in times.items()})
        if with_numpy:
            row.update({f"{k}_vs_numpy": statistics.median(n / t for n, t in zip(times["numpy"], times[k]))
                        for k in pkgs})
        row.update({"rounds_s": times, "paired_ratios": ratios, "median_ratio": statistics.median(ratios),
                    "min_ratio": min(ratios), "max_ratio": max(ratios)})
        rows.append(row)
        print(f"{name:32s} baseline {row['baseline_solves_per_s']:12.1f}/s  current {row['current_solves_per_s']:12.1f}/s"
              f"  ratio {row['median_ratio']:.3f} [{row['min_ratio']:.3f}, {row['max_ratio']:.3f}]  fusions "
              f"{row['baseline_hlo_fusions']} -> {row['current_hlo_fusions']}  converged {row['baseline_converged']:.3f}"
              f" / {row['current_converged']:.3f}" + (f"  vs numpy {row['baseline_vs_numpy']:.1f}x / "
                                                         f"{row['current_vs_numpy']:.1f}x" if with_numpy else ""),
              flush=True)
    write("ik_ab" if args.only is None else f"ik_ab_{args.only.replace(' ', '_')}",
          {"baseline": args.baseline, "rounds": args.rounds, "rows": rows})


if __name__ == "__main__":
    main()
