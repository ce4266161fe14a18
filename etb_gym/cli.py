"""The ``etb-gym`` console script. Subcommands register themselves in ``SUBCOMMANDS``.

    etb-gym diagnose REC [REC ...] --model 3B --out DIR
"""
from __future__ import annotations

import argparse
import sys


def _add_diagnose(sub):
    from .diagnose.cli import add_arguments, build_parser, run

    p = sub.add_parser("diagnose", help="find where recordings and the model disagree, name and fit the missing physics",
                       description=build_parser().description)
    add_arguments(p)
    p.set_defaults(func=run)


SUBCOMMANDS = [_add_diagnose]


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="etb-gym", description="etb-gym: electronic throttle body plants and tools")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    for add in SUBCOMMANDS:
        add(sub)
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    try:
        a = ap.parse_args(argv)
    except SystemExit as e:         # --help (0) or a usage error (2, message already printed)
        return int(e.code or 0)
    if not getattr(a, "func", None):
        ap.print_help()
        return 2
    return a.func(a)


if __name__ == "__main__":
    sys.exit(main())
