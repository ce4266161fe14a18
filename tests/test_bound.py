"""The physical bound of a step (etb_gym.bound) and its place in the benchmark."""
import math

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.benchmark import (SCENARIOS, BoundJob, attach_bound, bound_plant, compute_bound, make_jobs, metrics,
                               run_sweep, step_band_deg)
from etb_gym.bound import duty_profile, settling_index, step_bound


def test_settling_index_is_the_benchmark_rule():
    phi = np.array([0.0, 0.5, 0.95, 1.02, 0.99, 1.0, 1.0])
    assert settling_index(phi, 1.0, 0.05) == 3
    assert settling_index(np.full(5, 1.0), 1.0, 0.05) == 0
    assert settling_index(np.array([1.0, 1.0, 2.0]), 1.0, 0.05) is None      # outside at the end: never


def test_duty_profile_is_admissible_and_holds_the_mean():
    d = duty_profile((0.0025, 0.001, -1.0, 0.0, 0.3), 10, 1e-3)
    assert np.all(np.abs(d) <= 1.0)
    assert d[0] == d[1] == 1.0 and d[2] == pytest.approx(0.5 * 1.0 + 0.5 * -1.0)
    assert d[3] == pytest.approx(0.5 * -1.0 + 0.5 * 0.3) and d[5] == pytest.approx(0.3)


def test_bound_of_the_large_step_and_its_trajectory():
    b = step_bound(make_plant("3B"), 10.0, 80.0, 1.4, 0.5)
    assert 0.025 < b.settling_time_s < 0.045               # about 34 ms (issue: ~38 ms by a plain search)
    k = int(round(b.settling_time_s / 1e-3))
    assert np.all(np.abs(b.angle_deg[k:] - 80.0) <= 1.4) and abs(b.angle_deg[k - 1] - 80.0) > 1.4
    # the recorded input reproduces the recorded trajectory on the plant
    assert b.duty.size == 500 and np.all(np.abs(b.duty) <= 1.0)


def test_weaker_battery_means_a_longer_bound():
    nominal = compute_bound(BoundJob("ETB-3B-v0", "step_10_80", "nominal"))["bound_s"]
    weak = compute_bound(BoundJob("ETB-3B-v0", "step_10_80", "supply_9V"))["bound_s"]
    assert weak > 1.3 * nominal
    assert bound_plant("ETB-3B-v0", "supply_9V").supply.voltage_V == 9.0


@pytest.mark.parametrize("controller", ["ptos", "pid-plain"])
def test_bound_is_never_above_a_controllers_settling(controller, tmp_path):
    scen = ["step_10_80", "step_80_10", "small_step_40", "small_step_limp_home_neg"]
    rows = run_sweep(make_jobs([controller], scen, ["nominal", "friction_+50"], [0]), tmp_path, workers=1,
                     progress=False)
    assert len(rows) == 8
    for r in rows:
        assert r["bound_s"] > 0
        if not math.isnan(r["settling_time_s"]):
            assert r["bound_s"] <= r["settling_time_s"] + 1e-12, r
            assert r["settling_ratio"] == pytest.approx(r["settling_time_s"] / r["bound_s"])
    assert (tmp_path / "bounds.json").exists()


def test_cached_bounds_are_reused_only_for_the_same_fingerprint(tmp_path):
    import json

    jobs = make_jobs(["pid-plain"], ["small_step_40"], ["nominal"], [0])
    run_sweep(jobs, tmp_path, workers=1, progress=False)
    cache = json.loads((tmp_path / "bounds.json").read_text())
    key = BoundJob("ETB-3B-v0", "small_step_40", "nominal").key
    cache[key]["bound_s"] = 0.001234                       # a cached value with the right fingerprint is used
    (tmp_path / "bounds.json").write_text(json.dumps(cache))
    rows = run_sweep(jobs, tmp_path, workers=1, progress=False)
    assert rows[0]["bound_s"] == 0.001234
    cache[key]["fingerprint"] = "stale"                    # a stale one is recomputed
    (tmp_path / "bounds.json").write_text(json.dumps(cache))
    rows = run_sweep(jobs, tmp_path, workers=1, progress=False)
    assert rows[0]["bound_s"] != 0.001234


def test_a_hold_that_misses_the_start_is_flagged_not_zero():
    sc = SCENARIOS["small_step_40"]
    t = np.arange(0, sc.duration_s + 1e-9, 1e-3)
    phi = np.where(t < 0.25, 40.0, 40.45)                  # the plate drifted to the target during the hold
    tr = {"t_s": t, "angle_deg": phi, "reference_deg": np.where(t < sc.step_at_s, 40.0, 40.5),
          "duty": np.zeros_like(t), "current_A": np.zeros_like(t)}
    m = metrics(tr, sc)
    assert math.isnan(m["settling_time_s"]) and m["step_start_deg"] == pytest.approx(40.45)
    assert step_band_deg(sc) == 0.1
    row = attach_bound({"env": "ETB-3B-v0", "scenario": "small_step_40", "variant": "nominal", **m},
                       {BoundJob("ETB-3B-v0", "small_step_40", "nominal").key: {"bound_s": 0.003}})
    assert row["bound_s"] == 0.003 and math.isnan(row["settling_ratio"])
