"""RL training: smoke run, save/load round trip, interrupt + resume, the rl: controller, bad input."""
from __future__ import annotations

import json
import os
import signal

import gymnasium as gym
import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from etb_gym.controllers import make_controller  # noqa: E402
from etb_gym.rl import RLController, RunConfig, TrainingInterrupted, read_config, train  # noqa: E402
from etb_gym.rl.task import FEATURE_NAMES, PolicyFeatures, TaskConfig, draw_reference  # noqa: E402
from etb_gym.rl.train import main as train_main  # noqa: E402
from etb_gym.rl.vecenv import training_vec_env  # noqa: E402
from etb_gym.rl.wrappers import BaseControllerDuty  # noqa: E402

FAST_HP = {"learning_starts": 64, "buffer_size": 2_000, "batch_size": 32, "net_arch": [16, 16]}


def small_config(**kw) -> RunConfig:
    base = dict(env_id="ETB-3B-v0", algo="sac", timesteps=320, n_envs=2, seed=3, eval_freq=0, checkpoint_freq=10_000,
                hyperparams=dict(FAST_HP), task={"episode_s": 0.1})
    base.update(kw)
    return RunConfig(**base)


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("rl") / "sac"
    model = train(small_config(), out, progress=False, log=lambda *a: None)
    return out, model


def test_smoke_training_writes_a_complete_run(smoke_run):
    out, model = smoke_run
    assert model.num_timesteps == 320
    for f in ("config.json", "model.zip", "status.json", "checkpoints/latest.json"):
        assert (out / f).exists(), f
    assert json.loads((out / "status.json").read_text())["state"] == "finished"
    latest = json.loads((out / "checkpoints/latest.json").read_text())
    assert latest["timesteps"] == 320 and (out / "checkpoints" / latest["replay_buffer"]).exists()
    cfg = read_config(out)
    assert cfg.algo == "sac" and cfg.env_id == "ETB-3B-v0" and cfg.task_config.episode_s == 0.1
    assert list(tuple(json.loads((out / "config.json").read_text())["features"])) == list(FEATURE_NAMES)
    assert any((out / "tb").rglob("events.out.tfevents.*"))


def test_save_load_round_trip_gives_the_same_policy(smoke_run):
    out, model = smoke_run
    ctrl = make_controller(f"rl:{out}")
    assert isinstance(ctrl, RLController) and ctrl.dt == pytest.approx(1e-3)
    feats = np.random.default_rng(0).uniform(-1, 1, (32, len(FEATURE_NAMES))).astype(np.float32)
    a0, _ = model.predict(feats, deterministic=True)
    a1, _ = ctrl.model.predict(feats, deterministic=True)
    np.testing.assert_array_equal(a0, a1)
    # the same duty sequence from two independent loads, driven through the env the benchmark uses
    duties = []
    for c in (ctrl, RLController(out / "model.zip")):
        env = gym.make("ETB-3B-v0", reference={"name": "step", "initial_deg": 3.0, "final_deg": 3.5, "at_s": 0.02})
        obs, _ = env.reset(seed=0, options={"angle_deg": 3.0})
        c.reset(seed=0)
        seq = []
        for _ in range(60):
            d = c.act(obs)
            assert -1.0 <= d <= 1.0
            seq.append(d)
            obs, *_ = env.step(np.array([d], np.float32))
        duties.append(seq)
    assert duties[0] == duties[1]
    k = ctrl.task.action_repeat
    assert all(duties[0][i] == duties[0][i - i % k] for i in range(len(duties[0])))   # held between decisions


