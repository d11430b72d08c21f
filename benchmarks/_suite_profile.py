"""Where the test suite's time goes: a pytest plugin, and its summary.

Per test (each xdist worker appends to one JSON-lines file): wall seconds, the process's
and its children's CPU seconds, and JAX's own durations for tracing, lowering and XLA
compiles (``jax.monitoring`` events; a compile read from the run's compilation cache
counts as its read time), with every compile over half a second by program name::

    SUITE_PROFILE=/tmp/suite.jsonl PYTHONPATH=benchmarks python -m pytest -n 2 -q -p _suite_profile
    python benchmarks/_suite_profile.py /tmp/suite.jsonl

A test that runs a subprocess (the CLI, the notebooks) shows as child CPU; its compiles
are not split out.
"""

from __future__ import annotations

import collections
import json
import os
import resource
import sys
import time

EVENTS = {"trace": "/jax/core/compile/jaxpr_trace_duration",
          "lower": "/jax/core/compile/jaxpr_to_mlir_module_duration",
          "compile": "/jax/core/compile/backend_compile_duration"}
_now: dict = {}
_listening = False


def _listener(event, duration, **kw):
    _now[event] = _now.get(event, 0.0) + duration
    if event == EVENTS["compile"]:
        _now["compiles"] = _now.get("compiles", 0) + 1
        if duration > 0.5:
            _now.setdefault("programs", []).append([kw.get("fun_name"), round(duration, 3)])


def _cpu():
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime, kids.ru_utime + kids.ru_stime


try:
    import pytest
except ImportError:  # the summary needs no pytest
    pytest = None

if pytest is not None:
    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(item, nextitem):
        global _listening
        if not _listening:
            import jax

            jax.monitoring.register_event_duration_secs_listener(_listener)
            _listening = True
        _now.clear()
        t0, c0 = time.time(), _cpu()
        yield
        t1, c1 = time.time(), _cpu()
        rec = {"test": item.nodeid, "worker": os.environ.get("PYTEST_XDIST_WORKER", "-"), "start": t0,
               "wall": t1 - t0, "cpu": c1[0] - c0[0], "child": c1[1] - c0[1],
               **{k: _now.get(e, 0.0) for k, e in EVENTS.items()},
               "compiles": _now.get("compiles", 0), "programs": _now.get("programs", [])}
        with open(os.environ.get("SUITE_PROFILE", "suite_profile.jsonl"), "a") as f:
            f.write(json.dumps(rec) + "\n")


def summary(records: list[dict]) -> dict:
    """Totals (worker-seconds) over ``records``: subprocess tests apart, the in-process
    tests' wall split into compile, trace and lowering, and the rest (running, Python);
    the programs and files that cost most."""
    sub = [r for r in records if r["child"] > 1.0]
    inp = [r for r in records if r["child"] <= 1.0]
    wall = sum(r["wall"] for r in inp)
    parts = {k: sum(r[k] for r in inp) for k in EVENTS}
    programs, counts = collections.Counter(), collections.Counter()
    for r in inp:
        for name, secs in r["programs"]:
            programs[name] += secs
            counts[name] += 1
    files = collections.Counter()
    for r in records:
        files[r["test"].split("::")[0]] += r["wall"]
    workers = collections.defaultdict(list)
    for r in records:
        workers[r["worker"]].append(r)
    return {
        "tests": len(records), "worker_seconds": sum(r["wall"] for r in records),
        "span_per_worker": {w: max(r["start"] + r["wall"] for r in rs) - min(r["start"] for r in rs)
                            for w, rs in sorted(workers.items())},
        "subprocess_tests": {r["test"]: round(r["wall"], 1) for r in sub},
        "in_process": {"tests": len(inp), "wall": wall, **parts,
                       "rest": wall - sum(parts.values()), "compiles": sum(r["compiles"] for r in inp)},
        "programs_over_half_a_second": {n: [counts[n], round(s, 1)] for n, s in programs.most_common(12)},
        "files": {f: round(s, 1) for f, s in files.most_common(15)},
        "tests_longest": {r["test"]: round(r["wall"], 1) for r in sorted(records, key=lambda r: -r["wall"])[:15]},
    }


if __name__ == "__main__":
    recs = [json.loads(line) for line in open(sys.argv[1])]
    print(json.dumps(summary(recs), indent=1))
