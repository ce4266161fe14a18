"""The fuzz harness of `etb-gym diagnose` (scripts/fuzz_diagnose.py, issue 15) and the regressions it found:
random nameplates for every base model, its solve_ivp re-implementation of the documented equations, and one
end-to-end case through the command line."""
import math

import numpy as np
import pytest

from etb_gym.diagnose.synthetic import NAMEPLATE_RANGES, random_nameplate
from etb_gym.plant import MODELS, make_plant
from scripts_loader import load_script

fuzz = load_script("fuzz_diagnose")


@pytest.mark.parametrize("model", MODELS)
def test_random_nameplate_builds_every_base_model_with_pinned_extremes(model):
    """Regression: drive C has no torque_constant parameter (k_C = N psi_hat), and random_nameplate raised
    "unknown parameter 'torque_constant_Nm_per_A'" for 1C, 2C, 3C; now its turns are scaled to the drawn c_M."""
    fixed = {"drive.inductance_H": 30e-3, "spring.limp_home_deg": 8.0, "stops.open_deg": 80.0}
    p = random_nameplate(np.random.default_rng(5), model, fixed=fixed)
    pd = p.params_dict()
    assert pd["drive.inductance_H"] == pytest.approx(30e-3)
    assert math.degrees(pd["spring.limp_home_rad"]) == pytest.approx(8.0)
    assert math.degrees(pd["stops.open_rad"]) == pytest.approx(80.0)
    lo, hi = NAMEPLATE_RANGES["drive.torque_constant_Nm_per_A"]
    assert lo <= p.drive.params.torque_constant_Nm_per_A <= hi
    with pytest.raises(ValueError, match="inductance_mH"):
        random_nameplate(np.random.default_rng(5), model, fixed={"inductance_mH": 3.0})


def test_ivp_reimplementation_agrees_with_the_plant():
    """The harness's solve_ivp plant (written from docs/model.md alone) follows etb_gym's stepper on 3B (drive
    B, LuGre, spring, stops): a check that its recordings are the documented physics, not something else."""
    p = make_plant("3B")
    duty = np.concatenate([np.full(150, 0.45), np.full(100, -0.2), np.zeros(100)])
    X = fuzz.IvpPlant(p).simulate(duty)
    tr = p.simulate(duty=duty, angle_deg=math.degrees(p.limp_home_rad))
    assert np.max(np.abs(np.degrees(X[:, 0]) - np.degrees(tr.angle_rad))) < 0.05
    assert np.max(np.abs(X[:, 2] - tr.current_A)) < 0.01


def test_one_fuzz_case_runs_the_cli_end_to_end(tmp_path):
    """One short case (a random 3B-type nameplate, the solve_ivp recording at 800 Hz with coloured noise and no
    current, as .mat with aliased column names, a plant file 10-20 % off): the CLI ends in a report or a clear
    refusal or failure, never a BUG."""
    c = fuzz.draw_case(np.random.default_rng(0), 7)
    c.update(model="3B", source="ivp", fs_hz=800.0, duration_s=1.0, closed=False, colour=0.8, current=False,
             supply=True, format=".mat", names=1, candidates=["sensor_offset_gain"])
    row = fuzz.run_case(c, timeout_s=600.0)
    assert row["outcome"] in ("ok", "refused", "failed"), row


def test_csv_value_with_an_underscore_is_not_read_as_a_number(tmp_path):
    """Regression (found by the loader fuzz): Python's float() reads "6_0" as 60, so a mistyped CSV cell became a
    silent 60 V; now it is refused, naming the file, the column, the row and the line."""
    from etb_gym.recordings import RecordingError, load_recording
    t = np.arange(300) * 1e-3
    rows = [f"{x:.3f},{'6_0' if k == 101 else '6.0'},{5 + 10 * x:.4f}" for k, x in enumerate(t)]
    p = tmp_path / "rig.csv"
    p.write_text("time_s,voltage_V,angle_deg\n" + "\n".join(rows) + "\n")
    with pytest.raises(RecordingError, match=r"rig\.csv: column 'voltage_V', row 101: '6_0' is not a number"):
        load_recording(p)


def test_columns_of_different_lengths_name_both(tmp_path):
    """A scalar time column used to read "column 'angle_deg' has 300 rows: expected 1 like 'time_s'"."""
    from etb_gym.recordings import RecordingError, load_recording
    p = tmp_path / "rig.npz"
    np.savez(p, time_s=np.float64(1.0), voltage_V=np.zeros(300), angle_deg=np.full(300, 5.0))
    with pytest.raises(RecordingError, match=r"rig\.npz: column '\w+' has 300 rows but 'time_s' has 1"):
        load_recording(p)


def test_a_candidate_tied_to_a_missing_component_is_refused_not_a_key_error():
    """Regression (found by the plant-file fuzz): a plant file without a spring (``"spring": null``) and the
    candidate spring_asymmetry, which copies the spring's limp-home angle, raised KeyError 'spring.limp_home_rad'
    from the fit (the CLI's "internal error"); now building the model raises a ValueError naming what is
    missing, so the selection skips the candidate and lists it under skipped_candidates."""
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.model import Spec
    from etb_gym.plant import Plant
    d = make_plant("3B").to_dict()
    d["spring"] = None
    spec = Spec(Plant.from_dict(d)).with_candidate(CANDIDATES["spring_asymmetry"])
    with pytest.raises(ValueError, match=r"spring_asymmetry needs the plant's spring\.limp_home_rad.*no spring component"):
        spec.build(np.zeros(len(spec.params)))