def test_interrupt_and_resume_continue_from_the_checkpoint(tmp_path):
    import threading

    from stable_baselines3.common.callbacks import BaseCallback

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signal handlers need the main thread")
    out = tmp_path / "run"

    class Interrupt(BaseCallback):          # a real Ctrl-C (SIGINT) in the middle of training
        def _on_step(self):
            if self.num_timesteps == 160:
                os.kill(os.getpid(), signal.SIGINT)
            return True

    with pytest.raises(TrainingInterrupted):
        train(small_config(), out, callbacks=[Interrupt()], progress=False, log=lambda *a: None)
    latest = json.loads((out / "checkpoints/latest.json").read_text())
    n = latest["timesteps"]
    assert 160 <= n < 320 and "_interrupted" in latest["model"]
    assert json.loads((out / "status.json").read_text())["state"] == "interrupted"

    from stable_baselines3 import SAC

    saved = SAC.load(str(out / "checkpoints" / latest["model"]), device="cpu")
    seen = {}

    class Probe(BaseCallback):
        def _on_training_start(self):
            seen["start"] = self.model.num_timesteps
            seen["buffer"] = self.model.replay_buffer.size() * self.model.n_envs
            seen["n_updates"] = self.model._n_updates
            seen["params_equal"] = all(
                np.array_equal(a.detach().numpy(), b.detach().numpy())
                for a, b in zip(self.model.policy.parameters(), saved.policy.parameters()))

        def _on_step(self):
            return True

    with pytest.raises(ValueError, match="incompatible checkpoint"):
        train(None, out, resume=True, requested={"algo": "td3"}, progress=False, log=lambda *a: None)
    model = train(None, out, resume=True, callbacks=[Probe()], progress=False, log=lambda *a: None)
    assert seen["start"] == n                  # the step counter continues from the checkpoint
    assert seen["buffer"] == n                 # every transition collected before the interrupt is replayed
    assert seen["n_updates"] == saved._n_updates > 0
    assert seen["params_equal"]
    assert model.num_timesteps == 320 and model._n_updates > saved._n_updates
    assert json.loads((out / "status.json").read_text())["state"] == "finished"


def test_policy_features_batch_equals_single_streams():
    task = TaskConfig()
    rng = np.random.default_rng(1)
    streams = rng.normal(0, 0.3, (2, 50, 4))
    batch, singles = PolicyFeatures(2, 1e-3, task), [PolicyFeatures(1, 1e-3, task) for _ in range(2)]
    batch.reset_rows(np.arange(2), streams[:, 0])
    for i, s in enumerate(singles):
        s.reset_rows(np.array([0]), streams[i, :1])
    for k in range(1, 50):
        batch.update(streams[:, k])
        for i, s in enumerate(singles):
            s.update(streams[i, k:k + 1])
    np.testing.assert_allclose(batch.value(), np.vstack([s.value() for s in singles]), rtol=1e-6)
    assert np.all(np.isfinite(batch.value()))


def test_training_references_cover_the_benchmark_kinds():
    rng = np.random.default_rng(0)
    steps_small, steps_big, near_lh, ramps = 0, 0, 0, 0
    for _ in range(40):
        ref, a0 = draw_reference(rng, 1.5, 1e-3)
        t, v = np.array(ref["times_s"]), np.array(ref["values_deg"])
        assert np.all(np.diff(t) > 0) and 0.5 <= v.min() and v.max() <= 85.0 and v[0] == a0
        np.testing.assert_allclose(t * 1000, np.round(t * 1000), atol=1e-6)   # knots on the control grid
        dv, dt = np.diff(v), np.diff(t)
        jump = dt < 1.5e-3
        steps_small += int(np.sum(jump & (np.abs(dv) < 2.6)))
        steps_big += int(np.sum(jump & (np.abs(dv) > 20)))
        near_lh += int(np.sum(jump & (np.abs(v[1:] - 3.0) <= 3.0)))
        ramps += int(np.sum(~jump & (np.abs(dv) > 0)))
    assert min(steps_small, steps_big, near_lh, ramps) > 5


def test_training_vec_env_truncates_in_step_and_resets():
    env = training_vec_env("ETB-3B-v0", 2, TaskConfig(episode_s=0.01), seed=0)
    obs = env.reset()
    assert obs.shape == (2, len(FEATURE_NAMES))
    for k in range(5):
        obs, rew, done, infos = env.step(np.zeros((2, 1)))
        assert rew.shape == (2,) and np.all(rew <= 0)
    assert done.all() and all(i["TimeLimit.truncated"] for i in infos)
    assert infos[0]["terminal_observation"].shape == (len(FEATURE_NAMES),)
    env.close()
    with pytest.raises(ValueError, match="multiple of task.action_repeat"):
        training_vec_env("ETB-3B-v0", 1, TaskConfig(episode_s=0.003, action_repeat=2))


# ------------------------------------------------------------------------------------------------ bad input
def test_cli_rejects_unknown_algo_and_env(capsys, tmp_path):
    with pytest.raises(SystemExit):
        train_main(["--algo", "dqn", "--out", "x"])
    assert "unknown algorithm 'dqn'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        train_main(["--env", "ETB-9Z-v0", "--out", "x"])
    assert "unknown env 'ETB-9Z-v0'" in capsys.readouterr().err
    assert train_main(["--randomize", '{"friction_scale": [0.4, 1.6], "mass": [1, 2]}', "--out",
                          str(tmp_path / "r")]) == 2
    assert "unknown quantity 'mass'" in capsys.readouterr().err and not (tmp_path / "r").exists()
    cfg = RunConfig(randomize={"friction_scale": [0.4, 1.6]}).validate()
    assert cfg.env_randomization()["friction_scale"] == (0.4, 1.6) and "supply_V" in cfg.env_randomization()


