"""Test-rig recordings: read, validate and write CSV, ``.npz`` and MATLAB ``.mat`` files.

A recording is a regularly sampled log of one run (format: docs/recordings.md):

    time_s      [s]    strictly increasing, regular sample period (tolerance ``SAMPLING_TOLERANCE``)
    voltage_V   [V]    bridge voltage commanded at t[k] and held until t[k+1]   -- or --
    duty + supply_V    H-bridge duty in [-1, 1] and the supply voltage [V] (voltage = duty * supply_V)
    angle_deg   [deg]  measured plate angle (0 = closed, opening positive)
    current_A   [A]    optional measured coil current

Column names are matched case-insensitively; a few common aliases are accepted (``ALIASES``). Files are
only ever read: validation errors name the file, the column and the row (0-based data row) and say
what was expected.
"""
from __future__ import annotations

import csv
import dataclasses
import io
import math
from pathlib import Path

import numpy as np

from .io import write_atomic

FORMATS = (".csv", ".npz", ".mat")
SAMPLING_TOLERANCE = 0.01      # relative deviation of a sample period from the median period
MIN_DURATION_S = 0.5
MIN_SAMPLES = 200

ALIASES = {
    "time_s": ("time_s", "time", "t", "t_s", "time [s]"),
    "voltage_V": ("voltage_v", "voltage", "u", "u_v", "voltage [v]"),
    "duty": ("duty", "duty_cycle", "d"),
    "supply_V": ("supply_v", "supply", "v_supply", "battery_v", "supply [v]"),
    "angle_deg": ("angle_deg", "angle", "phi_deg", "angle [deg]", "position_deg"),
    "current_A": ("current_a", "current", "i", "i_a", "current [a]"),
}


class RecordingError(ValueError):
    """A recording file that cannot be used, with the file, column and row named."""


@dataclasses.dataclass
class Recording:
    """One validated recording (SI units; the angle stays in degrees, the documented file edge)."""

    name: str
    t_s: np.ndarray
    voltage_V: np.ndarray
    angle_deg: np.ndarray
    current_A: np.ndarray | None = None
    supply_V: np.ndarray | None = None
    path: str | None = None

    @property
    def n(self) -> int:
        return self.t_s.size

    @property
    def dt_s(self) -> float:
        return float(np.median(np.diff(self.t_s)))

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    def columns(self) -> dict:
        cols = {"time_s": self.t_s, "voltage_V": self.voltage_V, "angle_deg": self.angle_deg}
        if self.current_A is not None:
            cols["current_A"] = self.current_A
        if self.supply_V is not None:
            cols["supply_V"] = self.supply_V
        return cols


# ------------------------------------------------------------------------------------------ reading
def _find(cols: dict, key: str):
    lower = {k.strip().lower(): k for k in cols}
    for alias in ALIASES[key]:
        if alias in lower:
            return lower[alias]
    return None


def _read_csv(path: Path) -> dict:
    text = path.read_text(encoding="utf-8-sig")
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise RecordingError(f"{path}: the file holds no data")
    dialect = csv.Sniffer().sniff(lines[0], delimiters=",;\t") if any(c in lines[0] for c in ",;\t") else csv.excel
    rows = list(csv.reader(io.StringIO("\n".join(lines)), dialect))
    header = [h.strip() for h in rows[0]]
    if all(_is_number(h) for h in header):
        raise RecordingError(f"{path}: the first line must be a header naming the columns "
                             f"(time_s, voltage_V or duty + supply_V, angle_deg, optional current_A)")
    data = {h: np.empty(len(rows) - 1) for h in header}
    for r, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise RecordingError(f"{path}: data row {r} has {len(row)} fields: expected {len(header)} ({', '.join(header)})")
        for h, v in zip(header, row):
            try:
                data[h][r] = float(v) if v.strip() else math.nan
            except ValueError:
                raise RecordingError(f"{path}: column {h!r}, row {r}: {v!r} is not a number") from None
    return data


def _is_number(s: str) -> bool:
    try:
        float(s)
        return True
    except ValueError:
        return False


def _read_npz(path: Path) -> dict:
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: np.asarray(z[k]) for k in z.files}
    except (ValueError, OSError) as e:
        raise RecordingError(f"{path}: cannot read as .npz: {e}") from e


def _read_mat(path: Path) -> dict:
    from scipy.io import loadmat

    try:
        m = loadmat(str(path), squeeze_me=True)
    except (ValueError, OSError, NotImplementedError) as e:
        raise RecordingError(f"{path}: cannot read as MATLAB .mat (v4-v7.2 supported): {e}") from e
    return {k: np.asarray(v) for k, v in m.items() if not k.startswith("__")}


