"""Stable-Baselines3 agents on the ETB envs: algorithms, resumable training, evaluation with the benchmark's
metrics, and the policy-as-controller adapter (``make_controller("rl:PATH")``).

    from etb_gym.rl import RunConfig, train, RLController
    train(RunConfig(env_id="ETB-3B-v0", algo="sac", timesteps=200_000, n_envs=4, randomize=True), "runs/sac")
    ctrl = RLController("runs/sac")              # or make_controller("rl:runs/sac")
    duty = ctrl.act(observation)                 # the controller protocol of etb_gym.controllers.base

Modules (each importable on its own; SB3 and torch load only where a model is built or trained):

=============== ===================================================================================
``task``         the MDP's pieces: TaskConfig, policy features, tracking cost, training references,
                 residual base controllers (numpy only; shared by training and the deployed controller)
``wrappers``     the task as Gymnasium vector wrappers around ``gym.make_vec(env_id)``
``vecenv``       SB3's VecEnv over those wrappers; the training env of a run
``config``       the algorithm registry, RunConfig (validated: ``--hp`` values too), the model factory
``checkpoints``  checkpoint files, resume point, damaged-checkpoint errors that offer the last intact one
``run``          a run folder's state: status, evaluations, best model, final outputs
``train``        training with checkpoint / resume, and the ``etb-gym train`` command (``main``)
``evaluate``     scoring against PID / SMC, eval.csv, the RMS comparison (``python -m etb_gym.rl compare``)
``controller``   RLController and the ``rl:`` controller prefix (registered when this package is imported)
``plots``        the learning curve (local Agg canvas)
``files``        atomic writes
=============== ===================================================================================
"""
from __future__ import annotations

from .checkpoints import CheckpointError, Checkpoints
from .config import (ALGORITHMS, RUN_FORMAT, RunConfig, algorithm_class, available_algorithms, make_model,
                     read_config, validate_hyperparams, zero_policy_mean)
from .controller import RLController, load_controller
from .evaluate import classical_reference, evaluate_controller, rms_comparison, score_of
from .plots import plot_learning_curve
from .run import Run, TrainingInterrupted
from .task import FEATURE_NAMES, PolicyFeatures, TaskConfig, draw_reference, feature_names
from .train import main, train  # noqa: E402  (the package attribute ``train`` is the function, not the module)

_LAZY = {"make_training_env": "vecenv", "training_vec_env": "vecenv", "SB3VecEnv": "vecenv",
         "make_task_vec_env": "wrappers", "wrap_task": "wrappers"}

__all__ = ["ALGORITHMS", "RUN_FORMAT", "RunConfig", "algorithm_class", "available_algorithms", "make_model",
           "read_config", "validate_hyperparams", "zero_policy_mean", "RLController", "load_controller",
           "classical_reference", "evaluate_controller", "rms_comparison", "score_of", "plot_learning_curve",
           "FEATURE_NAMES", "PolicyFeatures", "TaskConfig", "draw_reference", "feature_names", "CheckpointError",
           "Checkpoints", "Run", "TrainingInterrupted", "main", "train", *_LAZY]


def __getattr__(name):
    """The names that need Gymnasium's vector wrappers or Stable-Baselines3, imported on first use."""
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'etb_gym.rl' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f"{__name__}.{mod}"), name)
