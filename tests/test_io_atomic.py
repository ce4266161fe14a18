"""The one atomic-write helper: umask mode, no temporary left behind, all result writers go through it."""
import os
import stat

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.io import is_temporary, write_atomic


@pytest.fixture
def umask022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def _mode(p):
    return stat.S_IMODE(os.stat(p).st_mode)


def test_write_atomic_kinds_and_mode(tmp_path, umask022):
    a = write_atomic(tmp_path / "a.txt", "héllo\n")
    b = write_atomic(tmp_path / "sub" / "b.bin", b"\x00\x01")
    c = write_atomic(tmp_path / "c.npz", lambda fh: np.savez(fh, x=np.arange(3)))
    assert a.read_text(encoding="utf-8") == "héllo\n" and b.read_bytes() == b"\x00\x01"
    assert np.load(c)["x"].tolist() == [0, 1, 2]
    for p in (a, b, c):
        assert _mode(p) == 0o644, (p, oct(_mode(p)))
    assert not [p for p in tmp_path.rglob("*") if is_temporary(p)]


def test_write_atomic_other_umask(tmp_path):
    old = os.umask(0o077)
    try:
        p = write_atomic(tmp_path / "x", "x")
    finally:
        os.umask(old)
    assert _mode(p) == 0o600


def test_failed_write_keeps_old_file_and_leaves_no_temporary(tmp_path):
    p = tmp_path / "r.txt"
    p.write_text("old")

    def boom(fh):
        fh.write(b"half")
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError):
        write_atomic(p, boom)
    assert p.read_text() == "old"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["r.txt"]
    with pytest.raises(TypeError, match="content must be"):
        write_atomic(p, 3.5)


def test_result_writers_keep_umask_mode(tmp_path, umask022):
    from etb_gym.bench_report import write_text
    from etb_gym.benchmark import Job, save_trace, write_results
    from etb_gym.diagnose.synthetic import make_recording
    from etb_gym.plantfile import save_plant
    from etb_gym.recordings import load_recording, save_recording

    files = [save_plant(make_plant("3B"), tmp_path / "p.toml"), save_plant(make_plant("1A"), tmp_path / "p.json")]
    rec = make_recording(make_plant("3B"), np.random.default_rng(0), duration_s=0.6)
    for ext in (".csv", ".npz", ".mat"):
        files.append(save_recording(rec, tmp_path / f"r{ext}"))
        back = load_recording(files[-1])
        np.testing.assert_array_equal(back.t_s, rec.t_s)
        np.testing.assert_array_equal(back.angle_deg, rec.angle_deg)
    write_text(tmp_path / "t.md", "# x\n")
    files.append(tmp_path / "t.md")
    job = Job("ETB-3B-v0", "pid", "step_10_80", "nominal", 0)
    save_trace(tmp_path / "traces", job, {"t_s": np.zeros(3)})
    files += list((tmp_path / "traces").iterdir())
    row = {"env": "ETB-3B-v0", "controller": "pid", "scenario": "step_10_80", "variant": "nominal", "seed": 0}
    from etb_gym.benchmark import CSV_COLUMNS
    row.update({c: 1.0 for c in CSV_COLUMNS[5:]})
    row["stable"] = True
    write_results(tmp_path / "results.csv", [row])
    files.append(tmp_path / "results.csv")
    for p in files:
        assert _mode(p) == 0o644, (p.name, oct(_mode(p)))
    assert not [p for p in tmp_path.rglob("*") if is_temporary(p)]
