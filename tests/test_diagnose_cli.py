"""etb-gym diagnose: every failure path before and after the work, exit codes, no result ever lost."""
import json
import os
import stat

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.cli import main as top_main
from etb_gym.diagnose import cli as dcli
from etb_gym.diagnose.report import REPORT_FILES
from etb_gym.diagnose.synthetic import make_recording
from etb_gym.plantfile import save_plant
from etb_gym.recordings import save_recording


class Stop(BaseException):
    pass


@pytest.fixture
def rec_path(tmp_path):
    rec = make_recording(make_plant("3B"), np.random.default_rng(0), duration_s=0.6, name="r.csv")
    return save_recording(rec, tmp_path / "r.csv")


@pytest.fixture
def reached(monkeypatch):
    """Stop right where the expensive diagnosis would start; record that the inputs were accepted."""
    seen = []

    def fake(recs, out, opts):
        seen.append((recs, out, opts))
        raise Stop
    monkeypatch.setattr(dcli, "_diagnose", fake)
    return seen


def _snapshot(d):
    return {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in d.rglob("*") if p.is_file()}


@pytest.mark.parametrize("args, words", [
    (["--sensor-resolution-deg", "-1"], ["--sensor-resolution-deg", "-1", "finite angle > 0 deg"]),
    (["--sensor-resolution-deg", "nan"], ["--sensor-resolution-deg", "nan", "finite angle > 0 deg"]),
    (["--sensor-resolution-deg", "inf"], ["--sensor-resolution-deg", "finite angle"]),
    (["--sensor-resolution-deg", "fine"], ["--sensor-resolution-deg", "'fine' is not a number"]),
    (["--jobs", "0"], ["--jobs", "integer >= 1"]),
    (["--jobs", "1.5"], ["--jobs", "not a whole number"]),
    (["--max-effects", "-1"], ["--max-effects", "integer >= 0"]),
    (["--substeps", "-3"], ["--substeps", "positive integer"]),
    (["--model", "4Z"], ["--model", "invalid choice"]),
    (["--candidates", "warp_drive"], ["--candidates", "invalid choice"]),
    (["--residual", "kalman"], ["--residual", "invalid choice", "observer"]),
])
def test_bad_options_rejected_before_work(tmp_path, rec_path, reached, capsys, args, words):
    out = tmp_path / "o"
    assert dcli.main([str(rec_path), "--out", str(out), *args]) == 2
    err = capsys.readouterr().err
    for w in words:
        assert w in err, (w, err)
    assert "Traceback" not in err and not out.exists() and not reached


@pytest.mark.parametrize("value", ["auto", "replay", "observer"])
def test_residual_option_reaches_the_diagnosis(tmp_path, rec_path, reached, value):
    with pytest.raises(Stop):
        dcli.main([str(rec_path), "--out", str(tmp_path / "o"), "--residual", value])
    assert reached[0][2].residual == value


@pytest.mark.parametrize("flag, value", [([], True), (["--rest-not-at-limp-home"], False)])
def test_rest_option_reaches_the_diagnosis(tmp_path, rec_path, reached, flag, value):
    """--rest-not-at-limp-home: a rig whose plate may rest off limp-home unpowered (static friction above the
    springs' preload) must not have a sensor offset read from its rest (rest_claim, rest_offset)."""
    with pytest.raises(Stop):
        dcli.main([str(rec_path), "--out", str(tmp_path / "o"), *flag])
    assert reached[0][2].rest_at_limp_home is value


def test_out_is_checked_before_work(tmp_path, rec_path, reached, capsys):
    f = tmp_path / "file.txt"
    f.write_text("keep me")
    assert dcli.main([str(rec_path), "--out", str(f)]) == 2
    assert "is an existing file" in capsys.readouterr().err and f.read_text() == "keep me"
    assert dcli.main([str(rec_path), "--out", str(f / "sub")]) == 2
    assert "is a file" in capsys.readouterr().err
    old = tmp_path / "old"
    old.mkdir()
    for n in REPORT_FILES[:3]:
        (old / n).write_text("previous result")
    before = _snapshot(old)
    assert dcli.main([str(rec_path), "--out", str(old)]) == 2
    err = capsys.readouterr().err
    assert "already holds a report" in err and "--force" in err
    assert _snapshot(old) == before and not reached
    with pytest.raises(Stop):                                   # --force: accepted, goes on to the work
        dcli.main([str(rec_path), "--out", str(old), "--force"])
    assert reached


def test_plant_input_inside_out_is_never_overwritten(tmp_path, rec_path, reached, capsys):
    out = tmp_path / "d"
    save_plant(make_plant("3B"), out / "calibrated_plant.toml")
    before = _snapshot(out)
    assert dcli.main([str(rec_path), "--out", str(out), "--force", "--plant", str(out / "calibrated_plant.toml")]) == 2
    assert "would be overwritten" in capsys.readouterr().err and _snapshot(out) == before


