"""Training robustness: --hp values checked before the run folder exists, damaged checkpoints refused with the
file named and the last intact one offered, SIGKILL at random points, the task wrappers on gym.make envs."""
from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from etb_gym.rl import RunConfig, read_config, train  # noqa: E402
from etb_gym.rl.checkpoints import CheckpointError  # noqa: E402
from etb_gym.rl.task import TaskConfig  # noqa: E402
from etb_gym.rl.train import main as train_main  # noqa: E402

FAST_HP = {"learning_starts": 64, "buffer_size": 2_000, "batch_size": 32, "net_arch": [16, 16]}


@pytest.mark.parametrize("hp, expect", [
    ("gamma=1.5", "--hp gamma=1.5 is invalid for sac: expected a discount factor in (0, 1]"),
    ("batch_size=0", "--hp batch_size=0 is invalid for sac: expected an integer >= 1"),
    ("gamma=abc", "--hp gamma=abc is invalid for sac: expected a discount factor in (0, 1]"),
    ("net_arch=[64,0]", "--hp net_arch=[64, 0] is invalid for sac: expected a list of layer widths"),
    ("batch_size=5000", "--hp batch_size=5000 is invalid for sac: expected at most buffer_size (2000)"),
    ("gamm=0.9", "--hp gamm=0.9: 'gamm' is not a hyperparameter of sac; valid are"),
])
def test_hp_values_are_checked_before_the_run_folder_is_written(tmp_path, capsys, hp, expect):
    out = tmp_path / "run"
    argv = ["--out", str(out), "--hp", hp, "--no-progress"]
    if "5000" in hp:
        argv += ["--hp", "buffer_size=2000"]
    assert train_main(argv) == 2
    err = capsys.readouterr().err
    assert expect in err and "Traceback" not in err and err.count("\n") == 1
    assert not out.exists()


def test_hp_rules_follow_the_algorithm_signature():
    with pytest.raises(ValueError, match=r"--hp n_epochs=2.5 is invalid for ppo: expected an integer >= 1"):
        RunConfig(algo="ppo", hyperparams={"n_epochs": 2.5}).validate()
    with pytest.raises(ValueError, match=r"--hp sde_sample_freq=true is invalid for sac: expected an integer"):
        RunConfig(hyperparams={"sde_sample_freq": True}).validate()
    RunConfig(hyperparams={"ent_coef": "auto_0.1", "gamma": 1, "gradient_steps": -1}).validate()


# ------------------------------------------------------------------------------------------------ checkpoints
@pytest.fixture(scope="module")
def two_checkpoints(tmp_path_factory):
    out = tmp_path_factory.mktemp("rlck") / "run"
    cfg = RunConfig(timesteps=320, n_envs=2, seed=1, eval_freq=0, checkpoint_freq=160, hyperparams=dict(FAST_HP),
                    task={"episode_s": 0.1})
    train(cfg, out, progress=False, log=lambda *a: None)
    names = sorted(p.name for p in (out / "checkpoints").glob("ckpt_*.zip"))
    assert names == ["ckpt_160.zip", "ckpt_320.zip"]
    return out


def _truncate(path: Path, keep: float = 0.5):
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * keep)])


@pytest.mark.parametrize("damaged, offered", [("ckpt_320.zip", "ckpt_160"),
                                              ("ckpt_320_replay_buffer.pkl", "ckpt_160"),
                                              ("latest.json", "ckpt_320")])
