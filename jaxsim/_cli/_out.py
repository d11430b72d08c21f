"""Output folders of the CLI commands: never overwrite what the command did not make.

A command writes a manifest ``.jaxsim-<command>`` into its folder listing the files it
wrote, brought up to date as it goes (after each section, and when it stops early, as
on Ctrl-C), so an interrupted run does not block the next one.  A later run may
overwrite those files, but refuses a folder holding any other file unless ``--force``
is given; a forced run names every such file it overwrote, and claims it.  The folder
is created and checked writable before any work.
"""

from __future__ import annotations

import os


class CLIError(Exception):
    """A user error of the command line: printed as one line, exit status 2."""


def _manifest(out: str, command: str) -> str:
    return os.path.join(out, f".jaxsim-{command}")


def _listed(out: str, command: str) -> set[str]:
    try:
        with open(_manifest(out, command)) as f:
            return {line.strip() for line in f if line.strip()}
    except OSError:
        return set()


def _files(out: str) -> dict[str, tuple[int, int]]:
    """Every file under ``out`` with its ``(mtime_ns, size)``."""
    found = {}
    for root, _, names in os.walk(out):
        for n in names:
            path = os.path.join(root, n)
            try:
                st = os.stat(path)
            except OSError:
                continue
            found[os.path.relpath(path, out)] = (st.st_mtime_ns, st.st_size)
    return found


def prepare(out: str, command: str, force: bool) -> dict[str, tuple[int, int]]:
    """Create ``out`` if needed and check it can be written; return the files already
    there, with their modification times and sizes.

    Raises:
      CLIError: ``out`` is a file, cannot be created or written, or holds files that
        this command did not write (without ``force``).
    """
    if os.path.exists(out) and not os.path.isdir(out):
        raise CLIError(f"--out {out!r} is a file, not a folder")
    try:
        os.makedirs(out, exist_ok=True)
    except OSError as e:
        raise CLIError(f"cannot create --out folder {out!r}: {e.strerror or e}") from None
    probe = os.path.join(out, f".jaxsim-write-test-{os.getpid()}")
    try:
        with open(probe, "w") as f:
            f.write("")
        os.remove(probe)
    except OSError as e:
        raise CLIError(f"cannot write into --out folder {out!r}: {e.strerror or e}") from None
    before = _files(out)
    foreign = sorted(set(before) - _listed(out, command) - {os.path.basename(_manifest(out, command))})
    if foreign and not force:
        shown = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
        raise CLIError(f"--out folder {out!r} holds files that `{command}` did not write ({shown}); "
                       f"choose an empty or new folder, or pass --force to write there anyway")
    return before


def record(out: str, command: str, before: dict[str, tuple[int, int]]) -> list[str]:
    """Write the manifest: the files this run created or rewrote (those it found and had
    listed before stay listed; files the user had there and this run left alone are not
    claimed).  Returns the files that were not the command's and that this run
    overwrote (only possible with ``--force``)."""
    listed = _listed(out, command)
    now = _files(out)
    changed = {f for f, stat in now.items() if before.get(f) != stat}
    ours = changed | (listed & set(now))
    ours.discard(os.path.basename(_manifest(out, command)))
    with open(_manifest(out, command), "w") as f:
        f.write("\n".join(sorted(ours)) + "\n")
    return sorted((changed & set(before)) - listed)