def test_existing_output_needs_force(tmp_path, capsys, smoke_run):
    other = tmp_path / "notes"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    assert train_main(["--out", str(other), "--timesteps", "10", "--no-progress"]) == 2
    assert "--force" in capsys.readouterr().err
    assert train_main(["--out", str(other), "--force", "--timesteps", "10", "--no-progress"]) == 2
    assert "not an RL run folder" in capsys.readouterr().err and (other / "keep.txt").read_text() == "mine"
    out, _ = smoke_run
    before = (out / "model.zip").read_bytes()
    assert train_main(["--out", str(out), "--timesteps", "10", "--no-progress"]) == 2
    assert (out / "model.zip").read_bytes() == before


def test_resume_errors_are_clear(tmp_path, capsys, smoke_run):
    out, _ = smoke_run
    assert train_main(["--resume", str(tmp_path / "nope"), "--no-progress"]) == 2
    assert "no such run folder" in capsys.readouterr().err
    assert train_main(["--resume", str(out), "--env", "ETB-1A-v0", "--no-progress"]) == 2
    assert "incompatible checkpoint" in capsys.readouterr().err
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "config.json").write_text((out / "config.json").read_text())
    assert train_main(["--resume", str(bare), "--no-progress"]) == 2
    assert "no checkpoint to resume from" in capsys.readouterr().err


