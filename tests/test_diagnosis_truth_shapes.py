"""The proof's truth shapes that are not the candidates' formulas (diagnose.truth_shapes, proof_truth.truth_shape)
and one end-to-end case: a shaft flux loss with a logistic angle profile (not the candidate's power law) is
named, and its refined twin predicts a held-out recording better than the formula's twin."""
import json
import math

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.diagnose import truth_shapes as ts
from etb_gym.diagnose.proof_truth import FAMILIES, OUTSIDE, family_shape, truth_for, truth_plant

SHAPED = [f for f in FAMILIES if f != "clean" and f not in OUTSIDE]


@pytest.mark.parametrize("family", SHAPED)
@pytest.mark.parametrize("shape", [1, 2])
def test_every_family_has_two_shapes_that_are_not_candidate_formulas(family, shape):
    rng = np.random.default_rng(0)
    effects, sensor_kw, pname, _ = truth_for(family, rng, 0.5, shape)
    comps = list(effects) + ([sensor_kw["reading"]] if "reading" in sensor_kw else [])
    assert len(comps) == 1 and comps[0].kind.startswith("truth."), comps
    assert pname is None                       # no candidate parameter to compare with
    other = truth_for(family, np.random.default_rng(0), 0.5, 3 - shape)[:2]
    o = list(other[0]) + ([other[1]["reading"]] if "reading" in other[1] else [])
    assert o[0].params != comps[0].params      # the two shapes differ


def test_family_shape_names_and_errors():
    assert family_shape("backlash@2") == ("backlash", 2) and family_shape("clean") == ("clean", 0)
    with pytest.raises(ValueError, match="shape 1 is not defined for clean"):
        family_shape("clean@1")
    with pytest.raises(ValueError, match="family 'nope'"):
        family_shape("nope@1")
    with pytest.raises(ValueError, match=r"SpringShapeParams.profile = 3.0 is invalid: expected one of 0, 1"):
        ts.SpringShape(profile=3.0)


def test_spring_and_stop_shapes_are_tied_to_the_truth_plant():
    rng = np.random.default_rng(1)
    effects, *_ = truth_for("backlash", rng, 0.5, 1)
    p = truth_plant(rng, effects, substeps=20)
    e = p.effects[0]
    assert e.params.preload_Nm == p.spring.params.preload_Nm and e.params.limp_home_rad == p.spring.params.limp_home_rad
    effects, *_ = truth_for("end_stop_compliance", np.random.default_rng(2), 1.0, 1)
    p = truth_plant(np.random.default_rng(2), effects, substeps=20, nameplate="random")
    assert p.effects[0].params.contact_rad < p.angle_max_rad


def test_sensor_shapes_act_as_described():
    phi = np.radians(np.concatenate([np.full(20, 10.0), np.full(40, 30.0)]))
    lp = ts.SensorFilter(time_constant_s=0.004).apply(phi)
    assert lp[19] == pytest.approx(phi[0]) and phi[0] < lp[21] < phi[-1] and lp[-1] == pytest.approx(phi[-1], abs=1e-4)
    ma = ts.SensorFilter(average_samples=4, profile=1.0).apply(phi)
    assert ma[22] == pytest.approx(0.25 * phi[0] + 0.75 * phi[-1]) and ma[23] == pytest.approx(phi[-1])
    q = math.radians(90.0 / 256)
    ramp = np.linspace(0.0, 20 * q, 2001)
    codes = ts.SensorCodes(resolution_rad=q, nonlinearity=0.5).apply(ramp)
    widths = np.diff(ramp[np.flatnonzero(np.diff(codes)) + 1])
    assert np.allclose(np.sort(widths)[[0, -1]] / q, [0.5, 1.5], atol=0.02)    # uneven codes, mean q
    hy = ts.SensorCodes(resolution_rad=q, hysteresis=0.5, profile=1.0)
    up_down = hy.apply(np.concatenate([ramp, ramp[::-1]]))
    assert np.max(np.abs(up_down[:ramp.size] - ramp)) > 0.9 * q                  # lags by the hysteresis
    bow = ts.SensorCurve(bow_rad=0.01).apply(np.radians([0.0, 45.0, 90.0]))
    assert bow == pytest.approx(np.radians([0.0, 45.0, 90.0]) + [0.0, 0.01, 0.0], abs=1e-12)


