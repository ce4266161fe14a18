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
    "benchmark": ("etb_gym.benchmark_cli", "run the controller benchmark (PID, sliding mode, RL agents) on an ETB env",
                  "scripts/benchmark.py"),
    "train": ("etb_gym.rl.train", "train a Stable-Baselines3 agent on an ETB env (resumable)", None),
    "diagnose": ("etb_gym.diagnose.cli", "find where recordings and the model disagree, name and fit the "
                 "missing physics", None),
    "prove": ("etb_gym.diagnose.proof", "blind proof of the diagnosis on synthetic recordings with concealed "
              "effects", "scripts/prove_diagnosis.py"),
    "speed": ("etb_gym.speed", "measure steps/s of the envs side by side with Pendulum-v1 and gym-electric-motor",
              "scripts/bench_speed.py"),
    "reproduce": ("etb_gym.paper", "regenerate analogues of the paper's Figs. 8, 12, 13, 14, 15", None),
    "design": ("etb_gym.controllers.design_report", "design the PID and sliding-mode gains on the linearized plant "
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


if __name__ == "__main__":
    sys.exit(main())
