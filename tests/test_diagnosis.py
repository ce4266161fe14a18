"""End-to-end diagnosis on small synthetic recordings (seeded): the proof script's quick mode, the clean
case, the report contract and the CLI."""
import json
from pathlib import Path

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.cli import main as cli_main
from etb_gym.components import effects as fx
from etb_gym.diagnose import diagnose
from etb_gym.diagnose.synthetic import make_recording
from etb_gym.plantfile import load_plant
from etb_gym.recordings import save_recording

ROOT = Path(__file__).resolve().parents[1]
SMALL = ("shaft_flux_loss", "spring_asymmetry", "sensor_offset_gain", "airflow_torque")


class _Prove:
    """The proof's library entry point (``etb_gym.diagnose.proof.run``: rows and per-family summary)."""

    @staticmethod
    def main(argv):
        from etb_gym.diagnose import proof
        return proof.run(argv)


def _prove():
    return _Prove


def test_quick_proof_names_the_concealed_effects_and_claims_nothing_on_clean_data():
    rows, fams = _prove().main(["--quick", "--families", "clean", "shaft_flux_loss", "sensor_offset_gain",
                                "--duration", "3", "--jobs", "1"])
    by = {r["family"]: r for r in rows}
    assert by["clean"]["effects"] == [] and by["clean"]["named"]
    assert by["shaft_flux_loss"]["named"] and by["sensor_offset_gain"]["named"]
    assert by["shaft_flux_loss"]["rms_after"] < 0.5 * by["shaft_flux_loss"]["rms_before"]


def test_quick_proof_names_an_electrical_and_a_friction_effect_with_their_parameters():
    """Two more families (electrical, friction) against a library that also holds their rivals."""
    rows, _ = _prove().main(["--quick", "--families", "coil_heating", "angle_dependent_friction", "--duration", "3",
                             "--jobs", "1", "--candidates", "coil_heating", "angle_dependent_friction",
                             "shaft_flux_loss", "sensor_offset_gain", "stribeck_friction"])
    for r in rows:
        assert r["effects"][:1] == [r["family"]], r
        assert r["param_rel_err"] < 0.10 and r["rms_after"] < 0.2 * r["rms_before"], r
        assert r["heldout_rms_after"] < 0.5 * r["heldout_rms_before"], r


def test_cli_writes_contract_report_and_loadable_plant(tmp_path, capsys):
    truth = make_plant("3B", substeps=40, effects=[fx.ShaftFluxLoss(loss_at_open_Nm_per_A=0.03, exponent=3.0)])
    rec = make_recording(truth, np.random.default_rng(3), duration_s=3.0, name="rig.csv")
    save_recording(rec, tmp_path / "rig.csv")
    out = tmp_path / "diag"
    rc = cli_main(["diagnose", str(tmp_path / "rig.csv"), "--model", "3B", "--out", str(out), "--quiet",
                   "--jobs", "1", "--max-effects", "1", "--candidates", *SMALL])
    assert rc == 0
    assert "verdict:" in capsys.readouterr().out
    rep = json.loads((out / "report.json").read_text())
    for k in ("schema", "model", "recordings", "verdict", "rms_before_deg", "rms_after_deg", "noise_floor_deg",
              "mismatch_windows_s", "effects", "unexplained", "calibrated_plant"):
        assert k in rep
    assert rep["schema"] == "etb-gym/diagnosis/1" and rep["recordings"] == ["rig.csv"]
    assert rep["verdict"] in ("explained", "partly_explained")
    e = rep["effects"][0]
    assert e["id"] == "shaft_flux_loss"
    p = e["parameters"]["loss_at_open_Nm_per_A"]
    assert set(p) == {"value", "stderr", "unit"} and abs(p["value"] - 0.03) < 0.003
    assert rep["mismatch_windows_s"]["rig.csv"], "the mismatch must be located"
    plant = load_plant(out / rep["calibrated_plant"])
    assert "shaft_flux_loss" in plant.component_names
    for f in ("report.md", "residual_time.png", "residual_regimes.png"):
        assert (out / f).stat().st_size > 0


