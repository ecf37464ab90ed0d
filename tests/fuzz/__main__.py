"""``python -m tests.fuzz --seed S [--scale K] [--only 'ID or glob'] [--keep DIR]``: run fuzz cases
and print the failures (each with its command line and how to run it again)."""

from __future__ import annotations

import argparse
import sys
import tempfile

from tests.fuzz.run import fuzz, report


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m tests.fuzz", description=__doc__)
    p.add_argument("--seed", type=int, nargs="+", default=[0], help="seeds (default: 0)")
    p.add_argument("--scale", type=int, default=1, help="cases per target: K times the CI number (default: 1)")
    p.add_argument("--only", help="a case id or a glob of ids, e.g. 'simulate.activations#0.3' or 'jaw*'")
    p.add_argument("--keep", metavar="DIR", help="work in DIR and keep the cases' files (default: a temporary folder)")
    p.add_argument("--workers", type=int, default=2, help="driver processes (default: 2)")
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="facesim-fuzz-") as tmp:
        cases, results, failures = fuzz(args.keep or tmp, tuple(args.seed), args.scale, args.only, args.workers)
        print(report(cases, results, failures))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