def test_rl_prefix_errors_name_the_problem(tmp_path, smoke_run):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        make_controller(f"rl:{tmp_path / 'missing'}")
    out, _ = smoke_run
    wrong = tmp_path / "wrong"
    wrong.mkdir()
    (wrong / "model.zip").write_bytes((out / "model.zip").read_bytes())
    cfg = json.loads((out / "config.json").read_text())
    cfg["algo"], cfg["hyperparams"] = "ppo", {}
    cfg.pop("hyperparams_resolved")
    (wrong / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(ValueError, match="cannot load .* as a PPO policy"):
        make_controller(f"rl:{wrong}")
    with pytest.raises(ValueError, match="unknown algorithm"):
        RunConfig(algo="a2c").validate()
    with pytest.raises(ValueError, match="'learning_starts' is not a hyperparameter of ppo"):
        RunConfig(algo="ppo", hyperparams={"learning_starts": 10}).validate()


def test_rms_comparison_ratios_and_marks():
    from etb_gym.rl import rms_comparison

    def row(c, s, v, rms):
        return {"env": "ETB-3B-v0", "controller": c, "scenario": s, "variant": v, "seed": 0, "rms_error_deg": rms}

    rows = [row("rl:x", "pedal", "nominal", 1.0), row("pid", "pedal", "nominal", 2.0), row("smc", "pedal", "nominal", 0.8),
            row("rl:x", "step_10_80", "supply_9V", 5.0), row("pid", "step_10_80", "supply_9V", 10.0),
            row("smc", "step_10_80", "supply_9V", 20.0)]
    md, table = rms_comparison(rows, "rl:x")
    assert [round(r["ratio"], 3) for r in table] == [1.25, 0.5]
    assert "**1/2** runs within 1.2x, **1/2** better than both" in md and "**miss**" in md
    with pytest.raises(ValueError, match="no benchmark rows for controller 'rl:y'"):
        rms_comparison(rows, "rl:y")


# ------------------------------------------------------------------------------------------------ residual RL
@pytest.fixture(scope="module")
def residual_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("rl") / "residual"
    cfg = small_config(timesteps=256, task={"episode_s": 0.1, "residual": "smc-plain", "residual_scale": 0.3})
    model = train(cfg, out, progress=False, log=lambda *a: None)
    return out, model


def _drive(ctrl, reference, n=80, base=None):
    """Duties of ``ctrl`` (and of an independent ``base`` controller fed the same observations)."""
    env = gym.make("ETB-3B-v0", reference=reference)
    obs, _ = env.reset(seed=0, options={"angle_deg": reference.get("initial_deg", 40.0)})
    ctrl.reset(seed=0)
    if base is not None:
        base.reset(seed=0)
    duties, bases = [], []
    for _ in range(n):
        d = ctrl.act(obs)
        duties.append(d)
        if base is not None:
            bases.append(base.act(obs))
        obs, *_ = env.step(np.array([d], np.float32))
    env.close()
    return np.array(duties), np.array(bases)


def test_residual_smoke_run_records_the_base_controller(residual_run):
    out, model = residual_run
    assert model.num_timesteps == 256
    d = json.loads((out / "config.json").read_text())
    assert d["task"]["residual"] == "smc-plain" and d["task"]["residual_scale"] == 0.3
    assert d["features"] == list(FEATURE_NAMES) + ["base_duty"]
    assert model.observation_space.shape == (len(FEATURE_NAMES) + 1,)
    env = training_vec_env("ETB-3B-v0", 2, TaskConfig(episode_s=0.01, residual="pid-plain"), seed=0)
    obs = env.reset()
    assert obs.shape == (2, len(FEATURE_NAMES) + 1)
    layer = env.venv
    while not isinstance(layer, BaseControllerDuty):
        layer = layer.env
    base, plant_env = layer.base, env.venv.unwrapped
    applied, step = [], plant_env.step

    def record(a):                                        # the duty sent to the plant vs the base's duty
        applied.append((np.asarray(a, float).ravel().copy(), base.duty.copy()))
        return step(a)

    plant_env.step = record
    np.testing.assert_array_equal(obs[:, -1], base.duty.astype(np.float32))
    _, rew, _, _ = env.step(np.zeros((2, 1)))             # zero residual: the applied duty is the base duty
    _, rew2, _, _ = env.step(np.ones((2, 1)))             # full residual: base + 0.3, clipped
    assert len(applied) == 4 and np.all(rew <= 0) and np.all(rew2 < 0)
    for a, b in applied[:2]:
        np.testing.assert_allclose(a, b, atol=1e-7)
    for a, b in applied[2:]:
        np.testing.assert_allclose(a, np.minimum(b + 0.3, 1.0), atol=1e-6)
    env.close()


def test_untrained_residual_agent_is_its_base_controller():
    from etb_gym.rl import make_model, make_training_env

    cfg = small_config(task={"episode_s": 0.1, "residual": "smc-plain"}).validate()
    env = make_training_env(cfg)
    ctrl = RLController(model=make_model(cfg, env, None), config=cfg)
    ref = {"name": "step", "initial_deg": 40.0, "final_deg": 40.5, "at_s": 0.01}
    duties, bases = _drive(ctrl, ref, base=make_controller("smc-plain"))
    np.testing.assert_array_equal(duties, bases)          # zeroed output layer: residual exactly 0
    env.close()


def test_residual_round_trip_rebuilds_the_base_controller(residual_run):
    from etb_gym.controllers.smc import SlidingModeController

    out, model = residual_run
    ctrl = make_controller(f"rl:{out}")
    assert isinstance(ctrl.base.ctrls[0], SlidingModeController)
    ref = {"name": "step", "initial_deg": 40.0, "final_deg": 40.5, "at_s": 0.01}
    d1, bases = _drive(ctrl, ref, base=make_controller("smc-plain"))
    d2, _ = _drive(RLController(out / "model.zip"), ref)
    np.testing.assert_array_equal(d1, d2)
    assert np.all(np.abs(d1 - bases) <= 0.3 + 1e-9)       # a bounded correction of the base duty
    assert np.any(d1 != bases)                            # ... that the trained policy does apply


def test_residual_bad_input_names_the_option(capsys, tmp_path):
    with pytest.raises(ValueError, match=r"task.residual = 'lqr' is invalid: .*\['pid-nocomp', 'pid-plain', 'smc-plain'\]"):
        TaskConfig(residual="lqr")
    with pytest.raises(ValueError, match="task.residual_scale = 0 is invalid"):
        TaskConfig(residual="pid-plain", residual_scale=0)
    with pytest.raises(SystemExit):
        train_main(["--residual", "lqr", "--out", str(tmp_path / "r")])
    assert "--residual 'lqr': unknown base controller; valid are pid-nocomp, pid-plain, smc-plain" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        train_main(["--residual", "smc-plain", "--residual-scale", "3", "--out", str(tmp_path / "r")])
    assert "--residual-scale 3.0: expected a duty range in (0, 2]" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        train_main(["--residual-scale", "0.2", "--out", str(tmp_path / "r")])
    assert "--residual-scale needs --residual BASE" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
