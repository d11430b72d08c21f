"""Progress on long work: a heartbeat line every few seconds, with an estimate from the
last run of the same stretch."""

from __future__ import annotations

import json
import os
import threading
import time

from .cache import cache_dir

#: Seconds between heartbeat lines.
EVERY = 5.0


def _store() -> str:
    """The stage timings file, beside the compilation cache it depends on."""
    return os.path.join(cache_dir(), "jaxsim-stage-times.json")


def _load() -> dict:
    try:
        with open(_store()) as f:
            out = json.load(f)
        return out if isinstance(out, dict) else {}
    except (OSError, ValueError):
        return {}


def _save(key: str, seconds: float) -> None:
    times = _load()
    times[key] = seconds
    try:
        os.makedirs(os.path.dirname(_store()), exist_ok=True)
        tmp = f"{_store()}.{os.getpid()}"
        with open(tmp, "w") as f:  # whole or not at all: report sections save from several processes
            json.dump(times, f, indent=1, sort_keys=True)
        os.replace(tmp, _store())
    except OSError:
        pass  # no estimate next time; nothing else depends on it


class Stage:
    """A named stretch of work (a compile, a long loop) that prints a line when it starts,
    one every ``every`` seconds while it runs (elapsed, and the time left if the same
    stretch ran before), and one when it ends.

    Args:
      prefix: the command's tag, e.g. ``"[demo]"``.
      name: what runs, e.g. ``"humanoid: tracking 240 frames"``.
      key: the stretch's identity for the estimate (default ``name``); include the mode.
      every: seconds between heartbeat lines.
    """

    def __init__(self, prefix: str, name: str, key: str | None = None, every: float = EVERY):
        self.prefix, self.name, self.key, self.every = prefix, name, key or name, every
        self.last = _load().get(self.key)
        self._stop = threading.Event()

    def _line(self, elapsed: float) -> str:
        if isinstance(self.last, (int, float)) and self.last > 0:
            left = max(self.last - elapsed, 0.0)
            return (f"{self.prefix} {self.name}: {elapsed:.0f} s, about {left:.0f} s left "
                    f"(the last run took {self.last:.0f} s)")
        return f"{self.prefix} {self.name}: {elapsed:.0f} s (no earlier run to estimate from)"

    def _beat(self) -> None:
        while not self._stop.wait(self.every):
            print(self._line(time.perf_counter() - self.t0), flush=True)

    def __enter__(self):
        self.t0 = time.perf_counter()
        eta = f" (the last run took {self.last:.0f} s)" if isinstance(self.last, (int, float)) else ""
        print(f"{self.prefix} {self.name} ...{eta}", flush=True)
        self._thread = threading.Thread(target=self._beat, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, kind, value, tb):
        self._stop.set()
        self._thread.join()
        seconds = time.perf_counter() - self.t0
        if kind is None:
            _save(self.key, seconds)
            print(f"{self.prefix} {self.name}: done in {seconds:.1f} s", flush=True)
        return False
