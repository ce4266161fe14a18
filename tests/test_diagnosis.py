"""End-to-end diagnosis on small synthetic recordings (seeded): the proof script's quick mode, the clean
case, the report contract and the CLI."""
import importlib.util
import json
import sys
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


def _prove():
    spec = importlib.util.spec_from_file_location("prove_diagnosis", ROOT / "scripts" / "prove_diagnosis.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("prove_diagnosis", mod)
    spec.loader.exec_module(mod)
    return mod


def test_quick_proof_names_the_concealed_effects_and_claims_nothing_on_clean_data():
    rows, fams = _prove().main(["--quick", "--families", "clean", "shaft_flux_loss", "sensor_offset_gain",
                                "--duration", "3", "--jobs", "1"])
    by = {r["family"]: r for r in rows}
    assert by["clean"]["effects"] == [] and by["clean"]["named"]
    assert by["shaft_flux_loss"]["named"] and by["sensor_offset_gain"]["named"]
    assert by["shaft_flux_loss"]["rms_after"] < 0.5 * by["shaft_flux_loss"]["rms_before"]


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


def test_diagnose_validates_options():
    with pytest.raises(ValueError, match="unknown candidate"):
        diagnose([], candidates=("warp_drive",))
