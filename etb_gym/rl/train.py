"""Training with checkpoints and resume, and the ``etb-gym train`` command.

    etb-gym train --env ETB-3B-v0 --timesteps 200000 --out runs/sac_3b            # SAC, 8 sub-envs
    etb-gym train --algo ppo --n-envs 16 --randomize --out runs/ppo_3b
    etb-gym train --residual smc-plain --residual-scale 0.3 --randomize --out runs/res_3b   # residual RL
    etb-gym train --resume runs/sac_3b                  # continue an interrupted (Ctrl-C, kill) run
    etb-gym train --resume runs/sac_3b --timesteps 400000        # ... or extend a finished one
    etb-gym benchmark --controller rl:runs/sac_3b --controller pid --controller smc

Outputs in --out: config.json, model.zip, best_model.zip, eval.csv, learning_curve.png, checkpoints/, tb/
(tensorboard --logdir OUT/tb); see etb_gym.rl.run. docs/rl.md: the task design (features, reward, action
repeat) and the hyperparameters. Every option, --hp values included, is checked before the run folder is
written. Exit codes: 0 done, 2 invalid options or an unusable run folder / checkpoint (one sentence on
stderr), 130 interrupted (a checkpoint was written; continue with --resume).
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path
from typing import Mapping, Sequence

from .checkpoints import CheckpointError
from .config import RunConfig, algorithm_class, env_dt, make_model, read_config, versions
from .files import atomic_json, remove_temporaries
from .run import Run, TrainingInterrupted, check_resume, prepare_output
from .task import feature_names


class _TimeLimit(Exception):
    """Ends ``learn`` at a rollout boundary once the run's wall-time budget is spent (then finished normally)."""


