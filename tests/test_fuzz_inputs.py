"""Fuzzing every file and argument boundary with a generated corpus of malformed inputs (seeded, so a failure
reproduces). For each input: either it is accepted (and then read correctly where the truth is known), or it
is refused with a sentence that names the file or option and says what was expected. Never a traceback from
deep inside (any other exception type fails the test), never a modified input, never an overwritten result.

Run with ``-s`` to see the counts per boundary (they are also asserted: >= 500 in all)."""
import io
import json
import random
import re
from pathlib import Path

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.diagnose import cli as dcli
from etb_gym.plantfile import load_plant, save_plant
from etb_gym.recordings import RecordingError, load_recording, save_recording, validate

COUNTS: dict[str, dict[str, int]] = {}
N_CSV, N_BIN, N_PLANT, N_ARGS = 260, 90, 160, 80


def _count(boundary, outcome):
    c = COUNTS.setdefault(boundary, {"inputs": 0, "accepted": 0, "refused": 0})
    c["inputs"] += 1
    c[outcome] += 1


def _base_columns(n=600, dt=1e-3, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    volt = np.repeat(rng.choice([-6.0, 0.0, 3.0, 8.0], n // 20 + 1), 20)[:n]
    ang = 5.0 + 30.0 * (1 + np.sin(2 * np.pi * 3 * t)) + rng.normal(0, 0.01, n)
    cur = volt / 1.5 + rng.normal(0, 0.01, n)
    return {"time_s": t, "voltage_V": volt, "angle_deg": ang, "current_A": cur}


def _csv_text(cols, sep=",", dec=".", header=None, newline="\n", comment=None):
    keys = list(cols)
    lines = [] if comment is None else [f"# {comment}"]
    lines.append(sep.join(header or keys))
    for row in zip(*(cols[k] for k in keys)):
        lines.append(sep.join(repr(float(v)).replace(".", dec) for v in row))
    return newline.join(lines) + newline


def _check_refusal(msg: str, path: Path):
    assert str(path) in msg or path.name in msg, f"message does not name the file: {msg}"
    assert "Traceback" not in msg and "np.float" not in msg and "array(" not in msg, msg
    assert re.search(r"expected|looks like|repair|not supported|is larger|no such|holds no|not a file|appears twice|"
                     r"all name", msg), f"message states no expectation: {msg}"


def _load_and_check(path: Path, boundary: str):
    before = (path.read_bytes(), path.stat().st_mtime_ns)
    try:
        rec = load_recording(path)
        outcome = "accepted"
    except RecordingError as e:
        _check_refusal(str(e), path)
        rec, outcome = None, "refused"
    assert (path.read_bytes(), path.stat().st_mtime_ns) == before, f"{path} was modified"
    _count(boundary, outcome)
    return rec


# --------------------------------------------------------------------------------- known encodings: accepted
@pytest.mark.parametrize("variant", ["utf-8-sig", "utf-16", "utf-16-le", "utf-16-be", "cp1252-comment", "crlf",
                                     "semicolon-comma-decimal", "tab", "quoted-header", "blank-lines"])
def test_csv_encodings_and_dialects_are_read_correctly(tmp_path, variant):
    cols = _base_columns()
    p = tmp_path / "r.csv"
    if variant in ("utf-8-sig", "utf-16", "utf-16-le", "utf-16-be"):
        p.write_bytes(_csv_text(cols, comment="Prüfstand 3 – 25 °C").encode(variant))
    elif variant == "cp1252-comment":
        p.write_bytes(_csv_text(cols, comment="Prüfstand, Messung über 25 °C").encode("cp1252"))
    elif variant == "crlf":
        p.write_bytes(_csv_text(cols, newline="\r\n").encode())
    elif variant == "semicolon-comma-decimal":
        p.write_text(_csv_text(cols, sep=";", dec=","))
    elif variant == "tab":
        p.write_text(_csv_text(cols, sep="\t"))
    elif variant == "quoted-header":
        p.write_text(_csv_text(cols, header=[f'"{k}"' for k in cols]))
    else:
        p.write_text(_csv_text(cols).replace("\n", "\n\n", 5))
    rec = _load_and_check(p, "recordings: dialects")
    assert rec is not None, variant
    np.testing.assert_array_equal(rec.angle_deg, cols["angle_deg"])
    np.testing.assert_array_equal(rec.voltage_V, cols["voltage_V"])


@pytest.mark.parametrize("col, factor, words", [
    ("time_s", 1e3, ["'time_s'", "milliseconds", "time_ms"]),
    ("voltage_V", 1e3, ["'voltage_V'", "mV", "divide by 1000"]),
    ("current_A", 1e3, ["'current_A'", "mA", "divide by 1000"]),
])
def test_unit_scales_are_named(tmp_path, col, factor, words):
    cols = _base_columns()
    cols[col] = cols[col] * factor
    p = tmp_path / "r.csv"
    p.write_text(_csv_text(cols))
    with pytest.raises(RecordingError) as e:
        load_recording(p)
    for w in words:
        assert w in str(e.value), str(e.value)
    # declared in the name: converted
    cols2 = dict(cols)
    new = {"time_s": "time_ms", "voltage_V": "voltage_mV", "current_A": "current_mA"}[col]
    cols2[new] = cols2.pop(col)
    p.write_text(_csv_text(cols2))
    rec = load_recording(p)
    ref = _base_columns()
    np.testing.assert_allclose(getattr(rec, {"time_s": "t_s"}.get(col, col)), ref[col], rtol=1e-12)


@pytest.mark.parametrize("col, value, row", [("voltage_V", 1000.0, 77), ("voltage_V", 40.0, 5),
                                             ("current_A", 250.0, 100), ("angle_deg", 95.0, 150)])
def test_single_sample_outliers_are_named(tmp_path, col, value, row):
    cols = _base_columns()
    if col == "angle_deg":
        cols[col][row - 1: row + 2] = 20.0
    cols[col][row] = value
    with pytest.raises(RecordingError) as e:
        validate(cols, source="rig.csv")
    msg = str(e.value)
    assert f"'{col}'" in msg and str(row) in msg and "outlier" in msg, msg


def test_duplicate_and_ambiguous_columns(tmp_path):
    cols = _base_columns()
    p = tmp_path / "d.csv"
    p.write_text(_csv_text(cols, header=["time_s", "voltage_V", "angle_deg", "angle_deg"]))
    with pytest.raises(RecordingError, match=r"'angle_deg' appears twice \(columns 3 and 4\)"):
        load_recording(p)
    p.write_text(_csv_text(cols, header=["time_s", "voltage_V", "angle", "angle_deg"]))
    with pytest.raises(RecordingError, match="all name angle_deg"):
        load_recording(p)


def test_swapped_angle_and_voltage_columns_are_named(tmp_path):
    cols = _base_columns()
    cols["voltage_V"], cols["angle_deg"] = cols["angle_deg"] + 60.0, cols["voltage_V"]
    with pytest.raises(RecordingError) as e:
        validate(cols, source="rig.csv")
    assert "'voltage_V'" in str(e.value)


def test_huge_file_refused_before_reading(tmp_path, monkeypatch):
    import etb_gym.recordings as R
    p = tmp_path / "big.csv"
    p.write_text(_csv_text(_base_columns()))
    monkeypatch.setattr(R, "MAX_FILE_BYTES", 1000)
    with pytest.raises(RecordingError, match="larger than"):
        load_recording(p)


# --------------------------------------------------------------------------------- generated CSV corpus
def _mutate_csv(rng: random.Random, cols) -> bytes:
    text = _csv_text(cols)
    op = rng.randrange(16)
    lines = text.splitlines()
    if op == 0:                                   # truncate anywhere
        return text.encode()[: rng.randrange(len(text))]
    if op == 1:                                   # flip random bytes
        b = bytearray(text.encode())
        for _ in range(rng.randint(1, 20)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b)
    if op == 2:                                   # a bad cell
        r = rng.randrange(1, len(lines))
        cells = lines[r].split(",")
        cells[rng.randrange(len(cells))] = rng.choice(["inf", "-inf", "nan", "", "1e300", "-1e400", "abc", "1,5",
                                                       "0x10", "1e", "--1", "１", "None", "TRUE"])
        lines[r] = ",".join(cells)
    elif op == 3:                                 # swap or rename header names
        h = lines[0].split(",")
        i, j = rng.sample(range(len(h)), 2)
        h[i], h[j] = h[j], h[i]
        if rng.random() < 0.5:
            h[rng.randrange(len(h))] = rng.choice(["", "x", "angle", "Time", "U", "i", "duty", "supply", "angle_deg"])
        lines[0] = ",".join(h)
    elif op == 4:                                 # drop a column
        k = rng.randrange(4)
        lines = [",".join(c for m, c in enumerate(ln.split(",")) if m != k) for ln in lines]
    elif op == 5:                                 # drop / duplicate rows
        r = rng.randrange(1, len(lines))
        lines.insert(r, lines[r]) if rng.random() < 0.5 else lines.pop(r)
    elif op == 6:                                 # scale a column
        k = rng.randrange(4)
        f = rng.choice([1e-3, 1e3, 1e6, -1.0, 100.0, 0.0])
        c = {key: v * (f if m == k else 1.0) for m, (key, v) in enumerate(cols.items())}
        return _csv_text(c).encode()
    elif op == 7:                                 # an outlier of any size
        c = {k: v.copy() for k, v in cols.items()}
        key = rng.choice(list(c))
        c[key][rng.randrange(len(c[key]))] = rng.choice([1e3, -1e3, 40.0, 1e300, 123.4, -31.0, 0.0])
        return _csv_text(c).encode()
    elif op == 8:                                 # encoding chaos
        enc = rng.choice(["utf-16", "utf-16-le", "utf-32", "cp1252", "latin-1", "utf-8-sig", "cp437"])
        return _csv_text(cols, comment=rng.choice(["Prüfstand", "µs résolution", "テスト", "ÄÖÜß°"])).encode(
            enc, errors="replace")
    elif op == 9:                                 # random garbage
        return bytes(rng.randrange(256) for _ in range(rng.randint(0, 3000)))
    elif op == 10:                                # extra separators / ragged rows
        r = rng.randrange(len(lines))
        lines[r] = lines[r] + rng.choice([",", ",,", ";1", ",1.0,2.0"])
    elif op == 11:                                # other separators
        sep = rng.choice([";", "\t", " ", "|"])
        return _csv_text(cols, sep=sep, dec=rng.choice([".", ","])).encode()
    elif op == 12:                                # time irregular / not increasing
        c = {k: v.copy() for k, v in cols.items()}
        r = rng.randrange(1, len(c["time_s"]))
        c["time_s"][r] = c["time_s"][r - 1] * rng.choice([1.0, 0.5, 1.0 + 1e-9])
        return _csv_text(c).encode()
    elif op == 13:                                # header only / comments only / empty
        return rng.choice([lines[0] + "\n", "# only a comment\n", "", "\n\n", "\ufeff"]).encode()
    elif op == 14:                                # very long line
        lines[rng.randrange(len(lines))] += "9" * rng.randint(100, 20000)
    else:                                         # mixed newlines and NULs
        return text.replace("\n", rng.choice(["\r\n", "\r", "\n\x00"]), rng.randint(1, 50)).encode()
    return ("\n".join(lines) + "\n").encode()


def test_generated_csv_corpus(tmp_path):
    rng = random.Random(1234)
    cols = _base_columns()
    for k in range(N_CSV):
        p = tmp_path / f"m{k}.csv"
        p.write_bytes(_mutate_csv(rng, cols))
        _load_and_check(p, "recordings: CSV")
    assert COUNTS["recordings: CSV"]["inputs"] == N_CSV


# --------------------------------------------------------------------------------- generated npz / mat corpus
def _binary_variants(rng: random.Random, tmp_path: Path, k: int) -> Path:
    cols = _base_columns()
    ext = rng.choice([".npz", ".mat"])
    p = tmp_path / f"b{k}{ext}"
    op = rng.randrange(9)
    if op == 0:                                           # text pretending to be binary
        p.write_text(_csv_text(cols))
        return p
    if op == 1:
        p.write_bytes(bytes(rng.randrange(256) for _ in range(rng.randint(0, 4000))))
        return p
    if op == 2:                                           # HDF5 (MATLAB v7.3) or zip magic with garbage
        p.write_bytes(rng.choice([b"\x89HDF\r\n\x1a\n", b"PK\x03\x04", b"MATLAB 5.0 MAT-file"]) + bytes(200))
        return p
    c = {k2: v.copy() for k2, v in cols.items()}
    if op == 3:
        key = rng.choice(list(c))
        c[key] = rng.choice([c[key].astype(str), c[key] > 0, np.stack([c[key], c[key]]), c[key][:10],
                             np.full(len(c[key]), np.inf), c[key].reshape(-1, 1)])
    elif op == 4:
        c.pop(rng.choice(list(c)))
    elif op == 5:
        c[rng.choice(list(c))][rng.randrange(600)] = rng.choice([np.nan, 1e300, -1e3])
    real = io.BytesIO()
    if ext == ".npz":
        np.savez(real, **c)
    else:
        from scipy.io import savemat
        savemat(real, c)
    data = real.getvalue()
    if op == 6:
        data = data[: rng.randrange(len(data))]
    elif op == 7:
        b = bytearray(data)
        for _ in range(rng.randint(1, 30)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        data = bytes(b)
    p.write_bytes(data)
    return p


def test_generated_npz_and_mat_corpus(tmp_path):
    rng = random.Random(99)
    for k in range(N_BIN):
        _load_and_check(_binary_variants(rng, tmp_path, k), "recordings: npz/mat")
    # the one with an object array must not unpickle
    p = tmp_path / "obj.npz"
    np.savez(p, time_s=np.array([object()] * 3, dtype=object))
    _load_and_check(p, "recordings: npz/mat")


# --------------------------------------------------------------------------------- plant files
_VALUES = [True, False, "abc", "", [1, 2], {}, {"a": 1}, -1.0, 0.0, 1e400, -1e400, float("nan"), 1e300, 3, None]


def _plant_variant(rng: random.Random, base: dict):
    d = json.loads(json.dumps(base))
    op = rng.randrange(8)
    sections = [k for k, v in d.items() if isinstance(v, dict)]
    if op == 0:
        d[rng.choice(["schema", "model", "control_period_s", "substeps"])] = rng.choice(
            _VALUES + ["etb-gym/plant/99", "etb-gym/plant/0", "4Z", "3b"])
    elif op == 1:                                     # a wrong type / value for a parameter
        s = rng.choice(sections)
        tab = d[s] if s in ("rotor", "supply") else d[s]["params"]
        tab[rng.choice(list(tab))] = rng.choice(_VALUES)
    elif op == 2:                                     # an unknown key somewhere
        s = rng.choice(sections + [None])
        key = rng.choice(["inertia", "gain", "coulomb", "x", "kind2", "params2"])
        (d if s is None else (d[s] if s in ("rotor", "supply") or rng.random() < 0.5 else d[s]["params"]))[key] = 1.0
    elif op == 3:                                     # a whole section of the wrong shape
        d[rng.choice(sections + ["effects"])] = rng.choice(_VALUES + [[{"kind": "nope"}], [{"name": "x"}]])
    elif op == 4:
        d["effects"] = [{"kind": rng.choice(["effect.coil_heating", "effect.backlash", "friction.lugre", "nope", 3]),
                         "params": rng.choice([{}, {"gap_deg": -1.0}, {"x": 1}, [], {"gap_deg": "1"}]),
                         "name": rng.choice(["e", "", 5, None, "drive"])}]
    elif op == 5:
        s = rng.choice(sections)
        d[s].pop(rng.choice(list(d[s])))
    elif op == 6:
        d[rng.choice(sections)]["kind"] = rng.choice(["drive.nope", "friction.lugre", 1, None])
    else:
        return None                                   # text-level corruption (below)
    return d


def _write_plant_text(rng, p: Path, d, base_text: str):
    if d is not None:
        if p.suffix == ".json":
            try:
                p.write_text(json.dumps(d))
            except ValueError:
                p.write_text(json.dumps(d, allow_nan=True))
        else:
            from etb_gym.plantfile import dumps_toml
            try:
                p.write_text(dumps_toml(d))
            except (TypeError, ValueError):               # a value TOML cannot hold (None, nan): use JSON
                p = p.with_suffix(".json")
                p.write_text(json.dumps(d))
        return p
    op = rng.randrange(4)
    if op == 0:
        p.write_text(base_text[: rng.randrange(len(base_text))])
    elif op == 1:
        b = bytearray(base_text.encode())
        for _ in range(rng.randint(1, 10)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        p.write_bytes(bytes(b))
    elif op == 2:
        p.write_bytes(base_text.encode("utf-16"))
    else:
        p.write_bytes(bytes(rng.randrange(256) for _ in range(rng.randint(0, 500))))
    return p


def test_generated_plant_file_corpus(tmp_path):
    rng = random.Random(7)
    base_plant = make_plant("3B", effects=[__import__("etb_gym.components.effects", fromlist=["x"]).Backlash()])
    base = base_plant.to_dict()
    texts = {".toml": save_plant(base_plant, tmp_path / "base.toml").read_text(),
             ".json": save_plant(base_plant, tmp_path / "base.json").read_text()}
    for k in range(N_PLANT):
        ext = rng.choice([".toml", ".json"])
        p = _write_plant_text(rng, tmp_path / f"p{k}{ext}", _plant_variant(rng, base), texts[ext])
        before = p.read_bytes()
        try:
            load_plant(p)
            outcome = "accepted"
        except (ValueError, FileNotFoundError) as e:
            msg = str(e)
            assert msg.startswith(f"plant file {p}"), msg
            assert "Traceback" not in msg and "np.float" not in msg and "__init__()" not in msg, msg
            assert "expected" in msg or "valid" in msg or "unknown" in msg, msg
            outcome = "refused"
        assert p.read_bytes() == before
        _count("plant files", outcome)


@pytest.mark.parametrize("text, words", [
    ('schema = "etb-gym/plant/99"\nmodel = "3B"\n', ["schema", "etb-gym/plant/99", "etb-gym/plant/1"]),
    ('model = "3B"\n[rotor]\ninertia_kg_m2 = true\n', ["rotor", "inertia_kg_m2", "expected a number", "bool"]),
    ('model = "3B"\n[rotor]\ninertia_kg_m2 = "big"\n', ["inertia_kg_m2", "'big'", "expected a number"]),
    ('model = "3B"\n[supply]\nvoltage = 12.0\n', ["supply", "unknown key", "voltage", "voltage_V"]),
    ('model = "3B"\n[rotor]\nJ = 1e-5\n', ["rotor", "unknown key", "'J'", "inertia_kg_m2"]),
    ('model = "3B"\n[friction]\nkind = "friction.lugre"\n[friction.params]\ncoulomb_Nm = "0.1"\n',
     ["friction.params", "coulomb_Nm", "expected a number"]),
    ('model = "3B"\nsubsteps = true\n', ["substeps", "whole number"]),
    ('model = "3B"\n[supply]\npwm_mode = 5\n', ["pwm_mode", "expected text"]),
])
def test_plant_file_messages_name_the_key(tmp_path, text, words):
    p = tmp_path / "p.toml"
    p.write_text(text)
    with pytest.raises(ValueError) as e:
        load_plant(p)
    for w in words:
        assert w in str(e.value), str(e.value)


def test_override_parser_is_shared_and_names_keys():
    p = make_plant("3B")
    for bad, words in [({"rotor.inertia_kg_m2": True}, ["inertia_kg_m2", "bool"]),
                       ({"friction.coulomb_Nm": "1"}, ["coulomb_Nm", "expected a number"]),
                       ({"friction": 1.0}, ["'component.field'"]),
                       ({"gear.ratio": 2.0}, ["unknown component 'gear'"]),
                       ({"drive.R": 1.0}, ["unknown parameter 'R'", "resistance_ohm"])]:
        for fn in (p.with_params, p.param_vector):
            with pytest.raises(ValueError) as e:
                fn(bad)
            for w in words:
                assert w in str(e.value), (fn.__name__, str(e.value))
    with pytest.raises(ValueError, match="not part of P"):
        p.param_vector({"supply.voltage_V": 13.0})
    with pytest.raises(ValueError) as e:
        p.with_params({"friction.coulomb_Nm": np.float64("nan")})
    assert "np.float64" not in str(e.value) and "nan" in str(e.value)


# --------------------------------------------------------------------------------- CLI arguments
def _rand_arg(rng: random.Random, rec: str, tmp: Path):
    opts = {"--sensor-resolution-deg": ["-1", "nan", "inf", "0", "abc", "1e-3", "0.02", "", "1e400"],
            "--jobs": ["0", "-1", "1", "2", "x", "1.5", "99999999999999999999"],
            "--max-effects": ["-1", "0", "3", "a", "2.0"],
            "--substeps": ["0", "-3", "20", "1e3", "x"],
            "--model": ["3B", "4Z", "", "3b", "1a", "A3"],
            "--candidates": ["coil_heating", "nope", "coil_heating coil_heating"],
            "--plant": [str(tmp / "missing.toml"), str(tmp / "bad.toml"), str(tmp / "good.toml"), str(tmp)],
            "--out": [str(tmp / "o_new"), str(tmp / "file.txt"), str(tmp / "old_report"), str(tmp / "file.txt" / "x")]}
    argv = [rec]
    if rng.random() < 0.2:
        argv.append(rng.choice([str(tmp / "nope.csv"), str(tmp / "file.txt"), rec]))
    for opt in rng.sample(list(opts), rng.randint(1, 4)):
        v = rng.choice(opts[opt])
        argv += [opt, *v.split(" ")] if v else [opt, v]
    if "--out" not in argv:
        argv += ["--out", str(tmp / "o_new")]
    if rng.random() < 0.2:
        argv.append(rng.choice(["--force", "--bogus", "--quiet"]))
    return argv


def test_generated_diagnose_cli_arguments(tmp_path, monkeypatch, capsys):
    rng = random.Random(5)
    rec = save_recording(validate(_base_columns(600)), tmp_path / "r.csv")
    (tmp_path / "file.txt").write_text("not a folder")
    (tmp_path / "bad.toml").write_text("model = '3B'\n[rotor]\ninertia_kg_m2 = true\n")
    save_plant(make_plant("1A"), tmp_path / "good.toml")
    old = tmp_path / "old_report"
    old.mkdir()
    (old / "report.json").write_text('{"verdict": "match"}')

    class Stop(BaseException):
        pass

    def stop(recs, out, opts):
        raise Stop
    monkeypatch.setattr(dcli, "_diagnose", stop)
    protected = [rec, tmp_path / "file.txt", tmp_path / "bad.toml", tmp_path / "good.toml", old / "report.json"]
    snap = {p: p.read_bytes() for p in protected}
    for _ in range(N_ARGS):
        argv = _rand_arg(rng, str(rec), tmp_path)
        try:
            rc = dcli.main(argv)
        except Stop:                                   # every check passed: the work would start here
            _count("diagnose CLI", "accepted")
            assert "--force" in argv or str(old) not in argv, argv
            continue
        err = capsys.readouterr().err
        assert rc == 2, (argv, rc, err)
        assert "Traceback" not in err and err.strip(), (argv, err)
        assert re.search(r"--[a-z-]+|\.csv|\.toml|recording", err), (argv, err)
        _count("diagnose CLI", "refused")
        for p, b in snap.items():
            assert p.read_bytes() == b, (argv, p)
    assert COUNTS["diagnose CLI"]["inputs"] == N_ARGS


def test_generated_benchmark_cli_arguments(tmp_path, monkeypatch, capsys):
    from etb_gym import benchmark_cli as mod      # what `etb-gym benchmark` and scripts/benchmark.py run

    class Stop(BaseException):
        pass
    seen = []

    def stop(jobs, out, **kw):
        seen.append(jobs)
        raise Stop
    monkeypatch.setattr(mod, "run_sweep", stop)
    rng = random.Random(11)
    opts = {"--controller": ["pid", "smc", "nope", "os:system", "rl:", "pid"], "--env": ["ETB-3B-v0", "ETB-9Z-v0", ""],
            "--scenario": ["step_10_80", "nope", ""], "--variant": ["nominal", "friction_+50", "x"],
            "--seeds": ["0", "-1", "2", "x"], "--workers": ["0", "1", "two"], "--out": [str(tmp_path / "b")]}
    for _ in range(N_ARGS // 2):
        argv = []
        for opt in rng.sample(list(opts), rng.randint(1, 4)):
            for _ in range(rng.randint(1, 2)):
                argv += [opt, rng.choice(opts[opt])]
        n_before = len(seen)
        try:
            rc = mod.main(argv)
        except Stop:
            jobs = seen[n_before]
            assert len({j.key for j in jobs}) == len(jobs), f"duplicate jobs for {argv}"
            _count("benchmark CLI", "accepted")
            continue
        except SystemExit as e:
            rc = e.code
        err = capsys.readouterr().err
        assert rc == 2 and "Traceback" not in err and err.strip(), (argv, rc, err)
        _count("benchmark CLI", "refused")
    assert not (tmp_path / "b").exists() or not any((tmp_path / "b").iterdir())


def test_zz_report_counts(capsys):
    """Print the counts per boundary (this runs last in the file) and hold the corpus to its size."""
    with capsys.disabled():
        total = 0
        for b, c in sorted(COUNTS.items()):
            print(f"\n  {b}: {c['inputs']} inputs, {c['accepted']} accepted, {c['refused']} refused with a sentence",
                  end="")
            total += c["inputs"]
        print(f"\n  total: {total} generated inputs, 0 tracebacks, 0 modified inputs")
    if len(COUNTS) >= 5:        # the whole file ran (not a -k selection)
        assert total >= 500