@pytest.mark.parametrize("content, words", [
    (None, ["--plant", "does not exist"]),
    ("schema = 'etb-gym/plant/1'\nmodel = '3B'\n[rotor]\ninertia_kg_m2 = true\n", ["inertia_kg_m2", "number"]),
    ("model = '3B'\n[rotor\n", ["cannot parse"]),
])
def test_plant_missing_or_malformed_is_a_sentence(tmp_path, rec_path, reached, capsys, content, words):
    p = tmp_path / "plant.toml"
    if content is not None:
        p.write_text(content)
    assert dcli.main([str(rec_path), "--out", str(tmp_path / "o"), "--plant", str(p)]) == 2
    err = capsys.readouterr().err
    assert str(p) in err and "Traceback" not in err and err.count("\n") == 1
    for w in words:
        assert w in err, (w, err)
    assert not (tmp_path / "o").exists()


def test_shared_basenames_get_distinct_names_and_rates_must_match(tmp_path, reached, capsys):
    rng = np.random.default_rng(1)
    a = save_recording(make_recording(make_plant("3B"), rng, duration_s=0.6), tmp_path / "a" / "run.csv")
    b = save_recording(make_recording(make_plant("3B"), rng, duration_s=0.6), tmp_path / "b" / "run.csv")
    with pytest.raises(Stop):
        dcli.main([str(a), str(b), "--out", str(tmp_path / "o")])
    assert [r.name for r in reached[0][0]] == ["a/run.csv", "b/run.csv"]
    assert dcli.main([str(a), str(a), "--out", str(tmp_path / "o2")]) == 2
    assert "given twice" in capsys.readouterr().err
    slow = make_plant("3B", control_period_s=2e-3)
    c = save_recording(make_recording(slow, rng, duration_s=0.6), tmp_path / "c.csv")
    assert dcli.main([str(a), str(c), "--out", str(tmp_path / "o3")]) == 2
    err = capsys.readouterr().err
    assert "different sample periods" in err and "c.csv 2 ms" in err and "Traceback" not in err


def test_failure_after_inputs_writes_failed_report(tmp_path, rec_path, monkeypatch, capsys):
    def boom(recs, out, opts):
        np.full(None, 1.0)          # the kind of deep error a broken candidate used to raise
    monkeypatch.setattr(dcli, "_diagnose", boom)
    out = tmp_path / "o"
    old = os.umask(0o022)
    try:
        rc = top_main(["diagnose", str(rec_path), "--out", str(out), "--quiet"])
    finally:
        os.umask(old)
    assert rc == 3
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "could not proceed" in err and "report.json" in err and "Traceback" not in err
    rep = json.loads((out / "report.json").read_text())
    assert rep["verdict"] == "failed" and rep["recordings"] == ["r.csv"] and rep["reason"]
    assert rep["error_type"] == "TypeError" and "Traceback" in rep["traceback"]
    assert "Verdict: failed" in (out / "report.md").read_text()
    assert stat.S_IMODE((out / "report.json").stat().st_mode) == 0o644
    # a failed report is a report too: not replaced silently
    assert dcli.main([str(rec_path), "--out", str(out)]) == 2


def test_value_error_reason_is_the_message(tmp_path, rec_path, monkeypatch, capsys):
    def bad(recs, out, opts):
        raise ValueError("the calibrated model left the end stops in every segment")
    monkeypatch.setattr(dcli, "_diagnose", bad)
    assert dcli.main([str(rec_path), "--out", str(tmp_path / "o")]) == 3
    rep = json.loads((tmp_path / "o" / "report.json").read_text())
    assert rep["reason"] == "the calibrated model left the end stops in every segment"


def test_help_exits_zero(capsys):
    assert dcli.main(["--help"]) == 0
    assert "Exit codes" in capsys.readouterr().out


def test_markdown_lists_skipped_candidates():
    from types import SimpleNamespace

    from etb_gym.diagnose.report import markdown
    r = {"recordings": ["r.csv"], "model": "3B", "verdict": "match", "rms_before_deg": 0.01, "rms_after_deg": 0.01,
         "noise_floor_deg": 0.01, "elapsed_s": 1.0, "calibrated_parameters": {}, "mismatch_windows_s": {"r.csv": []},
         "regimes_before": [], "regimes_after": [], "effects": [], "unexplained": [], "tests": [],
         "calibrated_plant": "calibrated_plant.toml",
         "skipped_candidates": [{"id": "coil_heating", "reason": "its first simulation failed (non-finite state)"}]}
    md = markdown(SimpleNamespace(report=r), [])
    assert "## Candidates skipped" in md and "`coil_heating`: its first simulation failed" in md


def test_library_checks_out_before_work(tmp_path, rec_path, monkeypatch):
    from etb_gym.diagnose import diagnose
    from etb_gym.diagnose import run as R
    f = tmp_path / "f"
    f.write_text("x")
    monkeypatch.setattr(R, "prepare", lambda *a, **k: (_ for _ in ()).throw(AssertionError("work started")))
    with pytest.raises(ValueError, match="is an existing file"):
        diagnose([rec_path], out=f)
    assert f.read_text() == "x"