def test_cli_rejects_bad_recording_with_a_message(tmp_path, capsys):
    p = tmp_path / "bad.csv"
    p.write_text("time_s,voltage_V\n" + "\n".join(f"{k * 1e-3},1.0" for k in range(300)))
    assert cli_main(["diagnose", str(p), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert "missing column 'angle_deg'" in capsys.readouterr().err


def test_diagnose_validates_options(tmp_path, capsys):
    with pytest.raises(ValueError, match="unknown candidate"):
        diagnose([], candidates=("warp_drive",))
    rec = make_recording(make_plant("3B"), np.random.default_rng(0), duration_s=0.6, name="r.csv")
    with pytest.raises(ValueError, match=r"substeps = 0\b.*positive integer"):
        diagnose([rec], substeps=0)
    save_recording(rec, tmp_path / "r.csv")
    assert cli_main(["diagnose", str(tmp_path / "r.csv"), "--out", str(tmp_path / "o"), "--substeps", "-3"]) == 2
    assert "--substeps: -3: expected a positive integer" in capsys.readouterr().err


def test_closed_loop_recording_is_the_reference_pid_on_the_sensor_readings():
    """Closed-loop rig data: the package's PID positions the truth from its own noisy, quantized readings,
    tracks the reference, and the recorded voltage is what it commanded (input depends on the output)."""
    truth = make_plant("3B", substeps=40)
    rec = make_recording(truth, np.random.default_rng(4), duration_s=3.0, closed=True, noise_deg=0.01)
    assert rec.n == 3000 and np.all(np.isfinite(rec.angle_deg))
    q = 90.0 / 4096
    assert np.allclose(rec.angle_deg / q, np.round(rec.angle_deg / q), atol=1e-6)      # 12-bit readings
    assert np.max(np.abs(rec.voltage_V)) <= truth.supply.voltage_V + 1e-9
    assert np.ptp(rec.angle_deg) > 20.0                     # it moved between reference levels ...
    fast = np.abs(np.diff(rec.angle_deg)) > 0.5             # ... and holds in between (no hunting limit cycle:
    assert fast.mean() < 0.05                                #     moving faster than 500 deg/s < 5 % of the time)


def test_integrator_step_is_chosen_below_the_noise_floor():
    """The diagnosis refines its integrator step until its own error is below half the noise floor: finer
    for a quiet sensor than for a noisy one."""
    from etb_gym.diagnose.model import prepare
    from etb_gym.diagnose.run import choose_substeps

    truth = make_plant("3B", substeps=80)
    steps = []
    for noise in (0.003, 0.1):
        rec = make_recording(truth, np.random.default_rng(5), duration_s=3.0, noise_deg=noise, resolution_deg=0.0)
        steps.append(choose_substeps(make_plant("3B"), prepare([rec], 12.0)))
    assert steps[0] > steps[1] and steps[1] >= 5, steps


def _regression_coverage(rho: float, reps: int = 300, seed: int = 0):
    """Monte Carlo: a linear output-error problem r = J dx + e with AR(1) errors of coefficient ``rho``,
    m = 10000 samples (10 s) in 0.5 s blocks at 1 kHz; coverage of value +- 1.645 stderr for the model-based and
    the block-robust estimates (FitResult.stderr takes the larger)."""
    from scipy.signal import lfilter

    from etb_gym.diagnose import fit as F
    from etb_gym.diagnose.model import Spec
    spec = Spec(make_plant("3B"))
    p = len(spec.params)
    rng = np.random.default_rng(seed)
    m = 10000
    t = np.arange(m) * 1e-3
    J = np.column_stack([np.sin(2 * np.pi * (k + 1) * 0.37 * t) + 0.3 * rng.standard_normal(m) for k in range(p)])
    blocks = np.floor(t / F.BLOCK_S).astype(int)
    hit_model, hit_robust = 0, 0
    scale = np.array([pp.scale for _, pp in spec.params])
    for _ in range(reps):
        w = rng.standard_normal(m)
        e = lfilter([np.sqrt(1 - rho ** 2)], [1.0, -rho], w)      # AR(1), unit stationary variance
        dx, *_ = np.linalg.lstsq(J, e, rcond=None)          # the estimate's error (truth at 0)
        r = e - J @ dx
        naive = F.FitResult(spec, dx, float(r @ r), m, J, 1, 1.0)
        robust = F.FitResult(spec, dx, float(r @ r), m, J, 1, 1.0, F.block_scores(J, r, blocks))
        se_n = np.array(list(naive.stderr().values())) / scale
        se_r = np.array(list(robust.stderr().values())) / scale
        hit_model += np.all(np.abs(dx) <= 1.645 * se_n)
        hit_robust += np.all(np.abs(dx) <= 1.645 * se_r)
    return hit_model / reps, hit_robust / reps, p


def test_block_robust_stderr_covers_the_truth_under_correlated_residuals():
    # correlated residuals (time constant ~100 samples): the white-noise formula's 90 % intervals are far
    # too narrow; the block-robust sandwich restores joint coverage close to 0.9^p
    naive, robust, p = _regression_coverage(rho=0.99, reps=150)
    assert naive < 0.5 * 0.9 ** p
    assert robust >= 0.75 * 0.9 ** p
    # white residuals: both estimates agree and cover
    naive_w, robust_w, _ = _regression_coverage(rho=0.0, reps=150, seed=1)
    assert naive_w >= 0.8 * 0.9 ** p and robust_w >= 0.8 * 0.9 ** p


def test_proof_finds_two_concealed_effects_at_once():
    """Shaft flux loss and coil heating concealed together: selection iterates and names both, with their
    parameters, against a library that also holds their electrical rivals."""
    rows, _ = _prove().main(["--pairs", "shaft_flux_loss+coil_heating", "--seeds", "1", "--duration", "4",
                             "--jobs", "1", "--candidates", "shaft_flux_loss", "coil_heating",
                             "torque_constant_error", "supply_drop", "sensor_offset_gain"])
    (r,) = rows
    assert r["named"] and min(r["effect_sizes"]) > 10, r
    assert all(p["param_rel_err"] < 0.10 for p in r["params"]), r
    assert r["rms_after"] < 0.1 * r["rms_before"] and r["heldout_rms_after"] < 0.5 * r["heldout_rms_before"], r