def _callbacks():
    from stable_baselines3.common.callbacks import BaseCallback

    class RunCallback(BaseCallback):
        """Periodic checkpoints (model, replay buffer, VecNormalize statistics, eval state; atomic, with a
        ``latest.json`` pointer written last), evaluations with the benchmark's metrics (TensorBoard
        ``eval/*``, ``eval.csv``, ``best_model.zip``) and the on-interrupt checkpoint.

        All three happen at the start of a rollout: there the replay buffer holds exactly ``num_timesteps``
        transitions and the gradient steps of the previous rollout are done, so a checkpoint loses nothing
        (SB3 calls ``on_step`` before it stores the step's transition)."""

        def __init__(self, run: "Run"):
            super().__init__(verbose=0)
            self.run = run
            self.next_ckpt = None
            self.next_eval = None

        def _on_training_start(self):
            r, n = self.run, self.model.num_timesteps
            self.next_ckpt = (n // r.cfg.checkpoint_freq + 1) * r.cfg.checkpoint_freq
            self.next_eval = (n // r.cfg.eval_freq + 1) * r.cfg.eval_freq if r.cfg.eval_freq else None

        def _on_rollout_start(self) -> None:
            run, n = self.run, self.model.num_timesteps
            if run.stop_requested:
                path = run.checkpoint(self.model, tag="_interrupted")
                run.write_status("interrupted", n)
                raise TrainingInterrupted(f"interrupted at {n} timesteps: checkpoint {path}")
            if self.next_eval is not None and n >= self.next_eval:
                run.evaluate(self.model, self.logger)
                self.next_eval = (n // run.cfg.eval_freq + 1) * run.cfg.eval_freq
            if n >= self.next_ckpt:
                run.checkpoint(self.model)
                self.next_ckpt = (n // run.cfg.checkpoint_freq + 1) * run.cfg.checkpoint_freq
            if run.cfg.time_limit_s and run.wall_time_s >= run.cfg.time_limit_s:
                run.time_limited = True
                raise _TimeLimit()

        def _on_step(self) -> bool:
            for info in self.locals.get("infos", ()):
                ep = info.get("episode")
                if ep is not None:
                    self.run.returns.append(float(ep["r"]))
            return True

    return RunCallback


def _new_run(cfg: RunConfig, out: Path, force: bool):
    """Validate ``cfg`` (every option, before anything is written), prepare ``out``, write config.json and
    build the model. Returns (run, model)."""
    cfg = cfg.validate()
    prepare_output(out, force)
    run = Run(cfg, out)
    d = cfg.to_dict()
    d["env_dt_s"] = env_dt(cfg.env_id)
    d["features"] = list(feature_names(cfg.task_config))
    d["versions"] = versions()
    atomic_json(out / "config.json", d)
    from .vecenv import make_training_env

    run.env = make_training_env(cfg)
    model = make_model(cfg, run.env, str(out / "tb"))
    if cfg.eval_freq:
        run.reference()
    return run, model


def _resumed_run(out: Path, requested: Mapping | None, timesteps, time_limit_s, checkpoint: str | None, log):
    """The run in ``out`` at its latest (or the named) intact checkpoint. Returns (run, model)."""
    if not out.is_dir():
        raise FileNotFoundError(f"--resume {out}: no such run folder")
    cfg = read_config(out)
    check_resume(cfg, requested or {})
    if timesteps is not None:
        cfg.timesteps = int(timesteps)
    if time_limit_s is not None:      # a new budget for the accumulated wall time (0: none)
        cfg.time_limit_s = float(time_limit_s)
    cfg.validate()
    run = Run(cfg, out)
    entry = run.checkpoints.resume_entry(checkpoint)
    for folder in (out, run.ckpt_dir):          # leftovers of writes cut short by a kill
        remove_temporaries(folder)
    n0 = int(entry["timesteps"])
    dropped = run.checkpoints.discard_after(n0)
    if dropped:
        log(f"resuming from {entry['model']}: discarded the newer checkpoint(s) {', '.join(dropped)}")
    run.wall_before = float(entry.get("wall_time_s") or 0.0)
    run.eval_rows = [r for r in run.eval_rows if r["timesteps"] <= n0]
    if entry.get("best_score") is not None:
        run.best = min(run.best, float(entry["best_score"]))
    stats = run.ckpt_dir / entry["vecnormalize"] if entry.get("vecnormalize") else None
    cls = algorithm_class(cfg.algo)
    from .vecenv import make_training_env

    try:
        run.env = make_training_env(cfg, seed=cfg.seed + n0, normalize_stats=stats)
    except Exception as exc:    # a damaged pickle raises assorted errors
        raise run.checkpoints.refuse(stats, f"cannot be loaded ({type(exc).__name__}: {exc})", before=n0) from None
    path = run.ckpt_dir / entry["model"]
    try:
        model = cls.load(str(path), env=run.env, device="cpu", tensorboard_log=str(out / "tb"))
        if entry.get("replay_buffer"):
            path = run.ckpt_dir / entry["replay_buffer"]
            model.load_replay_buffer(str(path))
    except Exception as exc:    # SB3 raises assorted errors for damaged files
        run.env.close()
        raise run.checkpoints.refuse(path, f"cannot be loaded ({type(exc).__name__}: {exc})", before=n0) from None
    log(f"resuming {cfg.algo.upper()} on {cfg.env_id} from {entry['model']} at {model.num_timesteps} timesteps"
        f" -> {cfg.timesteps}")
    return run, model


def train(cfg: RunConfig | None, out, *, resume: bool = False, force: bool = False, requested: Mapping | None = None,
          timesteps: int | None = None, time_limit_s: float | None = None, checkpoint: str | None = None,
          callbacks: Sequence = (), progress: bool = True, log=print):
    """Train (or, with ``resume``, continue) the run in folder ``out``; returns the model.

    New run: ``cfg`` is validated, ``out`` prepared (see :func:`prepare_output`), ``config.json`` written.
    Resume: the config comes from ``out/config.json`` (``requested`` settings must agree with it), the latest
    checkpoint's (or ``checkpoint``'s, e.g. "ckpt_50000") model, replay buffer and normalization statistics are
    loaded and training continues to ``timesteps`` (default: the config's; ``time_limit_s`` replaces the
    wall-time budget, which counts the whole run) without resetting the step counter. A damaged checkpoint
    raises :class:`~etb_gym.rl.checkpoints.CheckpointError` naming the file and the last intact one.
    Ctrl-C / SIGTERM save a checkpoint first, then re-raise KeyboardInterrupt."""
    import torch

    out = Path(out)
    if resume:
        run, model = _resumed_run(out, requested, timesteps, time_limit_s, checkpoint, log)
    else:
        if checkpoint is not None:
            raise ValueError("--checkpoint names the checkpoint to resume from: it needs --resume")
        run, model = _new_run(cfg, out, force)
    cfg = run.cfg
    torch.set_num_threads(cfg.torch_threads)
    _learn(run, model, resume, callbacks, progress, log)
    if cfg.eval_freq and (not run.eval_rows or run.eval_rows[-1]["timesteps"] < model.num_timesteps):
        run.evaluate(model)
    run.checkpoint(model)
    run.finish(model)
    run.write_status("finished (time limit)" if run.time_limited else "finished", model.num_timesteps)
    run.env.close()
    return model


def _learn(run: Run, model, resume: bool, callbacks: Sequence, progress: bool, log) -> None:
    """``model.learn`` up to the run's timesteps, with SIGINT / SIGTERM turned into a checkpoint and
    :class:`TrainingInterrupted`, and the wall-time budget into a normal end."""
    cfg, out = run.cfg, run.out
    remaining = cfg.timesteps - model.num_timesteps
    cb = [_callbacks()(run), *callbacks]
    handlers = {}

    def request_stop(signum, frame):
        if run.stop_requested:            # a second Ctrl-C: stop at once (no checkpoint)
            raise KeyboardInterrupt
        run.stop_requested = True
        log(f"signal {signum}: stopping at the next rollout boundary after a checkpoint (again to abort)")

    if _in_main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            handlers[sig] = signal.signal(sig, request_stop)
    run.write_status("running", model.num_timesteps)
    try:
        if remaining > 0:
            model.learn(total_timesteps=remaining, callback=cb, reset_num_timesteps=not resume, tb_log_name="run",
                        progress_bar=progress)
    except _TimeLimit:
        log(f"time limit {cfg.time_limit_s:g} s reached at {model.num_timesteps} timesteps")
    except TrainingInterrupted as exc:
        run.plot()
        log(f"{exc}; continue with --resume {out}")
        run.env.close()
        raise
    finally:
        for sig, h in handlers.items():
            signal.signal(sig, h)


def _in_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()



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


def build_parser(prog: str = "etb-gym train") -> argparse.ArgumentParser:
    from etb_gym.envs import ENV_IDS

    from .config import ALGORITHMS, available_algorithms

    p = argparse.ArgumentParser(prog=prog, description="Train a Stable-Baselines3 agent on an ETB env (resumable; "
                                "evaluated with the controller benchmark's metrics).",
                                epilog=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
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
                        "base controller (pid, pid-plain or smc, designed on the env's nominal model); default: none, "
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
    p.add_argument("--checkpoint", default=None, metavar="NAME",
                   help="with --resume: continue from this checkpoint (e.g. ckpt_50000) instead of the latest; "
                        "a damaged checkpoint's error names the last intact one")
    p.add_argument("--force", action="store_true", help="replace an existing run folder given as --out")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def parse_args(argv=None, prog: str = "etb-gym train"):
    """Parsed and checked options (argparse's exit 2 with a sentence for an invalid combination)."""
    from etb_gym.envs import ENV_IDS

    from .config import ALGORITHMS, available_algorithms
    from .task import residual_bases

    p = build_parser(prog)
    a = p.parse_args(argv)
    if a.env is not None and a.env not in ENV_IDS:
        p.error(f"unknown env {a.env!r}: valid are {', '.join(ENV_IDS)}")
    if a.algo is not None and a.algo.lower() not in ALGORITHMS:
        p.error(f"unknown algorithm {a.algo!r}: valid are {', '.join(available_algorithms())}")
    if a.resume and a.out:
        p.error("--resume DIR continues the run in DIR: do not pass --out as well")
    if not a.resume and not a.out:
        p.error("--out DIR is required for a new run (or --resume DIR to continue one)")
    if a.checkpoint and not a.resume:
        p.error("--checkpoint NAME picks the checkpoint to resume from: it needs --resume DIR")
    if a.resume and a.force:
        p.error("--force replaces a run folder; it cannot be combined with --resume")
    for name in ("timesteps", "n_envs", "action_repeat", "checkpoint_freq", "threads"):
        v = getattr(a, name)
        if v is not None and v < 1:
            p.error(f"--{name.replace('_', '-')} {v}: expected an integer >= 1")
    if a.residual is not None:
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


def config_from_args(a) -> RunConfig:
    """The RunConfig of a new run from parsed options."""
    cfg = RunConfig(env_id=a.env or "ETB-3B-v0", algo=(a.algo or "sac").lower(),
                    seed=a.seed if a.seed is not None else 0,
                    randomize=a.randomize if isinstance(a.randomize, dict) else bool(a.randomize),
                    normalize=bool(a.normalize), hyperparams=dict(a.hp))
    for name, field in (("timesteps", "timesteps"), ("n_envs", "n_envs"), ("checkpoint_freq", "checkpoint_freq"),
                        ("eval_freq", "eval_freq"), ("threads", "torch_threads")):
        if getattr(a, name) is not None:
            setattr(cfg, field, getattr(a, name))
    if a.time_limit_min is not None:
        cfg.time_limit_s = 60.0 * a.time_limit_min
    if a.eval_variant:
        cfg.eval_variants = list(a.eval_variant)
    task = {}
    for opt, key in (("action_repeat", "action_repeat"), ("episode_s", "episode_s"), ("residual", "residual"),
                     ("residual_scale", "residual_scale")):
        if getattr(a, opt) is not None:
            task[key] = getattr(a, opt)
    cfg.task = task
    return cfg


def main(argv=None, prog: str = "etb-gym train") -> int:
    """``etb-gym train``: exit 0 done, 2 invalid options / unusable run folder or checkpoint, 130 interrupted."""
    a = parse_args(argv, prog)
    t0 = time.perf_counter()
    try:
        if a.resume:
            requested = {"env_id": a.env, "algo": a.algo, "n_envs": a.n_envs, "randomize": a.randomize,
                         "normalize": a.normalize}
            train(None, a.resume, resume=True, requested=requested, timesteps=a.timesteps,
                  time_limit_s=None if a.time_limit_min is None else 60.0 * a.time_limit_min,
                  checkpoint=a.checkpoint, progress=not a.no_progress)
            out = a.resume
        else:
            train(config_from_args(a), a.out, force=a.force, progress=not a.no_progress)
            out = a.out
    except TrainingInterrupted:
        return 130
    except (CheckpointError, ValueError, FileNotFoundError, FileExistsError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    best = f" (best evaluation: {out}/best_model.zip)" if (Path(out) / "best_model.zip").exists() else ""
    print(f"done in {time.perf_counter() - t0:.0f} s -> {out}/model.zip{best}; benchmark it with: "
          f"etb-gym benchmark --controller rl:{out} --controller pid --controller smc")
    return 0


if __name__ == "__main__":
    sys.exit(main())
