"""Command line: ``python -m jaxsim {demo,report,bench}``."""

from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m jaxsim", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("demo", help="run the lab's scenes and write animations and a summary")
    p.add_argument("--out", default="jaxsim-demo", help="output folder (default: ./jaxsim-demo)")
    p.add_argument("--fast", action="store_true", help="shorter runs (under a minute)")
    p = sub.add_parser("report", help="write the error-vs-time and stability report")
    p.add_argument("--out", default="jaxsim-report", help="output folder (default: ./jaxsim-report)")
    p.add_argument("--quick", action="store_true", help="small sizes (under two minutes)")
    p = sub.add_parser("bench", help="run the benchmark scripts in benchmarks/")
    p.add_argument("names", nargs="*", help="benchmarks to run (default: all)")
    args = parser.parse_args(argv)
    if args.command == "demo":
        from ._cli.demo import run

        return run(out=args.out, fast=args.fast)
    if args.command == "report":
        from ._cli.report import run

        return run(out=args.out, quick=args.quick)
    from ._cli.bench import run

    return run(args.names)


if __name__ == "__main__":
    sys.exit(main())
