"""The proof's rows file survives SIGKILL: a run's row is written whole or not at all, --resume redoes a torn run."""
import json
import os
import signal
import subprocess
import sys
import textwrap

from etb_gym.diagnose import proof


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
