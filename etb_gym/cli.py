"""The ``etb-gym`` console script. Subcommands register themselves in ``SUBCOMMANDS``.

    etb-gym diagnose REC [REC ...] --model 3B --out DIR
"""
from __future__ import annotations

import argparse
import sys


def _add_diagnose(sub):
    from .diagnose.candidates import CANDIDATES
    from .plant import MODELS

    p = sub.add_parser("diagnose", help="find where recordings and the model disagree, name and fit the missing physics",
                       description="Calibrate the model to test-rig recordings, locate the mismatch, add candidate "
                                   "effects, and write report.json, report.md, PNGs and calibrated_plant.toml.")
    p.add_argument("recordings", nargs="+", metavar="REC", help="recording files (.csv, .npz, .mat); see docs/recordings.md")
    p.add_argument("--model", default="3B", type=str.upper, choices=MODELS, help="nominal model (default 3B)")
    p.add_argument("--plant", default=None, help="start from this plant file (.toml/.json) instead of --model")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--candidates", nargs="+", default=None, metavar="ID", choices=list(CANDIDATES),
                   help="restrict the library (default: all): " + ", ".join(CANDIDATES))
    p.add_argument("--max-effects", type=int, default=3, help="at most this many effects (default 3)")
    p.add_argument("--jobs", type=int, default=2, help="parallel fits (default 2)")
    p.add_argument("--sensor-resolution-deg", type=float, default=None,
                   help="the resolution the model assumes for the angle sensor (default 90/4096 deg)")
    p.add_argument("--substeps", type=int, default=None,
                   help="integrator substeps per sample (default: chosen so the model's own error stays below "
                        "half the noise floor, 20..160)")
    p.add_argument("--quiet", action="store_true", help="no progress bar, summary only")
    p.set_defaults(func=_run_diagnose)


def _run_diagnose(a) -> int:
    from pathlib import Path

    from .diagnose import Options, diagnose
    from .diagnose.report import summary
    from .recordings import RecordingError

    kw = {}
    if a.candidates:
        kw["candidates"] = tuple(a.candidates)
    if a.sensor_resolution_deg is not None:
        kw["sensor_resolution_deg"] = a.sensor_resolution_deg
    if a.max_effects < 0 or a.jobs < 1:
        print("etb-gym diagnose: --max-effects must be >= 0 and --jobs >= 1", file=sys.stderr)
        return 2
    if a.substeps is not None:
        if a.substeps < 1:
            print(f"etb-gym diagnose: --substeps {a.substeps}: expected a positive integer", file=sys.stderr)
            return 2
        kw["substeps"] = a.substeps
    plant = None
    if a.plant:
        from .plantfile import load_plant
        plant = load_plant(a.plant)
    opts = Options(model=a.model, plant=plant, max_effects=a.max_effects, jobs=a.jobs, progress=not a.quiet,
                   verbose=not a.quiet, **kw)
    try:
        res = diagnose(a.recordings, out=Path(a.out), options=opts)
    except RecordingError as e:
        print(f"etb-gym diagnose: {e}", file=sys.stderr)
        return 2
    print(summary(res))
    print(f"report: {Path(a.out) / 'report.md'}  (report.json, calibrated_plant.toml, PNGs beside it)")
    return 0


SUBCOMMANDS = [_add_diagnose]


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="etb-gym", description="etb-gym: electronic throttle body plants and tools")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    for add in SUBCOMMANDS:
        add(sub)
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    a = ap.parse_args(argv)
    if not getattr(a, "func", None):
        ap.print_help()
        return 2
    return a.func(a)


if __name__ == "__main__":
    sys.exit(main())
