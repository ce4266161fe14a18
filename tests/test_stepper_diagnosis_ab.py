"""scripts/stepper_diagnosis_ab.py: its --help and the side-by-side table from rows (no diagnosis is run)."""
import json

import pytest
from scripts_loader import load_script


def _row(label, case, seed, substeps, cpu, effects, twin):
    return {"label": label, "case": case, "seed": seed, "closed": seed % 2 == 1, "noise_deg": 0.01,
            "substeps": substeps, "diag_cpu_s": cpu, "diag_wall_s": 2 * cpu, "effects": effects,
            "verdict": "explained" if effects else "match", "rms_after": 0.011, "twin": twin,
            "elapsed_breakdown_s": {"calibrate": cpu / 2, "explain": cpu / 2}}


def test_help():
    ab = load_script("stepper_diagnosis_ab")
    with pytest.raises(SystemExit) as e:
        ab.main(["--help"])
    assert e.value.code == 0


def test_summary_pairs_cases_and_medians(tmp_path, capsys):
    ab = load_script("stepper_diagnosis_ab")
    rows = [_row("A", "clean", 0, 160, 40.0, [], 1.0), _row("B", "clean", 0, 10, 20.0, [], 1.0),
            _row("A", "coil_heating", 0, 80, 100.0, ["coil_heating"], 1.2),
            _row("B", "coil_heating", 0, 20, 50.0, ["coil_heating"], 1.1),
            _row("A", "supply_drop", 1, 80, 10.0, ["supply_drop"], 1.2)]        # no B row: left out
    (tmp_path / "ab_rows.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    ab.main(["summary", "--out", str(tmp_path)])
    out = capsys.readouterr().out
    assert "| clean | 0 | open | 0.01 | 160 / 10 | 40.0 / 20.0 | 0.50 |" in out
    assert "supply_drop" not in out
    assert "2 cases, same effects and verdict 2/2" in out
    assert "A 70.0 s, B 35.0 s: B/A = 0.50 (change -50%)" in out
