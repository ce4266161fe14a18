"""A training run's folder: its state (status, evaluations, best model, checkpoints) and the rules for creating
and resuming it. A run folder holds::

    config.json           everything needed to rebuild the env, the features and the policy (RunConfig)
    model.zip             final policy (SB3 zip);  best_model.zip: best evaluation score so far
    vecnormalize.pkl      observation/reward statistics (only with normalize=True)
    checkpoints/          periodic and on-interrupt checkpoints (etb_gym.rl.checkpoints)
    eval.csv              evaluation history;  eval_reference.json: PID / sliding-mode figures it is scored against
    learning_curve.png    evaluation score and training return over timesteps;  tb/: TensorBoard logs
    status.json           state (running / interrupted / finished), timesteps, accumulated wall time
"""
from __future__ import annotations

import math
import pickle
import shutil
import time
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .checkpoints import Checkpoints
from .config import ALGORITHMS, RunConfig
from .controller import RLController
from .evaluate import classical_reference, evaluate_controller, read_eval_csv, score_of, write_eval_csv
from .files import atomic_json, dump_pickle, save_model
from .plots import curve_title, plot_learning_curve


class TrainingInterrupted(KeyboardInterrupt):
    """Raised out of ``learn`` after the on-interrupt checkpoint has been written."""


class Run:
    """State of one training run folder (module docstring)."""

    def __init__(self, cfg: RunConfig, out: Path):
        self.cfg, self.out = cfg, Path(out)
        self.checkpoints = Checkpoints(self.out, cfg.env_id, cfg.algo)
        self.ckpt_dir = self.checkpoints.dir
        self.returns: list[float] = []
        self.eval_rows = read_eval_csv(self.out / "eval.csv")
        # best_model.zip is the best policy ever evaluated in this folder (also one evaluated after the
        # checkpoint a resumed run restarts from)
        self.best = min([r["score"] for r in self.eval_rows if math.isfinite(r["score"])], default=math.inf)
        self.wall0 = time.perf_counter()
        self.wall_before = 0.0
        self._ref = None
        self.env = None
        self.stop_requested = False
        self.time_limited = False

    @property
    def wall_time_s(self) -> float:
        return self.wall_before + time.perf_counter() - self.wall0

    # -- status
    def write_status(self, state: str, timesteps: int) -> None:
        atomic_json(self.out / "status.json", {"state": state, "timesteps": int(timesteps),
                                                "target_timesteps": self.cfg.timesteps,
                                                "wall_time_s": round(self.wall_time_s, 1),
                                                "best_score": self.best if math.isfinite(self.best) else None})

    # -- evaluation
    def reference(self):
        if self._ref is None:
            self._ref = classical_reference(self.cfg, self.out / "eval_reference.json")
        return self._ref

    def _normalizer(self):
        from stable_baselines3.common.vec_env import VecNormalize

        return self.env if isinstance(self.env, VecNormalize) else None

    def evaluate(self, model, logger=None) -> dict:
        ref = self.reference()
        vn = self._normalizer()
        obs_rms = None if vn is None else (vn.obs_rms, vn.clip_obs, vn.epsilon)
        ctrl = RLController(model=model, config=self.cfg, obs_rms=obs_rms, name="rl")
        res = evaluate_controller(ctrl, self.cfg, "rl")
        rms = {f"{s}/{v}": m["rms_error_deg"] for (s, v), m in res.items()}
        score = score_of(rms, ref)
        ratios = {k: v / max(ref[k]["best"], 1e-9) for k, v in rms.items()}
        row = {"timesteps": float(model.num_timesteps), "wall_time_s": self.wall_time_s, "score": score,
               "worst_ratio": max(ratios.values()),
               "train_return": float(np.mean(self.returns[-20:])) if self.returns else math.nan}
        row.update({f"rms/{k}": v for k, v in rms.items()})
        self.eval_rows.append(row)
        write_eval_csv(self.out / "eval.csv", self.eval_rows)
        if logger is not None:
            logger.record("eval/score", score)
            logger.record("eval/worst_ratio", row["worst_ratio"])
            for k, v in rms.items():
                logger.record(f"eval/rms_{k.replace('/', '_')}", v)
        if score < self.best:
            self.best = score
            save_model(model, self.out / "best_model.zip")
            if vn is not None:
                dump_pickle(vn, self.out / "best_vecnormalize.pkl")
        return row

    # -- checkpoints
    def checkpoint(self, model, tag: str = "") -> Path:
        vn = self._normalizer()
        entry = self.checkpoints.save(
            model, tag=tag, replay_buffer=ALGORITHMS[self.cfg.algo]["off_policy"],
            vecnormalize=None if vn is None else (lambda fh: pickle.dump(vn, fh)),
            wall_time_s=round(self.wall_time_s, 1), best_score=self.best if math.isfinite(self.best) else None,
            time=time.time())
        self.write_status("running", entry["timesteps"])
        return self.ckpt_dir / entry["model"]

    # -- final outputs
    def finish(self, model) -> None:
        save_model(model, self.out / "model.zip")
        vn = self._normalizer()
        if vn is not None:
            dump_pickle(vn, self.out / "vecnormalize.pkl")
        self.plot()

    def plot(self) -> None:
        if self.eval_rows:
            plot_learning_curve(self.eval_rows, self.out / "learning_curve.png", title=curve_title(self.cfg))


def prepare_output(out: Path, force: bool) -> None:
    """A fresh run folder: refuse to touch an existing non-empty folder unless ``force`` (and then only if it is
    an RL run folder: it holds config.json)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise FileExistsError(f"--out {out}: exists and is not a folder")
    if out.exists() and any(out.iterdir()):
        if not force:
            raise FileExistsError(f"--out {out}: the folder exists and is not empty; pass --force to replace it, "
                                  f"or --resume {out} to continue its run")
        if not (out / "config.json").exists():
            raise FileExistsError(f"--out {out}: not an RL run folder (no config.json); refusing to delete it even "
                                  "with --force")
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)


def check_resume(saved: RunConfig, requested: Mapping[str, Any]) -> None:
    """Raise if an explicitly requested setting contradicts the run being resumed."""
    for key in ("env_id", "algo", "n_envs", "randomize", "normalize"):
        v = requested.get(key)
        if key == "randomize" and v is True and saved.randomize:
            continue                      # --randomize on resume of a run with (custom) randomization
        if v is not None and (str(v).lower() if key == "algo" else v) != getattr(saved, key):
            raise ValueError(f"--resume: the checkpoint was trained with {key}={getattr(saved, key)!r}, not {v!r} "
                             "(incompatible checkpoint; start a new run with --out instead)")
