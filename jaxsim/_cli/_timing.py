"""Timing the demo's runs: compile time apart from run time."""

from __future__ import annotations

import time

#: JAX's own duration events that make up a first call's compile (tracing, lowering, XLA).
_COMPILE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration",
                   "/jax/core/compile/backend_compile_duration")
_active: list[float] = []


def _listen(event: str, duration: float, **_) -> None:
    if _active and event in _COMPILE_EVENTS:
        _active[-1] += duration


_registered = False


def timed(fn, again: bool = True):
    """Run ``fn`` and return ``(result, compile_s, run_s)``.

    ``again``: run it a second time and time that (cheap runs, where the first call's
    dispatch overheads would matter); else ``run_s`` is the first call less the compile
    time JAX reports for it (long runs, which then run once)."""
    import jax
    import jax.monitoring

    global _registered
    if not _registered:
        jax.monitoring.register_event_duration_secs_listener(_listen)
        _registered = True
    _active.append(0.0)
    t0 = time.perf_counter()
    try:
        out = jax.block_until_ready(fn())
    finally:
        compile_s = _active.pop()
    first = time.perf_counter() - t0
    if not again:
        return out, compile_s, max(first - compile_s, 0.0)
    t1 = time.perf_counter()
    out = jax.block_until_ready(fn())
    return out, first - (time.perf_counter() - t1), time.perf_counter() - t1
