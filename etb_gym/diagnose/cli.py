"""``etb-gym diagnose``: the command line of the diagnosis. Failure modes and exit codes: docs/errors.md.

    etb-gym diagnose REC [REC ...] --model 3B --out DIR [--force]

Every input is checked before the work starts (recordings, plant file, options, the output folder), so a
mistake costs seconds, not a diagnosis. Exit codes:

    0  the diagnosis ran; report.json/report.md/PNGs/calibrated_plant.toml are in --out (any verdict)
    2  an input or option is unusable (nothing written; the message names the file/option and the expectation)
    3  the inputs were fine but the diagnosis could not proceed: --out/report.json has verdict "failed" and
       the reason, report.md says so
    130 interrupted (Ctrl-C); nothing new is written
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

EXIT_OK, EXIT_INPUT, EXIT_FAILED, EXIT_INTERRUPTED = 0, 2, 3, 130
PROG = "etb-gym diagnose"


class InputError(ValueError):
    """An unusable input or option; the message is one sentence naming it."""


# ------------------------------------------------------------------------------------------ argument types
def _int_at_least(lo: int, what: str, hi: int | None = None):
    def conv(s: str) -> int:
        try:
            if "_" in s:            # Python reads "1_0" as 10: a mistyped value must not become another one
                raise ValueError(s)
            v = int(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{s!r} is not a whole number: expected {what}") from None
        if v < lo or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"{v}: expected {what}")
        return v
    return conv


def _positive_finite(what: str, hi: float | None = None):
    def conv(s: str) -> float:
        try:
            if "_" in s:
                raise ValueError(s)
            v = float(s)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{s!r} is not a number: expected {what}") from None
        if not (math.isfinite(v) and v > 0) or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"{s}: expected {what}")
        return v
    return conv


def _nonempty(what: str):
    def conv(s: str) -> str:
        if not s.strip():
            raise argparse.ArgumentTypeError(f"{s!r} is empty: expected {what}")
        return s
    return conv


MAX_JOBS = max(8, 2 * (os.cpu_count() or 1))   # --jobs forks this many workers at once: more only thrash
MAX_SUBSTEPS = 1000                             # 1000 per sample: far finer than the truth's 200 (5 us at 1 kHz)
MAX_RESOLUTION_DEG = 10.0                       # a coarser sensor step cannot resolve a throttle's stroke


def add_arguments(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    from ..plant import MODELS
    from .candidates import CANDIDATES

    p.add_argument("recordings", nargs="+", metavar="REC", help="recording files (.csv, .npz, .mat); see docs/recordings.md")
    p.add_argument("--model", default="3B", type=str.upper, choices=MODELS, help="nominal model (default 3B)")
    p.add_argument("--plant", default=None, type=_nonempty("a plant file (.toml/.json)"),
                   help="start from this plant file (.toml/.json) instead of --model")
    p.add_argument("--out", required=True, type=_nonempty("an output folder"),
                   help="output folder (created; must not hold a report unless --force)")
    p.add_argument("--force", action="store_true",
                   help="replace a report already in --out (default: refuse, so no result is lost)")
    p.add_argument("--candidates", nargs="+", default=None, metavar="ID", choices=list(CANDIDATES),
                   help="restrict the library (default: all): " + ", ".join(CANDIDATES))
    p.add_argument("--max-effects", type=_int_at_least(0, "an integer >= 0"), default=3,
                   help="at most this many effects (default 3)")
    p.add_argument("--jobs", type=_int_at_least(1, f"an integer >= 1 and <= {MAX_JOBS}", MAX_JOBS), default=2,
                   help=f"parallel fits (default 2, at most {MAX_JOBS})")
    p.add_argument("--sensor-resolution-deg", default=None,
                   type=_positive_finite(f"a finite angle > 0 deg, at most {MAX_RESOLUTION_DEG:g} deg",
                                         MAX_RESOLUTION_DEG),
                   help="the resolution the model assumes for the angle sensor (default 90/4096 deg)")
    p.add_argument("--substeps", type=_int_at_least(1, f"a positive integer <= {MAX_SUBSTEPS}", MAX_SUBSTEPS),
                   default=None,
                   help="integrator substeps per sample (default: chosen so the model's own error stays below "
                        "half the noise floor, 5..80)")
    p.add_argument("--residual", choices=("auto", "replay", "observer"), default="auto",
                   help="what the model is scored by: the replay of the recorded voltage, or the one-step error of "
                        "an observer pulled towards the measured angle (for closed-loop recordings); auto (default): "
                        "the observer where the recording is detected as closed loop (docs/diagnosis.md)")
    p.add_argument("--rest-not-at-limp-home", action="store_true",
                   help="do not read a sensor offset from a closed loop's unpowered rest before it engages (default: "
                        "the springs hold an unpowered plate at limp-home, so that rest marks limp-home; use this "
                        "flag where the static friction exceeds the springs' preload and a released plate may rest "
                        "away from limp-home, docs/diagnosis-shapes.md)")
    p.add_argument("--quiet", action="store_true", help="no progress bar, summary only")
    return p


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    return add_arguments(argparse.ArgumentParser(
        prog=prog, description="Calibrate the model to test-rig recordings, locate the mismatch, add candidate "
                               "effects, and write report.json, report.md, PNGs and calibrated_plant.toml. "
                               "Exit codes: 0 done, 2 unusable input (nothing written), 3 diagnosis failed "
                               "(report.json says why), 130 interrupted. See docs/errors.md."))


# ------------------------------------------------------------------------------------------ checks before work
def check_out(out: Path, force: bool, inputs=()) -> None:
    """Refuse an --out that is a file, holds a report (unless ``force``), cannot be created or written, or
    would overwrite one of the ``inputs``."""
    from .report import REPORT_FILES

    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is an existing file: expected a folder (new, or one without a report)")
    for anc in out.parents:
        if anc.exists():
            if not anc.is_dir():
                raise InputError(f"--out {out}: {anc} is a file, so the folder cannot be created")
            break
    here = [f for f in REPORT_FILES if (out / f).exists()]
    for p in inputs:
        try:
            rp = Path(p).resolve()
        except OSError:
            continue
        if rp.parent == out.resolve() and rp.name in REPORT_FILES:
            raise InputError(f"--out {out}: the input {p} would be overwritten by the report; choose another --out")
    if here and not force:
        raise InputError(f"--out {out}: already holds a report ({', '.join(here)}): choose a new folder, "
                         f"or add --force to replace it")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"--out {out}: cannot create the folder ({e.strerror or e})") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InputError(f"--out {out}: the folder is not writable")


def _names(paths: list[str]) -> list[str]:
    """Report names of the recordings: the file name, or as many trailing path parts as make them distinct."""
    resolved = [Path(p).resolve() for p in paths]
    seen = {}
    for p, r in zip(paths, resolved):
        if r in seen:
            raise InputError(f"recording {p}: given twice (also as {seen[r]})")
        seen[r] = p
    parts = [r.parts for r in resolved]
    for k in range(1, max(len(x) for x in parts) + 1):
        names = ["/".join(x[-k:]) for x in parts]
        if len(set(names)) == len(names):
            return names
    return [str(r) for r in resolved]


def load_inputs(a):
    """Recordings, plant and options, all checked. Raises InputError/RecordingError (nothing written)."""
    from ..recordings import RecordingError, load_recording
    from .run import Options

    names = _names(a.recordings)
    recs = [load_recording(p, name=n) for p, n in zip(a.recordings, names)]
    dts = [r.dt_s for r in recs]
    if max(dts) - min(dts) > 1e-3 * min(dts):
        listing = ", ".join(f"{r.name} {r.dt_s * 1e3:.6g} ms" for r in recs)
        raise RecordingError(f"the recordings have different sample periods ({listing}): resample them to one "
                             f"rate or diagnose them separately")
    plant = None
    if a.plant:
        from ..plantfile import load_plant
        try:
            plant = load_plant(a.plant)
        except (OSError, ValueError, TypeError) as e:
            msg = str(e)
            raise InputError(f"--plant: {msg}" if str(a.plant) in msg else f"--plant {a.plant}: {msg}") from None
    kw = {}
    if a.candidates:
        kw["candidates"] = tuple(dict.fromkeys(a.candidates))
    if a.sensor_resolution_deg is not None:
        kw["sensor_resolution_deg"] = a.sensor_resolution_deg
    if a.substeps is not None:
        kw["substeps"] = a.substeps
    kw["residual"] = a.residual
    kw["rest_at_limp_home"] = not a.rest_not_at_limp_home
    opts = Options(model=a.model, plant=plant, max_effects=a.max_effects, jobs=a.jobs, progress=not a.quiet,
                   verbose=not a.quiet, **kw)
    check_out(Path(a.out), a.force, inputs=[*a.recordings, *([a.plant] if a.plant else [])])
    return recs, opts


def _diagnose(recs, out: Path, opts):
    """The expensive part (kept separate so tests of the input checks can stop here)."""
    from . import diagnose
    return diagnose(recs, out=out, options=opts)


# ------------------------------------------------------------------------------------------ entry point
def _err(msg: str) -> None:
    print(f"{PROG}: {msg}", file=sys.stderr)


def run(a) -> int:
    from ..recordings import RecordingError
    from .report import summary, write_failed

    try:
        recs, opts = load_inputs(a)
    except (InputError, RecordingError) as e:
        _err(str(e))
        return EXIT_INPUT
    except KeyboardInterrupt:
        _err("interrupted; nothing written")
        return EXIT_INTERRUPTED
    out = Path(a.out)
    try:
        res = _diagnose(recs, out, opts)
    except KeyboardInterrupt:
        _err("interrupted; no report written")
        return EXIT_INTERRUPTED
    except Exception as e:        # noqa: BLE001 -- any failure becomes a "failed" report, never a lost run
        reason = _sentence(e)
        try:
            write_failed(out, reason, model=(opts.plant.model if opts.plant else None) or opts.model,
                         recordings=[r.name for r in recs], exc=e)
        except OSError as w:
            _err(f"the diagnosis could not proceed: {reason}; writing {out / 'report.json'} failed too: {w}")
            return EXIT_FAILED
        _err(f"the diagnosis could not proceed: {reason} (verdict \"failed\" in {out / 'report.json'})")
        return EXIT_FAILED
    print(summary(res))
    print(f"report: {out / 'report.md'}  (report.json, calibrated_plant.toml, PNGs beside it)")
    return EXIT_OK


def _sentence(e: BaseException) -> str:
    msg = " ".join(str(e).split())
    if isinstance(e, (ValueError, FloatingPointError)) and msg:
        return msg
    return f"internal error {type(e).__name__}: {msg or 'no message'} (please report it with report.json)"


def main(argv=None) -> int:
    """``etb-gym diagnose`` without the subcommand word: ``main(["rec.csv", "--out", "d"])``."""
    p = build_parser()
    try:
        a = p.parse_args(argv)
    except SystemExit as e:         # --help (0) or a usage error (2, message already printed)
        return int(e.code or 0)
    return run(a)


if __name__ == "__main__":
    sys.exit(main())
