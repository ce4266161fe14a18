#!/usr/bin/env python
"""Train a Stable-Baselines3 agent on an ETB env (resumable; evaluated with the controller benchmark's metrics).

    python scripts/train_rl.py --env ETB-3B-v0 --timesteps 200000 --out runs/sac_3b            # SAC, 8 sub-envs
    python scripts/train_rl.py --algo ppo --n-envs 16 --randomize --out runs/ppo_3b
    python scripts/train_rl.py --residual smc-plain --residual-scale 0.3 --randomize --out runs/res_3b   # residual RL
    python scripts/train_rl.py --resume runs/sac_3b                  # continue an interrupted run (Ctrl-C saves)
    python scripts/train_rl.py --resume runs/sac_3b --timesteps 400000        # ... or extend a finished one
    python scripts/benchmark.py --controller rl:runs/sac_3b --controller pid --controller smc

The baseline in baselines/sac_3b was trained with the command in its README.md. Outputs in --out: config.json,
model.zip, best_model.zip, eval.csv, learning_curve.png, checkpoints/, tb/ (tensorboard --logdir OUT/tb).
See docs/rl.md for the task design (features, reward, action repeat) and the hyperparameters.
"""
from __future__ import annotations

import argparse
import json
import sys
import time


def _hp(text: str):
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"--hp {text!r}: expected KEY=VALUE (VALUE as JSON, e.g. gamma=0.99 or "
                                         "net_arch=[64,64])")
    k, v = text.split("=", 1)
    try:
        val = json.loads(v)
    except json.JSONDecodeError:
        val = v
    return k.strip(), val


def _ranges(text: str):
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
        raise argparse.ArgumentTypeError(f"--randomize {text!r}: not JSON ({exc})") from None
    if not isinstance(d, dict):
        raise argparse.ArgumentTypeError(f"--randomize {text!r}: expected a JSON object {{quantity: [low, high]}}")
    return d


