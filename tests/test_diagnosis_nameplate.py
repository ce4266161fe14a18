"""The diagnosis on a user's plant file (another nameplate), and its failure paths: a candidate that cannot be
simulated is skipped with its reason, and a fit whose first simulation fails says so in a sentence."""
import json
import math

import numpy as np
import pytest

from etb_gym.cli import main as cli_main
from etb_gym.components import effects as fx
from etb_gym.diagnose import candidates as C
from etb_gym.diagnose import diagnose
from etb_gym.diagnose import fit as F
from etb_gym.diagnose.model import SimulationFailed, Spec, prepare, residual_size
from etb_gym.diagnose.synthetic import make_recording, nameplate_file_plant, random_nameplate
from etb_gym.plant import make_plant
from etb_gym.plantfile import load_plant, save_plant
from etb_gym.recordings import save_recording


def test_candidate_numbers_follow_the_nameplate():
    """For 3B every candidate keeps the library's numbers; for another nameplate they scale with it."""
    p3 = make_plant("3B")
    for c in C.CANDIDATES.values():
        assert c.params_for(p3) == tuple(c.fit), c.id
    other = make_plant("3B", {"drive.torque_constant_Nm_per_A": 0.066, "drive.resistance_ohm": 2.5,
                              "stops.open_rad": math.radians(82.0), "friction.coulomb_Nm": 0.1,
                              "friction.static_Nm": 0.11, "drive.inductance_H": 0.004})
    p = {f"{c.id}.{q.name}": q for c in C.CANDIDATES.values() for q in c.params_for(other)}
    ref = {f"{c.id}.{q.name}": q for c in C.CANDIDATES.values() for q in c.fit}
    assert p["torque_constant_error.delta_Nm_per_A"].scale == pytest.approx(0.5 * ref["torque_constant_error.delta_Nm_per_A"].scale)
    assert p["airflow_torque.quadratic_Nm"].upper == pytest.approx(0.25 * ref["airflow_torque.quadratic_Nm"].upper)
    assert p["stribeck_friction.stiction_Nm"].scale == pytest.approx(0.5 * ref["stribeck_friction.stiction_Nm"].scale)
    assert p["end_stop_compliance.open_rad"].init == pytest.approx(math.radians(82.0))
    assert p["inductance_saturation.inductance_drop_H"].upper < 0.004 * 0.3 * 0.8    # L stays positive


def _data(n=400):
    rec = make_recording(make_plant("3B"), np.random.default_rng(0), duration_s=n / 1000, name="r.csv")
    return prepare([rec], 12.0)


def test_fit_whose_first_simulation_fails_raises_a_sentence_not_a_type_error():
    data = _data()
    bad = C.Candidate("broken", "test", "exponent outside its valid range", (C.FitParam("exponent", 0.1, 0.0, 0.2, 0.05, "1"),),
                      fx.ShaftFluxLoss)
    spec = Spec(make_plant("3B")).with_candidate(bad)
    fun = F.make_fun(spec, data)
    r = fun(spec.x0())
    assert r.shape == (residual_size(data),) and np.all(r == F.FAIL) and "exponent" in fun.failure
    with pytest.raises(SimulationFailed, match=r"broken cannot be simulated .*exponent"):
        F.fit(spec, data)


def test_a_candidate_that_cannot_be_simulated_is_skipped_and_reported(monkeypatch):
    truth = make_plant("3B", substeps=40, effects=[fx.ShaftFluxLoss(loss_at_open_Nm_per_A=0.03, exponent=3.0)])
    rec = make_recording(truth, np.random.default_rng(3), duration_s=3.0, name="rig.csv")
    broken = C.Candidate("airflow_torque", "mechanical", "broken on purpose",
                         (C.FitParam("no_such_field", 0.0, -1.0, 1.0, 0.1, "N m"),), fx.AirflowTorque)
    monkeypatch.setitem(C.CANDIDATES, "airflow_torque", broken)
    res = diagnose([rec], jobs=1, progress=False, verbose=False, max_effects=1,
                   candidates=("shaft_flux_loss", "airflow_torque", "sensor_offset_gain"))
    assert [e["id"] for e in res.report["effects"]] == ["shaft_flux_loss"]
    (s,) = res.report["skipped_candidates"]
    assert s["id"] == "airflow_torque" and "no_such_field" in s["reason"]


@pytest.mark.parametrize("concealed", [False, True])
def test_cli_diagnoses_a_rig_of_another_nameplate_from_its_plant_file(tmp_path, concealed):
    """A throttle of another size (R, L, c_M, J, limp-home, stops), described by a plant file whose friction and
    spring are 10-20 % off: a concealed angle-dependent torque constant is named, a clean rig gives no effect."""
    rng = np.random.default_rng(11)
    truth = random_nameplate(rng, substeps=80)
    assert abs(truth.params_dict()["drive.resistance_ohm"] - 1.25) > 0.1
    file_plant = nameplate_file_plant(truth, rng)
    save_plant(file_plant, tmp_path / "rig_plant.toml")
    levels = ("friction.coulomb_Nm", "spring.preload_Nm", "spring.rate_Nm_per_rad")
    true_levels = {k: truth.params_dict()[k] for k in levels}
    if concealed:
        k = truth.params_dict()["drive.torque_constant_Nm_per_A"]
        truth = truth.replace(effects=[fx.ShaftFluxLoss(loss_at_open_Nm_per_A=0.2 * k, exponent=3.0)])
    rec = make_recording(truth, np.random.default_rng(12), duration_s=4.0, name="rig.csv")
    save_recording(rec, tmp_path / "rig.csv")
    out = tmp_path / "diag"
    rc = cli_main(["diagnose", str(tmp_path / "rig.csv"), "--plant", str(tmp_path / "rig_plant.toml"), "--out", str(out),
                   "--quiet", "--jobs", "1", "--max-effects", "1", "--candidates", "shaft_flux_loss", "airflow_torque",
                   "angle_dependent_friction", "torque_constant_error", "sensor_offset_gain"])
    assert rc == 0
    rep = json.loads((out / "report.json").read_text())
    assert [e["id"] for e in rep["effects"]] == (["shaft_flux_loss"] if concealed else [])
    assert rep["verdict"] == ("explained" if concealed else "match")
    assert rep["skipped_candidates"] == []
    plant = load_plant(out / rep["calibrated_plant"])
    assert plant.params_dict()["drive.resistance_ohm"] == truth.params_dict()["drive.resistance_ohm"]
    if not concealed:
        # the file's levels are 10-20 % off; the recording, not the file, decides them (docs/diagnosis-history.md round 16:
        # the calibration has no prior toward the file and lands on the truth's levels within 0.2 points)
        for k, v in true_levels.items():
            assert abs(file_plant.params_dict()[k] / v - 1) > 0.08
            assert abs(rep["calibrated_parameters"][k]["nominal_fit"] / v - 1) < 0.02, k
