"""report.json twin_range: where the exported twin extrapolates in angle (diagnose/twin_range.py)."""
from types import SimpleNamespace

import numpy as np

from etb_gym.diagnose.twin_range import describe
from etb_gym.plant import make_plant


def _data(angles_deg):
    return SimpleNamespace(recs=[SimpleNamespace(rec=SimpleNamespace(angle_deg=np.asarray(angles_deg, float)))])


def test_a_twin_trained_on_part_of_the_stroke_says_where_it_extrapolates():
    plant = make_plant("3B")
    lo_stop, hi_stop = np.degrees(plant.angle_min_rad), np.degrees(plant.angle_max_rad)
    d = describe(plant, plant, _data(np.linspace(10.0, 60.0, 2001)))
    assert [b["side"] for b in d["beyond"]] == ["below", "above"]
    assert d["beyond"][0]["from_deg"] == lo_stop and abs(d["beyond"][0]["to_deg"] - 10.0) < 0.1
    assert abs(d["beyond"][1]["from_deg"] - 60.0) < 0.1 and d["beyond"][1]["to_deg"] == hi_stop
    # the twin is the nominal model here: nothing extrapolated beyond it
    assert d["beyond"][0]["correction_Nm_far"] == 0.0 and d["beyond"][1]["correction_Nm_edge"] == 0.0
    assert "extrapolates over" in d["words"]


def test_a_twin_trained_over_the_whole_stroke_reports_no_span():
    plant = make_plant("3B")
    d = describe(plant, plant, _data(np.linspace(np.degrees(plant.angle_min_rad), np.degrees(plant.angle_max_rad), 999)))
    assert d["beyond"] == [] and "the whole stroke" in d["words"]


def test_the_correction_beyond_the_data_is_the_twins_torque_minus_the_nominals():
    plant = make_plant("3B")
    stiffer = plant.with_params({"spring.rate_Nm_per_rad": plant.params_dict()["spring.rate_Nm_per_rad"] * 1.1})
    d = describe(stiffer, plant, _data(np.linspace(20.0, 60.0, 501)))
    above = d["beyond"][1]
    assert above["correction_Nm_far"] is not None and abs(above["correction_Nm_far"]) > abs(above["correction_Nm_edge"])


def test_a_heating_time_constant_longer_than_the_recording_is_reported_as_extrapolated_in_time():
    from etb_gym.components.effects_electrical import CoilHeating
    plant = make_plant("3B")
    slow = plant.replace(effects=tuple(plant.effects) + (CoilHeating(CoilHeating.Params(
        heat_capacity_J_per_K=3.3, thermal_resistance_K_per_W=6.1)),))       # tau 20 s
    t = np.linspace(0.0, 6.0, 6001)
    data = SimpleNamespace(recs=[SimpleNamespace(rec=SimpleNamespace(angle_deg=np.linspace(10.0, 60.0, t.size),
                                                                     t_s=t))])
    d = describe(slow, plant, data)
    assert [s["effect"] for s in d["slow_states"]] == ["coil_heating"]
    assert abs(d["slow_states"][0]["tau_s"] - 3.3 * 6.1) < 1e-9 and d["slow_states"][0]["recording_s"] == 6.0
    assert "time constant 20.1 s exceeds the 6.0 s recording" in d["words"]
    fast = plant.replace(effects=tuple(plant.effects) + (CoilHeating(CoilHeating.Params(
        heat_capacity_J_per_K=0.5, thermal_resistance_K_per_W=2.0)),))       # tau 1 s: settles inside it
    assert describe(fast, plant, data)["slow_states"] == []


def test_a_thermal_network_branch_slower_than_the_recording_is_reported_as_extrapolated_in_time():
    """A learned Foster network's slowest branch (3x the recording by construction) counts only when it carries
    heat: the state's settled level is then an extrapolation, as for one slow node."""
    from etb_gym.components.effects_thermal import ThermalNetwork
    plant = make_plant("3B")
    t = np.linspace(0.0, 6.0, 6001)
    data = SimpleNamespace(recs=[SimpleNamespace(rec=SimpleNamespace(angle_deg=np.linspace(10.0, 60.0, t.size),
                                                                     t_s=t))])

    def with_network(r):
        net = ThermalNetwork(ThermalNetwork.Params(time_constant_s=(0.5, 3.0, 18.0), thermal_resistance_K_per_W=r))
        return plant.replace(effects=tuple(plant.effects) + (net,))
    d = describe(with_network((1.0, 2.0, 4.0)), plant, data)["slow_states"]
    assert [(s["parameter"], s["tau_s"]) for s in d] == [("time_constant_s[2]", 18.0)]
    assert describe(with_network((1.0, 2.0, 0.0)), plant, data)["slow_states"] == []   # the slow branch is empty


def test_angles_the_training_only_passed_at_speed_are_reported():
    """twin_range.passed_only: inside the visited range, >= 5 deg where the recording spent < 5 ms per degree."""
    plant = make_plant("3B")
    t = np.arange(0.0, 6.0, 1e-3)
    a = np.where(t < 3.0, 20.0, 80.0)             # holds at 20 and 80 deg ...
    ramp = (t >= 3.0) & (t < 3.2)                  # ... and one pass 20 -> 80 deg at 300 deg/s
    a[ramp] = 20.0 + 300.0 * (t[ramp] - 3.0)
    a[t >= 3.2] = 80.0
    data = SimpleNamespace(recs=[SimpleNamespace(rec=SimpleNamespace(angle_deg=a, t_s=t))])
    d = describe(plant, plant, data)
    (p,) = d["passed_only"]
    assert p["from_deg"] <= 22.0 and p["to_deg"] >= 78.0 and abs(p["s_per_deg"] - 1.0 / 300.0) < 1e-3
    assert "only at speed" in d["words"]
    slow = np.linspace(20.0, 80.0, t.size)        # a slow sweep: 100 ms per degree
    d = describe(plant, plant, SimpleNamespace(recs=[SimpleNamespace(rec=SimpleNamespace(angle_deg=slow, t_s=t))]))
    assert d["passed_only"] == [] and "only at speed" not in d["words"]