def test_non_formula_flux_loss_is_named_and_its_refined_twin_beats_the_formula(tmp_path):
    """A torque constant that falls in a logistic step at 55 deg (shape 1 of shaft_flux_loss): the catalogue
    names shaft_flux_loss, 3b keeps a torque-constant table beside the power law, and the exported twin predicts
    a held-out (closed-loop) recording better than the same twin without the table."""
    from etb_gym.diagnose import diagnose
    from etb_gym.diagnose.model import angle_residuals_deg, prepare, simulate
    from etb_gym.diagnose.synthetic import make_recording
    from etb_gym.plantfile import load_plant
    loss = ts.TorqueConstantProfile(loss_Nm_per_A=0.03, onset_rad=math.radians(55.0), width_rad=math.radians(4.0))
    truth = make_plant("3B", substeps=40, effects=[loss])
    rec = make_recording(truth, np.random.default_rng(4), duration_s=4.0, name="flux.csv")
    held = make_recording(truth, np.random.default_rng(5), duration_s=4.0, closed=True, name="held.csv")
    res = diagnose([rec], out=tmp_path / "d", jobs=1, progress=False, verbose=False, max_effects=1, substeps=20,
                   candidates=("shaft_flux_loss", "airflow_torque", "torque_constant_error"))
    rep = json.loads((tmp_path / "d" / "report.json").read_text())
    assert [e["id"] for e in rep["effects"]] == ["shaft_flux_loss"], rep["effects"]
    assert "shape" in rep["effects"][0], rep["effects"][0]
    twin = load_plant(tmp_path / "d" / "calibrated_plant.toml")
    assert any(e.kind == "effect.torque_constant_map" for e in twin.effects)
    formula_twin = twin.replace(effects=tuple(e for e in twin.effects if e.kind != "effect.torque_constant_map"))
    hd = prepare([held], 12.0)
    rms = lambda p: float(np.sqrt(np.mean(angle_residuals_deg(simulate(p, res.sensor, hd), hd)[0] ** 2)))
    r_map, r_formula = rms(twin), rms(formula_twin)
    assert r_map < 0.8 * r_formula, (r_map, r_formula)


def test_proof_runs_shapes_as_families_and_outside_families_only_as_shape_0():
    from etb_gym.diagnose import proof
    a = proof._parser().parse_args(["--shapes", "0", "2", "--seeds", "1", "--families", "clean", "backlash",
                                    "current_ripple"])
    assert proof._plan(a)[3] == [("clean", 0), ("backlash", 0), ("backlash@2", 0), ("current_ripple", 0)]
    a = proof._parser().parse_args(["--shapes", "1", "2", "--seeds", "1"])
    todo = [f for f, _ in proof._plan(a)[3]]
    assert len(todo) == 2 * len(SHAPED) and all("@" in f for f in todo)


def test_outside_score_needs_no_catalogue_effect_and_the_period():
    from etb_gym.diagnose.proof import score_outside
    rep = {"unexplained": [{"id": "unmodelled_torque", "outside_catalogue": True, "description": "outside ...",
                            "shape": {"angle": {"periodic": False}, "current": {"periodic": True, "period_deg": 20.2}}}]}
    row = {"effects": []}
    score_outside(row, rep, 20.0)
    assert row["named"] and row["period_deg"] == 20.2
    row = {"effects": ["shaft_flux_loss"]}
    score_outside(row, rep, 20.0)
    assert not row["named"]
    row = {"effects": []}
    score_outside(row, rep, 25.0)                       # period more than 10 % off
    assert not row["named"]


@pytest.mark.parametrize("shape", [0, 1, 2])
def test_inductance_truths_stay_physical_on_a_small_inductance_nameplate(shape):
    """A 3B-sized inductance drop (up to 4.5 mH) on a 2 mH nameplate made the truth's inductance negative and
    its recording diverge (survey case inductance_saturation@1, random nameplate, seed 0): the drop follows
    the plant's inductance (and the knee its current); on 3B nothing changes."""
    from etb_gym.diagnose.proof_truth import tie
    effects = truth_for("inductance_saturation", np.random.default_rng(1), 1.0, shape)[0]
    base = make_plant("3B")
    assert tie(effects, base)[0].params == effects[0].params
    small = base.with_params({"drive.inductance_H": 0.002, "drive.resistance_ohm": 2.5})
    e = tie(effects, small)[0].params
    assert math.isclose(e.inductance_drop_H, 0.1 * effects[0].params.inductance_drop_H)
    assert e.inductance_drop_H < 0.3 * 0.002                 # below the drive's saturated inductance
    knee = "saturation_current_A" if shape == 0 else "knee_current_A"
    assert math.isclose(getattr(e, knee), 0.5 * getattr(effects[0].params, knee))