def load_recording(path, *, name: str | None = None) -> Recording:
    """Read and validate one recording file (.csv, .npz or .mat). Never modifies the file."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such file")
    ext = path.suffix.lower()
    if ext not in FORMATS:
        raise RecordingError(f"{path}: unsupported file type {ext!r}: expected one of {', '.join(FORMATS)}")
    raw = {".csv": _read_csv, ".npz": _read_npz, ".mat": _read_mat}[ext](path)
    return validate(raw, source=str(path), name=name or path.name)


def validate(columns: dict, *, source: str = "<memory>", name: str | None = None) -> Recording:
    """Turn raw columns into a :class:`Recording`, or raise :class:`RecordingError` naming the problem."""
    def col(key, required=True):
        k = _find(columns, key)
        if k is None:
            if required:
                raise RecordingError(f"{source}: missing column {key!r} (aliases {', '.join(ALIASES[key])}); "
                                     f"found {sorted(columns)}")
            return None, None
        a = np.asarray(columns[k])
        if a.dtype.kind not in "fiu":
            raise RecordingError(f"{source}: column {k!r} is not numeric (dtype {a.dtype})")
        a = a.astype(float).reshape(-1) if a.ndim <= 1 or min(a.shape) == 1 else None
        if a is None:
            raise RecordingError(f"{source}: column {k!r} must be one-dimensional, got shape {np.shape(columns[k])}")
        return k, a

    kt, t = col("time_s")
    ka, ang = col("angle_deg")
    kv, volt = col("voltage_V", required=False)
    kd, duty = col("duty", required=False)
    ks, sup = col("supply_V", required=False)
    ki, cur = col("current_A", required=False)
    if volt is None and (duty is None or sup is None):
        missing = "voltage_V" if duty is None else "supply_V (needed with duty)"
        raise RecordingError(f"{source}: missing column {missing}: give voltage_V, or duty together with supply_V; "
                             f"found {sorted(columns)}")
    named = [(kt, t), (ka, ang), (kv, volt), (kd, duty), (ks, sup), (ki, cur)]
    n = t.size
    for k, a in named:
        if a is None:
            continue
        if a.size != n:
            raise RecordingError(f"{source}: column {k!r} has {a.size} rows: expected {n} like {kt!r}")
        bad = ~np.isfinite(a)
        if bad.any():
            r = int(np.argmax(bad))
            raise RecordingError(f"{source}: column {k!r}, row {r}: value {a[r]!r} is not a finite number")
    if n < MIN_SAMPLES:
        raise RecordingError(f"{source}: too short: {n} rows, expected at least {MIN_SAMPLES}")
    dt = np.diff(t)
    if np.any(dt <= 0):
        r = int(np.argmax(dt <= 0)) + 1
        raise RecordingError(f"{source}: column {kt!r}, row {r}: time {t[r]!r} s does not increase "
                             f"(previous row {t[r - 1]!r} s)")
    med = float(np.median(dt))
    dev = np.abs(dt - med) > SAMPLING_TOLERANCE * med
    if dev.any():
        r = int(np.argmax(dev)) + 1
        raise RecordingError(f"{source}: column {kt!r}, row {r}: irregular sampling: step {dt[r - 1]:.6g} s against "
                             f"the median {med:.6g} s (tolerance {SAMPLING_TOLERANCE:.0%}); resample to a fixed rate")
    if t[-1] - t[0] < MIN_DURATION_S:
        raise RecordingError(f"{source}: too short: {t[-1] - t[0]:.3g} s, expected at least {MIN_DURATION_S} s")
    lo, hi = float(ang.min()), float(ang.max())
    if hi - lo < 1.7 and -0.05 <= lo and hi <= 1.7:
        raise RecordingError(f"{source}: column {ka!r}: values span only {lo:.3g}..{hi:.3g}: this looks like a 0..1 "
                             f"fraction or radians, expected the plate angle in degrees")
    if hi - lo < 5.0 and 0.0 <= lo and hi <= 5.5 and not (hi - lo < 2.0 and abs(np.median(ang) - 3.0) < 1.0):
        raise RecordingError(f"{source}: column {ka!r}: values span only {lo:.3g}..{hi:.3g}: this looks like a sensor "
                             f"voltage (0-5 V), expected the plate angle in degrees")
    if lo < -30 or hi > 120:
        r = int(np.argmax((ang < -30) | (ang > 120)))
        raise RecordingError(f"{source}: column {ka!r}, row {r}: angle {ang[r]!r} deg is outside -30..120 deg; "
                             f"expected the plate angle in degrees (0 closed, 90 open)")
    if sup is not None and np.any(sup <= 0):
        r = int(np.argmax(sup <= 0))
        raise RecordingError(f"{source}: column {ks!r}, row {r}: supply {sup[r]!r} V: expected > 0 V")
    if volt is None:
        if np.any(np.abs(duty) > 1 + 1e-9):
            r = int(np.argmax(np.abs(duty) > 1 + 1e-9))
            raise RecordingError(f"{source}: column {kd!r}, row {r}: duty {duty[r]!r}: expected a value in [-1, 1]")
        volt = duty * sup
    elif sup is not None and np.any(np.abs(volt) > sup * (1 + 1e-6)):
        r = int(np.argmax(np.abs(volt) > sup * (1 + 1e-6)))
        raise RecordingError(f"{source}: column {kv!r}, row {r}: voltage {volt[r]!r} V exceeds the supply {sup[r]!r} V")
    return Recording(name=name or Path(source).name, t_s=t.copy(), voltage_V=volt.copy(), angle_deg=ang.copy(),
                     current_A=None if cur is None else cur.copy(), supply_V=None if sup is None else sup.copy(),
                     path=source if source != "<memory>" else None)


# ------------------------------------------------------------------------------------------ writing
def save_recording(rec: Recording, path) -> Path:
    """Write ``rec`` as .csv, .npz or .mat (atomically: a temporary file renamed into place)."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext not in FORMATS:
        raise ValueError(f"recording file {path}: expected one of {', '.join(FORMATS)}")
    cols = rec.columns()
    if ext == ".csv":
        keys = list(cols)
        buf = io.StringIO(newline="")
        w = csv.writer(buf)
        w.writerow(keys)
        for row in zip(*(cols[k] for k in keys)):
            w.writerow([repr(float(v)) for v in row])
        return write_atomic(path, buf.getvalue())
    if ext == ".npz":
        return write_atomic(path, lambda fh: np.savez(fh, **cols))
    from scipy.io import savemat

    return write_atomic(path, lambda fh: savemat(fh, {k: np.asarray(v, float) for k, v in cols.items()}))