def parse_args(argv=None):
    from etb_gym.envs import ENV_IDS
    from etb_gym.rl import ALGORITHMS, available_algorithms

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__.split("\n\n", 1)[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--env", default=None, help=f"env id, one of {', '.join(ENV_IDS)} (default ETB-3B-v0)")
    p.add_argument("--algo", default=None, help=f"algorithm: {', '.join(available_algorithms())} (default sac; tqc "
                                                "needs sb3-contrib)")
    p.add_argument("--timesteps", type=int, default=None,
                   help="policy decisions to train for, summed over sub-envs (default 100000); with --resume: the "
                        "new total")
    p.add_argument("--n-envs", type=int, default=None, help="sub-envs of the native vector env (default 8)")
    p.add_argument("--seed", type=int, default=None, help="seed of the model, the envs and the references (default 0)")
    p.add_argument("--randomize", nargs="?", const=True, default=None, type=_ranges, metavar="JSON",
                   help="per-episode parameter randomization of the env (supply, coil temperature, friction, "
                        "springs, inertia, sensor noise); optionally a JSON dict overriding some ranges, e.g. "
                        "--randomize '{\"friction_scale\": [0.4, 1.6]}'")
    p.add_argument("--normalize", action="store_true", default=None,
                   help="VecNormalize observations and rewards (off by default: the features are scaled by design)")
    p.add_argument("--action-repeat", type=int, default=None, help="control periods per policy decision (default 2)")
    p.add_argument("--episode-s", type=float, default=None, help="training episode length in s (default 1.5)")
    p.add_argument("--residual", default=None, metavar="BASE",
                   help="residual RL: the policy's action is a bounded correction added to the duty of this classical "
                        "base controller (pid-plain, smc-plain or pid-nocomp: angle-only, designed on the env's nominal model); default: none, "
                        "the policy outputs the duty")
    p.add_argument("--residual-scale", type=float, default=None, metavar="DUTY",
                   help="with --residual: duty = clip(base + SCALE * action, -1, 1), SCALE in (0, 2] (default 0.3)")
    p.add_argument("--hp", type=_hp, action="append", default=[], metavar="KEY=VALUE",
                   help="hyperparameter override (repeatable), e.g. --hp gamma=0.99 --hp net_arch=[256,256]; "
                        f"defaults per algorithm in etb_gym.rl.ALGORITHMS ({', '.join(ALGORITHMS)})")
    p.add_argument("--checkpoint-freq", type=int, default=None, help="timesteps between checkpoints (default 50000)")
    p.add_argument("--eval-freq", type=int, default=None, help="timesteps between evaluations (default 10000; 0: none)")
    p.add_argument("--eval-variant", action="append", default=None, metavar="NAME",
                   help="benchmark plant variant(s) for the evaluation (default nominal)")
    p.add_argument("--time-limit-min", type=float, default=None,
                   help="stop (as finished, with all outputs) once the run has used this many minutes of wall time "
                        "(counted over all its resumes; with --resume: the new budget, 0 = none)")
    p.add_argument("--threads", type=int, default=None, help="torch threads (default 1: the machine is shared)")
    p.add_argument("--out", default=None, help="output folder of a new run (required unless --resume)")
    p.add_argument("--resume", default=None, metavar="DIR", help="continue the run in DIR from its latest checkpoint")
    p.add_argument("--force", action="store_true", help="replace an existing run folder given as --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    a = p.parse_args(argv)
    if a.env is not None and a.env not in ENV_IDS:
        p.error(f"unknown env {a.env!r}: valid are {', '.join(ENV_IDS)}")
    if a.algo is not None and a.algo.lower() not in ALGORITHMS:
        p.error(f"unknown algorithm {a.algo!r}: valid are {', '.join(available_algorithms())}")
    if a.resume and a.out:
        p.error("--resume DIR continues the run in DIR: do not pass --out as well")
    if not a.resume and not a.out:
        p.error("--out DIR is required for a new run (or --resume DIR to continue one)")
    if a.resume and a.force:
        p.error("--force replaces a run folder; it cannot be combined with --resume")
    for name in ("timesteps", "n_envs", "action_repeat", "checkpoint_freq", "threads"):
        v = getattr(a, name)
        if v is not None and v < 1:
            p.error(f"--{name.replace('_', '-')} {v}: expected an integer >= 1")
    if a.residual is not None:
        from etb_gym.rl_task import residual_bases

        if a.residual not in residual_bases():
            p.error(f"--residual {a.residual!r}: unknown base controller; valid are {', '.join(residual_bases())}")
    if a.residual_scale is not None:
        if a.residual is None and not a.resume:
            p.error("--residual-scale needs --residual BASE")
        if not (0 < a.residual_scale <= 2):
            p.error(f"--residual-scale {a.residual_scale}: expected a duty range in (0, 2]")
    if a.eval_freq is not None and a.eval_freq < 0:
        p.error(f"--eval-freq {a.eval_freq}: expected >= 0")
    if a.resume and (a.hp or a.action_repeat or a.episode_s or a.seed is not None or a.residual is not None
                     or a.residual_scale is not None):
        p.error("--resume continues the saved configuration: --hp, --action-repeat, --episode-s, --seed, --residual "
                "and --residual-scale cannot be changed")
    return a


def main(argv=None) -> int:
    a = parse_args(argv)
    from etb_gym.rl import RunConfig, TrainingInterrupted, train

    t0 = time.perf_counter()
    try:
        if a.resume:
            requested = {"env_id": a.env, "algo": a.algo, "n_envs": a.n_envs, "randomize": a.randomize,
                         "normalize": a.normalize}
            train(None, a.resume, resume=True, requested=requested, timesteps=a.timesteps,
                  time_limit_s=None if a.time_limit_min is None else 60.0 * a.time_limit_min,
                  progress=not a.no_progress)
            out = a.resume
        else:
            cfg = RunConfig(env_id=a.env or "ETB-3B-v0", algo=(a.algo or "sac").lower(), seed=a.seed if a.seed is not None else 0,
                            randomize=a.randomize if isinstance(a.randomize, dict) else bool(a.randomize), normalize=bool(a.normalize), hyperparams=dict(a.hp))
            for name, field in (("timesteps", "timesteps"), ("n_envs", "n_envs"), ("checkpoint_freq", "checkpoint_freq"),
                                ("eval_freq", "eval_freq"), ("threads", "torch_threads")):
                if getattr(a, name) is not None:
                    setattr(cfg, field, getattr(a, name))
            if a.time_limit_min is not None:
                cfg.time_limit_s = 60.0 * a.time_limit_min
            if a.eval_variant:
                cfg.eval_variants = list(a.eval_variant)
            task = {}
            if a.action_repeat is not None:
                task["action_repeat"] = a.action_repeat
            if a.episode_s is not None:
                task["episode_s"] = a.episode_s
            if a.residual is not None:
                task["residual"] = a.residual
            if a.residual_scale is not None:
                task["residual_scale"] = a.residual_scale
            cfg.task = task
            train(cfg, a.out, force=a.force, progress=not a.no_progress)
            out = a.out
    except TrainingInterrupted:
        return 130
    except (ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"train_rl.py: error: {exc}", file=sys.stderr)
        return 2
    from pathlib import Path

    best = f" (best evaluation: {out}/best_model.zip)" if (Path(out) / "best_model.zip").exists() else ""
    print(f"done in {time.perf_counter() - t0:.0f} s -> {out}/model.zip{best}; benchmark it with: "
          f"python scripts/benchmark.py --controller rl:{out} --controller pid --controller smc")
    return 0


if __name__ == "__main__":
    sys.exit(main())