def test_damaged_checkpoint_is_named_and_the_last_intact_one_offered(two_checkpoints, tmp_path, capsys, damaged,
                                                                     offered):
    run = tmp_path / "run"
    shutil.copytree(two_checkpoints, run)
    _truncate(run / "checkpoints" / damaged)
    before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
    assert train_main(["--resume", str(run), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert str(run / "checkpoints" / damaged) in err and "Traceback" not in err
    assert f"the last intact checkpoint is {offered}" in err and f"--checkpoint {offered}" in err
    assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before      # nothing touched


def test_resume_from_the_offered_checkpoint_finishes_the_run(two_checkpoints, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(two_checkpoints, run)
    _truncate(run / "checkpoints" / "ckpt_320_replay_buffer.pkl")
    with pytest.raises(CheckpointError, match="no such checkpoint .* available: ckpt_160, ckpt_320"):
        train(None, run, resume=True, checkpoint="ckpt_999", progress=False, log=lambda *a: None)
    model = train(None, run, resume=True, checkpoint="ckpt_160", progress=False, log=lambda *a: None)
    assert model.num_timesteps == 320
    assert json.loads((run / "status.json").read_text())["state"] == "finished"
    latest = json.loads((run / "checkpoints/latest.json").read_text())
    assert latest["model"] == "ckpt_320.zip"
    from etb_gym.rl.checkpoints import Checkpoints

    assert Checkpoints(run, "ETB-3B-v0", "sac").problem(latest) is None      # rewritten, intact


def test_checkpoints_without_digests_are_checked_by_structure(two_checkpoints, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(two_checkpoints, run)
    for p in (run / "checkpoints").glob("*.json"):          # a run written before digests were recorded
        e = json.loads(p.read_text())
        e.pop("files", None)
        p.write_text(json.dumps(e))
    _truncate(run / "checkpoints" / "ckpt_320_replay_buffer.pkl", 0.9)
    assert train_main(["--resume", str(run), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "ckpt_320_replay_buffer.pkl is truncated" in err and "--checkpoint ckpt_160" in err


def test_no_intact_checkpoint_says_to_start_again(two_checkpoints, tmp_path, capsys):
    run = tmp_path / "run"
    shutil.copytree(two_checkpoints, run)
    for name in ("ckpt_160.zip", "ckpt_320.zip"):
        _truncate(run / "checkpoints" / name, 0.3)
    assert train_main(["--resume", str(run), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "ckpt_320.zip" in err and "no intact checkpoint is left" in err and "--force" in err


# ------------------------------------------------------------------------------------------------ SIGKILL
KILL_CYCLES = int(os.environ.get("ETB_RL_KILL_CYCLES", "2"))
ARGS = ["--timesteps", "1200", "--n-envs", "2", "--seed", "2", "--checkpoint-freq", "200", "--eval-freq", "0",
        "--episode-s", "0.1", "--no-progress", "--hp", "learning_starts=64", "--hp", "buffer_size=2000",
        "--hp", "batch_size=32", "--hp", "net_arch=[16,16]"]


def _train_proc(argv):
    return subprocess.Popen([sys.executable, "-m", "etb_gym.rl.train", *argv], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)


def test_training_survives_sigkill_at_random_points(tmp_path):
    """Kill -9 the training process at random moments after its first checkpoint, resume, repeat; the run
    finishes with every timestep trained once, intact checkpoints and no temporary files left."""
    rng = random.Random(0)
    run = tmp_path / "run"
    proc, kills = _train_proc(["--out", str(run), *ARGS]), 0
    while True:
        if kills < KILL_CYCLES:
            t0 = time.monotonic()
            while not (run / "checkpoints" / "latest.json").exists() and proc.poll() is None:
                assert time.monotonic() - t0 < 300, "no checkpoint within 5 min"
                time.sleep(0.05)
            time.sleep(rng.uniform(0.0, 1.5))
            if proc.poll() is None:
                proc.send_signal(signal.SIGKILL)
                proc.wait()
                kills += 1
                proc = _train_proc(["--resume", str(run), "--no-progress"])
                continue
        rc = proc.wait(timeout=600)
        assert rc == 0, proc.stderr.read()
        break
    assert kills == KILL_CYCLES
    status = json.loads((run / "status.json").read_text())
    assert status["state"] == "finished" and status["timesteps"] == 1200
    assert not [p for p in run.rglob("*.tmp")]
    from etb_gym.rl.checkpoints import Checkpoints

    store = Checkpoints(run, "ETB-3B-v0", "sac")
    latest = store.resume_entry()
    assert latest["timesteps"] == 1200 and store.problem(latest) is None
    from stable_baselines3 import SAC

    model = SAC.load(str(run / "model.zip"), device="cpu")
    assert model.num_timesteps == 1200
    assert read_config(run).timesteps == 1200


# ------------------------------------------------------------------------------------------------ wrappers
def test_task_wrappers_on_gym_make_envs_equal_the_native_vector_env():
    """The agent's MDP is the registered env seen through Gymnasium wrappers: N gym.make envs in a
    SyncVectorEnv give the same features, rewards and episode ends as the native vector env, bit for bit."""
    from etb_gym.rl.wrappers import make_task_vec_env

    task = TaskConfig(residual="smc-plain", episode_s=0.05)
    a = make_task_vec_env("ETB-3B-v0", 2, task, seed=4, randomize=True)
    b = make_task_vec_env("ETB-3B-v0", 2, task, seed=4, randomize=True, vectorization_mode="sync")
    fa, _ = a.reset()
    fb, _ = b.reset()
    np.testing.assert_array_equal(fa, fb)
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(60):
        act = rng.uniform(-1, 1, 2)
        ra, rb = a.step(act), b.step(act)
        for x, y in zip(ra[:4], rb[:4]):
            np.testing.assert_array_equal(x, y)
        if ra[3].any():
            ends += 1
            np.testing.assert_array_equal(ra[4]["final_obs"], rb[4]["final_obs"])
    assert ends == 2 and fa.shape == (2, 12)


# ------------------------------------------------------------------------------------------------ fuzzing
def _hp_values():
    from hypothesis import strategies as st

    return st.one_of(st.integers(-3, 5000), st.floats(allow_nan=True, allow_infinity=True, width=32),
                     st.booleans(), st.sampled_from(["abc", "auto", "auto_0.1", "", "1e-3", "[64]"]),
                     st.lists(st.integers(-2, 64), max_size=3), st.none())


@pytest.mark.parametrize("algo", ["sac", "ppo"])
def test_fuzzed_hp_values_are_rejected_with_a_sentence_or_build_a_model(algo, tmp_path):
    """Every --hp value either fails validation with a sentence naming it, or SB3 builds the model with it:
    nothing invalid slips through to fail deep inside SB3 or torch."""
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    from etb_gym.rl import ALGORITHMS, make_model
    from etb_gym.rl.vecenv import make_training_env

    keys = sorted(set(ALGORITHMS[algo]["defaults"]) | {"utd", "ent_coef", "max_grad_norm"} - {"n_steps"})
    stats = {"rejected": 0, "built": 0}

    @settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
    @given(key=st.sampled_from(keys), value=_hp_values())
    def check(key, value):
        hp = {"n_steps": 64} if algo == "ppo" else {"buffer_size": 5000}      # small models, quick to build
        hp[key] = value
        cfg = RunConfig(algo=algo, n_envs=2, hyperparams=hp, task={"episode_s": 0.1})
        try:
            cfg.validate()
        except ValueError as exc:
            msg = str(exc)
            assert msg.startswith("--hp ") and "Traceback" not in msg and "np." not in msg
            stats["rejected"] += 1
            return
        env = make_training_env(cfg)
        try:
            make_model(cfg, env, None)
        finally:
            env.close()
        stats["built"] += 1

    check()
    assert stats["rejected"] >= 5 and stats["built"] >= 2, stats


def test_fuzzed_checkpoint_damage_is_always_refused_by_name(two_checkpoints, tmp_path):
    """Random truncations and byte flips of every checkpoint file: each resume is refused with a sentence
    naming the damaged file, and the run folder is left as it was."""
    rng = random.Random(1)
    files = ["ckpt_320.zip", "ckpt_320_replay_buffer.pkl", "latest.json", "ckpt_320.json"]
    for k in range(16):
        run = tmp_path / f"run{k}"
        shutil.copytree(two_checkpoints, run)
        target = run / "checkpoints" / files[k % len(files)]
        data = bytearray(target.read_bytes())
        if k % 2:
            data = data[:rng.randrange(0, len(data))]
        else:
            i = rng.randrange(len(data))
            data[i] ^= 1 << rng.randrange(8)
        target.write_bytes(bytes(data))
        before = {p: p.read_bytes() for p in run.rglob("*") if p.is_file()}
        try:
            entry = __import__("etb_gym.rl.checkpoints", fromlist=["Checkpoints"]).Checkpoints(
                run, "ETB-3B-v0", "sac").resume_entry()
        except CheckpointError as exc:
            msg = str(exc)
            assert target.name in msg or "latest.json" in msg, msg
            assert "--checkpoint ckpt_" in msg or "--force" in msg
        else:       # a flipped byte inside ckpt_320.json / latest.json that keeps it a valid, matching entry
            assert target.suffix == ".json" and entry["model"] == "ckpt_320.zip"
        assert {p: p.read_bytes() for p in run.rglob("*") if p.is_file()} == before
