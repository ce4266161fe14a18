"""The one speed harness, etb_gym.speed (``etb-gym speed``; scripts/bench_speed.py and etb_gym.envs.benchmark
are thin wrappers of it): a quick run prints the table and the JSON line, reports the plain path, finds the
equal-accuracy substeps, and rejects bad arguments (issues 7, 12, 14)."""
import json
import math
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from etb_gym import make_plant, speed
from etb_gym.components.base import REGISTRY
from etb_gym.integrate import FastPathUnavailableWarning, substeps_used
from etb_gym.jit import HAVE_NUMBA

from test_fast_path import _PlainTorque

ROOT = Path(__file__).resolve().parents[1]
QUICK = ["--repeats", "1", "--seconds", "0.01", "--num-envs", "1", "3", "--no-gem", "--no-reference",
         "--excitation-s", "0.05"]
REQUIRED = ("etb_steps_per_s", "etb_switching_realtime_factor", "vector_steps_per_s", "pendulum_steps_per_s",
            "gem_steps_per_s", "reset_us", "ratio_etb_vs_pendulum", "ratio_etb_vs_gem", "excitation_fast_s",
            "excitation_solve_ivp_s", "fast_path", "substeps_for_0p044_deg", "vector_steps_per_s_at_equal_accuracy",
            "vector_cpu_us_per_plant_step_at_equal_accuracy", "vector_steps_per_s_bound_at_equal_accuracy")


def test_quick_run_prints_table_and_json_last(capsys, tmp_path):
    out_json = tmp_path / "speed.json"
    res = speed.run(QUICK + ["--json-out", str(out_json), "--equal-accuracy-substeps", "5", "--compare", "CartPole-v1"])
    lines = capsys.readouterr().out.strip().splitlines()
    last = json.loads(lines[-1])
    assert set(REQUIRED) <= set(last)
    assert last["gem_steps_per_s"] is None and last["ratio_etb_vs_gem"] is None
    assert set(last["vector_steps_per_s"]) == {"1", "3"}
    assert all(v > 0 for v in last["vector_steps_per_s"].values())
    assert last["etb_steps_per_s"] > 0 and last["reset_us"] > 0
    assert last["substeps_for_0p044_deg"] == 5 and last["vector_steps_per_s_at_equal_accuracy"] > 0
    assert math.isclose(last["vector_steps_per_s_bound_at_equal_accuracy"],
                        last["machine"]["cpus"] * 1e6 / last["vector_cpu_us_per_plant_step_at_equal_accuracy"])
    assert last["compare_steps_per_s"]["CartPole-v1"] > 0
    assert math.isclose(last["etb_switching_realtime_factor"], last["etb_switching_steps_per_s"] * 1e-3)
    assert last["fast_path"] is HAVE_NUMBA
    assert any(l.startswith("| gym.make(\"ETB-3B-v0\")") for l in lines)
    assert json.loads(out_json.read_text()) == last == json.loads(json.dumps(res))
    assert speed.main(QUICK) == 0


def test_equal_accuracy_search_finds_the_fewest_substeps():
    args = speed.parse_args(["--env-id", "ETB-3B-v0"])
    eq = speed.find_equal_accuracy(args)
    n = eq["substeps"]
    assert n is not None and eq["rms_deg"] <= speed.EQUAL_ACCURACY_DEG
    fewer = [m for m in eq["tried"] if m < n]
    assert all(eq["tried"][m] > speed.EQUAL_ACCURACY_DEG for m in fewer)
    assert n <= 3          # the second-order stepper with the exponential bristle damping: 3 (0.037 deg), not 20
    assert n == substeps_used(1e-3, n)


def test_says_when_a_plant_is_on_the_plain_path(capsys, tmp_path, monkeypatch):
    from etb_gym.plantfile import save_plant

    class PlainTorqueEffect(_PlainTorque):
        kind = "test.plain_torque_bench"

    monkeypatch.setitem(REGISTRY, PlainTorqueEffect.kind, PlainTorqueEffect)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FastPathUnavailableWarning)
        path = tmp_path / "plain.json"
        save_plant(make_plant("3B", effects=[PlainTorqueEffect()]), path)
        res = speed.run(["--repeats", "1", "--seconds", "0.01", "--num-envs", "2", "--no-gem",
                         "--no-reference", "--excitation-s", "0.02", "--plant", str(path)])
    out = capsys.readouterr().out
    assert res["fast_path"] is False
    assert "PLAIN" in out and "no compiled kernel" in out


def test_baseline_tree_is_importable(tmp_path):
    """--baseline REV extracts REV with git archive and lays out its packages as pyproject.toml maps them."""
    if subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True).returncode:
        pytest.skip("not a git checkout")
    src, pkg = speed.extract_revision("HEAD", tmp_path)
    assert (src / "scripts" / "bench_speed.py").is_file()
    code = "import etb_gym.envs.vector as v, etb_gym.controllers as c; print(v.__file__)"
    out = subprocess.run([sys.executable, "-c", code], env={"PYTHONPATH": str(pkg), "PATH": "/usr/bin:/bin"},
                         cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().startswith(str(pkg))


def test_rejects_bad_arguments(capsys):
    for bad in (["--repeats", "0"], ["--seconds", "-1"], ["--num-envs", "0"], ["--plant", "/nonexistent.toml"],
                ["--threads", "0"], ["--baseline-substeps", "5"], ["--baseline", "HEAD", "--baseline-substeps", "0"]):
        with pytest.raises(SystemExit):
            speed.parse_args(bad)
        assert "expected" in capsys.readouterr().err


@pytest.mark.parametrize("cmd", [["scripts/bench_speed.py"], ["-m", "etb_gym.envs.benchmark"], ["-m", "etb_gym.speed"]])
def test_wrappers_are_the_one_harness(cmd):
    out = subprocess.run([sys.executable, *cmd, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "--baseline" in out.stdout and "--compare" in out.stdout and "--num-envs" in out.stdout


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba")
def test_vector_env_and_speed_harness_start_a_sleeping_thread_pool():
    """The vector env asks numba for its thread count before its first batch step; the pool must be configured
    to sleep before that (a spinning pool cost 5-7x CPU per plant-step on the loaded 2-core machine)."""
    import os
    import subprocess

    clean = {k: v for k, v in os.environ.items()
             if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "NUMBA_THREADING_LAYER")}
    code = ("import numpy as np, gymnasium as gym, etb_gym, etb_gym.integrate as I; "
            "e = gym.make_vec('ETB-3B-v0', num_envs=128); e.reset(seed=0); e.step(np.zeros((128, 1), np.float32)); "
            "from etb_gym.speed import machine_info; print(I.THREAD_POOL + '|' + machine_info()['thread_pool'])")
    out = subprocess.run([sys.executable, "-c", code], env=clean, capture_output=True, text=True, timeout=300,
                         check=True).stdout.strip().splitlines()[-1]
    assert out == "OMP_WAIT_POLICY=PASSIVE|OMP_WAIT_POLICY=PASSIVE"
