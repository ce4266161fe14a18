"""The ``etb-gym`` command: one door to every tool, each subcommand a module's ``main(argv)``.

    etb-gym benchmark  --controller pid --controller smc      reference controllers on ETB-3B-v0
    etb-gym train      --residual smc --out runs/res_3b       an SB3 agent (resumable)
    etb-gym diagnose   rig.csv --model 3B --out diag/         what the model misses in recordings
    etb-gym prove      --seeds 20 --out out/proof             the diagnosis' blind proof
    etb-gym speed                                             steps/s next to Pendulum and gym-electric-motor
    etb-gym reproduce  --out out/paper                        the paper's figure analogues
    etb-gym design                                            PID / SMC design on the linearized plant

The dispatcher imports a subcommand's module only when that subcommand runs (``etb-gym --help`` imports
none), passes it the remaining arguments and returns its exit code. ``etb-gym X --help`` is X's own help.
"""
from __future__ import annotations

import argparse
import importlib
import inspect
import os
import sys

# name -> (module, one line for ``etb-gym --help``, script that did the job before it moved into the package)
COMMANDS: dict[str, tuple[str, str, str | None]] = {
    "benchmark": ("etb_gym.benchmark", "run the controller benchmark (PID, sliding mode, RL agents) on an ETB env",
                  "scripts/benchmark.py"),
    "train": ("etb_gym.rl.train", "train a Stable-Baselines3 agent on an ETB env (resumable)", None),
    "diagnose": ("etb_gym.diagnose.cli", "find where recordings and the model disagree, name and fit the "
                 "missing physics", None),
    "prove": ("etb_gym.diagnose.proof", "blind proof of the diagnosis on synthetic recordings with concealed "
              "effects", "scripts/prove_diagnosis.py"),
    "speed": ("etb_gym.speed", "measure steps/s of the envs side by side with Pendulum-v1 and gym-electric-motor",
              "scripts/bench_speed.py"),
    "reproduce": ("etb_gym.paper", "regenerate analogues of the paper's Figs. 8, 12, 13, 14, 15", None),
    "design": ("etb_gym.controllers.design", "design the PID and sliding-mode gains on the linearized plant "
               "(margins, Bode and step plots)", "scripts/design_controllers.py"),
}


class CommandUnavailable(Exception):
    """A subcommand whose module (or its ``main``) is not part of this installation."""


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser (for ``--help``): the subcommands with their one-line help, nothing imported."""
    ap = argparse.ArgumentParser(prog="etb-gym", description="etb-gym: electronic throttle body plants and tools. "
                                 "Run 'etb-gym COMMAND --help' for a command's options.",
                                 formatter_class=lambda prog: argparse.RawDescriptionHelpFormatter(
                                     prog, max_help_position=16, width=110))
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    for name, (_, text, _) in COMMANDS.items():
        sub.add_parser(name, help=text, add_help=False)
    return ap


def resolve(name: str):
    """The ``main`` of subcommand ``name``; CommandUnavailable with a sentence if this installation lacks it."""
    module, _, script = COMMANDS[name]
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name is None or not module.startswith(exc.name):
            raise                                   # a missing dependency of the module: its own message
        mod = None
    fn = getattr(mod, "main", None)
    if fn is None and name == "diagnose":
        return _legacy_diagnose
    if fn is None:
        where = f"{module}.main" if mod is not None else f"module {module}"
        hint = f"; meanwhile run: python {script} ARGS" if script else ""
        raise CommandUnavailable(f"etb-gym {name}: this installation has no {where} (the command is being moved "
                                 f"into the package){hint}")
    return fn


def _call(fn, name: str, argv: list[str]) -> int:
    """Run a subcommand's ``main`` with ``etb-gym NAME`` as its program name."""
    prog = f"etb-gym {name}"
    try:
        takes_prog = "prog" in inspect.signature(fn).parameters
    except (TypeError, ValueError):
        takes_prog = False
    if takes_prog:
        rc = fn(argv, prog=prog)
    else:
        saved = sys.argv[0]
        sys.argv[0] = prog                          # argparse's default prog is basename(sys.argv[0])
        try:
            rc = fn(argv)
        finally:
            sys.argv[0] = saved
    return 0 if rc is None else int(rc)


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = build_parser()
    if not argv or argv[0] in ("-h", "--help"):
        ap.print_help()
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        ap.error(f"unknown command {name!r}: valid are {', '.join(COMMANDS)}")
    # The command owns its process: let numba's OpenMP pool sleep, not spin, between parallel regions (on a
    # shared machine a spinning thread steals its partner's core, docs/speed.md), unless the user chose.
    # Library imports leave the environment alone; this is set before any subcommand imports numba.
    if not any(k in os.environ for k in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "NUMBA_THREADING_LAYER")):
        os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    try:
        fn = resolve(name)
    except CommandUnavailable as exc:
        print(exc, file=sys.stderr)
        return 2
    return _call(fn, name, rest)


# ------------------------------------------------------------------------------------------------ diagnose
# Today's diagnose command, used until etb_gym.diagnose.cli (with its main) is part of the package.
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



def _legacy_diagnose(argv, prog: str = "etb-gym diagnose") -> int:
    ap = argparse.ArgumentParser(prog=prog.rsplit(" ", 1)[0])
    _add_diagnose(ap.add_subparsers(dest="command"))
    a = ap.parse_args(["diagnose", *argv])
    return a.func(a)


if __name__ == "__main__":
    sys.exit(main())
