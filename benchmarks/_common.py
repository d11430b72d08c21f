"""Shared benchmark helpers: timing with compile time apart, JSON output."""

from __future__ import annotations

import importlib
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import jax

from jaxsim._host_memory import retained_limit

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def time_call(fn, *args, repeats: int = 7, min_time: float = 0.0, budget: float | None = None):
    """Time ``fn(*args)``: the first call (compile + run) apart from warm runs.

    With ``budget`` (seconds), fewer warm runs are made when one run is slow (at least 1).

    Returns a dict with ``first_s`` (compile + one run), ``compile_s`` (first minus the
    median warm run), ``run_s`` (median warm run), ``best_s`` and ``runs``.
    """
    t0 = time.perf_counter()
    jax.block_until_ready(fn(*args))
    first = time.perf_counter() - t0
    if budget is not None:
        repeats = max(1, min(repeats, int(budget / max(first, 1e-9))))
    runs = []
    t_start = time.perf_counter()
    while len(runs) < repeats or time.perf_counter() - t_start < min_time:
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        runs.append(time.perf_counter() - t0)
    med = statistics.median(runs)
    return {"first_s": first, "compile_s": max(first - med, 0.0), "run_s": med, "best_s": min(runs), "runs": len(runs)}


def time_plain(fn, *args, repeats: int = 3):
    """Median wall time of a plain (numpy) call."""
    runs = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(*args)
        runs.append(time.perf_counter() - t0)
    return {"run_s": statistics.median(runs), "best_s": min(runs), "runs": repeats}


def machine() -> dict:
    return {
        "python": platform.python_version(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "x64": bool(jax.config.jax_enable_x64),
        "retained_host_memory_bytes": retained_limit(),  # jaxsim.retain_host_memory(), if called
    }


def write(name: str, payload: dict) -> str:
    os.makedirs(RESULTS, exist_ok=True)
    path = os.path.join(RESULTS, name + ".json")
    payload = {"benchmark": name, "machine": machine(), "timestamp": time.strftime("%Y-%m-%dT%H:%M:%S"), **payload}
    with open(path, "w") as f:
        json.dump(payload, f, indent=2)
    print(f"wrote {path}")
    return path


def baseline_package(rev: str):
    """``jaxsim`` at git revision ``rev``, imported as ``jaxsim_baseline`` (its imports are relative)."""
    tmp = tempfile.mkdtemp(prefix="jaxsim_ab_")
    tar = subprocess.run(["git", "-C", ROOT, "archive", rev, "jaxsim"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", tmp], input=tar, check=True)
    shutil.move(os.path.join(tmp, "jaxsim"), os.path.join(tmp, "jaxsim_baseline"))
    sys.path.insert(0, tmp)
    return importlib.import_module("jaxsim_baseline")


def run_once(fn, arg) -> float:
    """Seconds for one call of ``fn(arg)``, to ``block_until_ready``."""
    t0 = time.perf_counter()
    jax.block_until_ready(fn(arg))
    return time.perf_counter() - t0


def ab_arguments():
    """The A/B benchmarks' parser: ``--baseline`` (a git revision, default ``HEAD``) and ``--rounds``."""
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--baseline", default="HEAD",
                    help="git revision to compare against (default HEAD: the working tree against its last commit)")
    ap.add_argument("--rounds", type=int, default=5)
    return ap