@pytest.mark.parametrize("args, words", [
    (["--jobs", "100000"], ["--jobs", "100000", "an integer >= 1 and <="]),
    (["--jobs", "1_0"], ["--jobs", "'1_0' is not a whole number"]),
    (["--substeps", "1000000000"], ["--substeps", "1000000000", "positive integer <= 1000"]),
    (["--sensor-resolution-deg", "1e300"], ["--sensor-resolution-deg", "1e300", "at most 10 deg"]),
    (["--sensor-resolution-deg", "1_0"], ["--sensor-resolution-deg", "'1_0' is not a number"]),
    (["--out", ""], ["--out", "'' is empty", "output folder"]),
    (["--plant", " "], ["--plant", "' ' is empty", "plant file"]),
])
def test_option_values_out_of_reason_are_refused_naming_option_and_value(tmp_path, monkeypatch, capsys, args,
                                                                         words):
    """Regression (round 28 option fuzz): --jobs 100000 forked 100000 workers, --substeps 1e9 ran forever,
    --sensor-resolution-deg 1e300 was assumed, "1_0" was read as 10, and an empty --out wrote the report into the
    working folder while an empty --plant silently meant none; now each is refused before any work (exit 2)."""
    from etb_gym.diagnose import cli as dcli
    reached = []
    monkeypatch.setattr(dcli, "_diagnose", lambda *a: reached.append(a))
    rec = tmp_path / "r.csv"
    t = np.arange(600) * 1e-3
    np.savetxt(rec, np.column_stack([t, np.where(t > 0.2, 3.0, 0.0), np.full(t.size, 7.0)]), delimiter=",",
               header="time_s,voltage_V,angle_deg", comments="")
    argv = [str(rec), *([] if "--out" in args else ["--out", str(tmp_path / "o")]), *args]
    code = dcli.main(argv)
    err = capsys.readouterr().err
    assert code == 2 and not reached and "Traceback" not in err
    for w in words:
        assert w in err, (w, err)


def test_fuzz_draws_concealed_effects_without_changing_the_clean_draws():
    """The fuzz's effect cases (round 28): a share of the cases carries a proof family and truth shape, drawn from
    the case's own seed, so --effects 0 draws exactly the clean cases of before; the truth carries the effect,
    the user's plant file does not, the family is the first candidate, and such a truth is recorded by
    etb_gym's plant (IvpPlant re-implements no effect)."""
    clean = [fuzz.draw_case(np.random.default_rng(3), k) for k in range(4)]
    some = [fuzz.draw_case(np.random.default_rng(3), k, 1.0) for k in range(4)]
    for a, b in zip(clean, some):
        assert a["effect"] is None and b["effect"] is not None
        assert {k: v for k, v in a.items() if not k.startswith("effect")} == \
            {k: v for k, v in b.items() if not k.startswith("effect")}
    c = dict(some[0], effect="backlash@1", effect_scale=0.5, source="ivp", closed=False)
    truth, file_plant, sensor_kw = fuzz.truth_and_file(c)
    assert truth.effects and not file_plant.effects and sensor_kw == {}
    assert not fuzz.ivp_source(c, truth) and fuzz.candidates(c)[0] == "backlash" and len(fuzz.candidates(c)) == 2
    c = dict(c, effect="sensor_delay@2")
    truth, _, sensor_kw = fuzz.truth_and_file(c)
    assert not truth.effects and "reading" in sensor_kw and fuzz.ivp_source(c, truth)
    assert fuzz.candidates(dict(c, effect="detent_torque")) == c["candidates"]


def test_fuzz_twin_check_loads_simulates_and_drives_the_env(tmp_path):
    """check_twin: a plant file loads back, simulates a recording's voltage within its stops and runs the env;
    a file that does not load is a BUG naming the file."""
    from etb_gym.diagnose.synthetic import make_recording
    from etb_gym.plantfile import save_plant
    p = make_plant("3B", substeps=10)
    rec = make_recording(p, np.random.default_rng(0), duration_s=0.6)
    assert fuzz.check_twin(save_plant(p, tmp_path / "twin.toml"), rec).startswith("ok: replay")
    (tmp_path / "bad.toml").write_text("[drive]\nkind = 3\n")
    assert fuzz.check_twin(tmp_path / "bad.toml", rec).startswith("BUG: the twin bad.toml:")


def test_the_catalogue_alternative_stays_within_the_users_library():
    """Regression (round 28 effect fuzz): refine's catalogue alternative tried every family of the generic
    tables' terms, whatever --candidates allowed: with --candidates angle_dependent_friction supply_drop a 2C closed
    loop was "explained" by shaft_flux_loss. Now the run passes its library and only its families are tried."""
    import inspect
    from etb_gym.diagnose import run
    from etb_gym.diagnose.refine import FAMILY_OF_TERM, families_of_term
    assert families_of_term() == FAMILY_OF_TERM
    lib = families_of_term(("angle_dependent_friction", "supply_drop"))
    assert lib["unmodelled_current"] == () and lib["unmodelled_angle"] == ("angle_dependent_friction",)
    assert lib["unmodelled_voltage"] == ("supply_drop",)
    assert "library=tuple(opts.candidates)" in inspect.getsource(run)
