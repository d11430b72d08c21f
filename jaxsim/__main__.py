"""Command line: python -m jaxsim {demo,report,bench}.

The arguments are parsed before JAX is imported, so --help and typos answer at once."""

from __future__ import annotations

import argparse
import os
import signal
import sys


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jaxsim", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("demo", help="run the lab's scenes and write animations and a summary")
    p.add_argument("--out", default="jaxsim-demo", help="output folder (default: ./jaxsim-demo)")
    p.add_argument("--fast", action="store_true", help="shorter runs of the same scenes (about 1.5 minutes on 2 cores "
                   "with an empty compilation cache)")
    p.add_argument("--force", action="store_true", help="write into --out even if it holds files demo did not write")
    p.add_argument("--no-cache", action="store_true", help="do not use JAX's persistent compilation cache "
                   "(default: on, in $JAX_COMPILATION_CACHE_DIR or ~/.cache/jaxsim/jax)")
    p = sub.add_parser("report", help="write the error-vs-time and stability report")
    p.add_argument("--out", default="jaxsim-report", help="output folder (default: ./jaxsim-report)")
    p.add_argument("--quick", action="store_true", help="small sizes, sections in two processes (about 3 "
                   "minutes on 2 cores with an empty compilation cache)")
    p.add_argument("--force", action="store_true", help="write into --out even if it holds files report did not write")
    p.add_argument("--no-cache", action="store_true", help="do not use JAX's persistent compilation cache")
    p = sub.add_parser("bench", help="run the package's benchmark scripts (source checkout)")
    p.add_argument("names", nargs="*", help="benchmarks to run (none: list them with their last durations)")
    p.add_argument("--all", action="store_true", help="run every benchmark (tens of minutes)")
    args = parser.parse_args(argv)
    from ._cli._out import CLIError

    try:
        if args.command == "bench":
            from ._cli.bench import run

            return run(args.names, run_all=args.all)
        from ._cli import _out
        from ._jobs.cache import enable_compilation_cache

        before = _out.prepare(args.out, args.command, args.force)  # before any work
        interrupted = []

        def checkpoint():
            written = _out.record(args.out, args.command, before)
            if interrupted:  # the interrupt was raised where Python swallows exceptions (a gc callback)
                raise KeyboardInterrupt
            return written

        def on_sigint(signum, frame):
            interrupted.append(signum)
            raise KeyboardInterrupt

        def quiet_unraisable(unraisable):  # the checkpoint raises it again where it can propagate
            if not (interrupted and isinstance(unraisable.exc_value, KeyboardInterrupt)):
                default_unraisable(unraisable)

        default_unraisable, sys.unraisablehook = sys.unraisablehook, quiet_unraisable
        default_sigint = signal.signal(signal.SIGINT, on_sigint)
        try:
            if args.no_cache:  # also for the report's worker processes
                os.environ["JAXSIM_NO_CACHE"] = "1"
            enable_compilation_cache()
            from . import retain_host_memory

            retain_host_memory()  # big cloths' scratch memory is not faulted in again every step
            if args.command == "demo":
                from ._cli.demo import run

                rc = run(out=args.out, fast=args.fast, checkpoint=checkpoint)
            else:
                from ._cli.report import run

                rc = run(out=args.out, quick=args.quick)
            if interrupted:
                raise KeyboardInterrupt
        except BaseException:
            if not interrupted:  # a real error; an interrupt can surface as another error from a cleanup
                raise
            _out.record(args.out, args.command, before)
            print(f"python -m jaxsim {args.command}: interrupted; the files written so far are listed as its own in "
                  f"{args.out}, so running it again there overwrites them", file=sys.stderr)
            return 130
        finally:
            signal.signal(signal.SIGINT, default_sigint)
            sys.unraisablehook = default_unraisable
            overwritten = _out.record(args.out, args.command, before)
            if overwritten:
                print(f"python -m jaxsim {args.command}: --force: overwrote {len(overwritten)} files it had not "
                      f"written: {', '.join(overwritten)}", file=sys.stderr)
        return rc
    except CLIError as e:
        print(f"python -m jaxsim {args.command}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
