"""The proof's rows file survives SIGKILL: a run's row is written whole or not at all, --resume redoes a torn run."""
import json
import os
import signal
import subprocess
import sys
import textwrap

from etb_gym.diagnose import proof
from scripts_loader import load_script


def test_torn_last_row_is_dropped_and_cut_from_the_file(tmp_path):
    f = tmp_path / "rows.jsonl"
    good = [{"family": "clean", "seed": 0, "x": 1}, {"family": "clean", "seed": 1, "x": 2}]
    f.write_text("".join(json.dumps(r) + "\n" for r in good) + '{"family": "clean", "se')
    assert proof.read_rows(f) == good
    assert f.read_text() == "".join(json.dumps(r) + "\n" for r in good)      # torn tail cut: appends stay whole
    proof.append_row(f, {"family": "clean", "seed": 2})
    assert [r["seed"] for r in proof.read_rows(f)] == [0, 1, 2]
    f.write_text(json.dumps(good[0]))                                           # last row without its newline
    assert proof.read_rows(f) == [] and f.read_text() == ""


def test_rows_survive_sigkill_during_appends(tmp_path):
    """A writer appending rows is killed with SIGKILL at a random point: every row in the file is whole."""
    f = tmp_path / "rows.jsonl"
    code = textwrap.dedent(f"""
        from etb_gym.diagnose.proof import append_row
        k = 0
        while True:
            append_row(__import__("pathlib").Path({str(f)!r}), {{"family": "clean", "seed": k, "pad": "x" * 5000}})
            k += 1
    """)
    p = subprocess.Popen([sys.executable, "-c", code])
    try:
        for _ in range(1200):           # up to 60 s: the writer's imports alone take > 10 s on a loaded machine
            if f.exists() and f.stat().st_size > 50_000:
                break
            import time
            time.sleep(0.05)
    finally:
        os.kill(p.pid, signal.SIGKILL)
        p.wait()
    rows = proof.read_rows(f)
    assert rows and [r["seed"] for r in rows] == list(range(len(rows)))
    assert all(len(r["pad"]) == 5000 for r in rows)


def test_main_returns_an_exit_code_and_resume_needs_out(capsys):
    assert proof.main(["--resume"]) == 2
    assert "--resume and --summarize need --out DIR" in capsys.readouterr().err


def test_naming_survey_counts_closed_loops_by_the_observer_footprint_and_reports_cpu_per_10_s(tmp_path):
    """scripts/naming_survey.py's tables: detectable by the replay footprint (effect_size) as the proof counts;
    closed loops also by what the observer residual sees (effect_size_observer); clean `match` rates; the
    diagnosis's CPU time scaled to a 10 s recording; below-3x effects outside the catalogue not counted."""
    S = load_script("naming_survey")
    base = dict(nameplate="random", seed=3, loop="closed", verdict="match", effects=[], named=False,
                time_s=5.0, duration_s=6.0)
    rows = [dict(base, family="shaft_flux_loss@1", case="shaft_flux_loss@1", effect_size=19.6,
                 effect_size_observer=1.7, cpu_s=1.2),
            dict(base, family="coil_heating@2", case="coil_heating@2", effect_size=13.2, effect_size_observer=5.5,
                 cpu_s=3.0),
            dict(base, family="airflow_torque@2", case="airflow_torque@2", loop="open", seed=2, effect_size=29.8,
                 effects=["airflow_torque"], named=True, verdict="explained", cpu_s=60.0),
            dict(base, family="current_ripple", case="current_ripple", loop="open", seed=2, effect_size=2.1,
                 cpu_s=1.8),
            dict(base, family="clean", case="clean", verdict="unexplained", cpu_s=2.4)]
    f = tmp_path / "rows.jsonl"
    f.write_text("".join(json.dumps(r) + "\n" for r in rows))
    text = S.summary([str(f)])
    line = {tuple(c.strip() for c in ln.split("|")[1:4]): ln.split("|")[4].strip() for ln in text.splitlines()
            if ln.startswith("| ") and ln.count("|") == 5}
    assert line[("detectable catalogue effects named first (>= 90 %)", "all", "all")] == "1/3"
    seen = next(k for k in line if k[0].startswith("... of them") and k[1:] == ("random", "closed"))
    assert line[seen] == "0/1"                      # only the coil heating is >= 3x through the observer
    assert line[("outside the catalogue (detectable): no catalogue effect, period within 10 % (>= 90 %)",
                 "all", "all")] == "-"             # the 2.1x ripple is not counted
    assert line[("clean: no effect claimed (>= 95 %)", "all", "all")] == "1/1"
    assert line[("clean: verdict match (>= 90 %)", "all", "all")] == "0/1"
    assert S.per_10s(rows[2]) == 100.0 and S.per_10s({"time_s": 1.0}) is None
    assert "median 4.0 s, max 100.0 s" in text     # CPU per 10 s of 2, 5, 100, 3, 4
