"""A pytest plugin that counts XLA compilations and their time, per session.

Each process (the xdist controller and every worker) listens to ``jax.monitoring``'s
duration events: tracing a function to a jaxpr, lowering it to StableHLO, and the backend
compile (a persistent-cache hit also passes through the backend compile event, and is
counted apart).  Workers hand their totals to the controller, which prints one line a
kind at the end of the session.  Subprocesses (the CLI demo, the notebooks) are not
counted: their compile work is their own wall time.
"""

from __future__ import annotations

import json
import os

import jax

EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "traces",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lowerings",
    "/jax/core/compile/backend_compile_duration": "compiles",
}
HIT = "/jax/compilation_cache/cache_hits"

_totals: dict[str, list[float]] = {name: [0, 0.0] for name in EVENTS.values()}
_totals["cache_hits"] = [0, 0.0]
#: Backend compiles and their seconds per test file (for finding where the compile work is).
_per_file: dict[str, list[float]] = {}
#: Backend compiles and their seconds per compiled function's name (``jit_broadcast_in_dim``, ...).
_per_name: dict[str, list[float]] = {}
_current = ["(collection)"]


def _on_duration(event: str, secs: float, **kw) -> None:
    name = EVENTS.get(event)
    if name is not None:
        _totals[name][0] += 1
        _totals[name][1] += secs
        if name == "compiles":
            for table, key in ((_per_file, _current[0]), (_per_name, str(kw.get("fun_name", "?")))):
                row = table.setdefault(key, [0, 0.0])
                row[0] += 1
                row[1] += secs


def _on_event(event: str, **_kw) -> None:
    if event == HIT:
        _totals["cache_hits"][0] += 1


jax.monitoring.register_event_duration_secs_listener(_on_duration)
jax.monitoring.register_event_listener(_on_event)


def pytest_runtest_setup(item):
    _current[0] = os.path.basename(str(item.fspath))


def pytest_sessionfinish(session, exitstatus):
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:  # an xdist worker: hand the totals to the controller
        workeroutput["jaxsim_compile_stats"] = json.dumps({"totals": _totals, "files": _per_file, "names": _per_name})


def pytest_testnodedown(node, error):
    out = getattr(node, "workeroutput", {}).get("jaxsim_compile_stats")
    if out:
        out = json.loads(out)
        for name, (n, secs) in out["totals"].items():
            _totals[name][0] += n
            _totals[name][1] += secs
        for table, part in ((_per_file, out["files"]), (_per_name, out["names"])):
            for name, (n, secs) in part.items():
                row = table.setdefault(name, [0, 0.0])
                row[0] += n
                row[1] += secs


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    t = _totals
    line = (f"XLA compile work (all workers): {t['compiles'][0]} backend compiles in "
            f"{t['compiles'][1]:.1f} s ({t['cache_hits'][0]} of them persistent-cache hits), "
            f"{t['traces'][0]} traces in {t['traces'][1]:.1f} s, "
            f"{t['lowerings'][0]} lowerings in {t['lowerings'][1]:.1f} s")
    terminalreporter.write_sep("-", "compile stats")
    terminalreporter.write_line(line)
    path = os.environ.get("JAXSIM_COMPILE_STATS")
    if path:
        def rows(table):
            return {k: {"compiles": v[0], "seconds": round(v[1], 2)}
                    for k, v in sorted(table.items(), key=lambda kv: -kv[1][0])}

        with open(path, "w") as f:
            json.dump({"totals": {k: {"count": v[0], "seconds": round(v[1], 2)} for k, v in t.items()},
                       "files": rows(_per_file), "names": rows(_per_name)}, f, indent=1)
