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


# columns in a declared non-SI unit, converted on reading (docs/recordings.md)
SCALED_ALIASES = {
    "time_s": {"time_ms": 1e-3, "t_ms": 1e-3, "time [ms]": 1e-3, "time_us": 1e-6, "time [us]": 1e-6},
    "voltage_V": {"voltage_mv": 1e-3, "u_mv": 1e-3, "voltage [mv]": 1e-3},
    "supply_V": {"supply_mv": 1e-3, "supply [mv]": 1e-3},
    "current_A": {"current_ma": 1e-3, "i_ma": 1e-3, "current [ma]": 1e-3},
}
MAX_FILE_BYTES = 1 << 28       # 256 MiB: about 5 million rows of CSV (80 min at 1 kHz)
SAMPLE_PERIOD_RANGE_S = (1e-6, 0.02)   # 1 MHz .. 50 Hz: what a throttle recording can be
VOLTAGE_LIMIT_V = 60.0         # no automotive bridge or battery exceeds this (48 V systems stay below 60 V)
CURRENT_LIMIT_A = 100.0        # a throttle motor draws a few amperes; 100 A is far beyond any
SPIKE_FACTOR = 3.0             # a sample this many times larger than the 4th largest, alone, is an outlier


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
def _find(cols: dict, key: str, source: str = "<memory>"):
    """The column for ``key`` and its scale to SI: (name, scale) or (None, 1). Two columns that both match
    (``angle`` and ``angle_deg``) are an error, not a guess."""
    lower = {}
    for k in cols:
        lower.setdefault(str(k).strip().lower(), k)
    hits = [(lower[a], 1.0) for a in ALIASES[key] if a in lower]
    hits += [(lower[a], f) for a, f in SCALED_ALIASES.get(key, {}).items() if a in lower]
    if len(hits) > 1:
        raise RecordingError(f"{source}: columns {', '.join(repr(h) for h, _ in hits)} all name {key}: expected "
                             f"exactly one of them; rename or drop the others")
    return hits[0] if hits else (None, 1.0)


def _decode(path: Path, raw: bytes) -> str:
    """CSV bytes to text: UTF-8 (with or without BOM), UTF-16/32 with a BOM or recognisable by its zero bytes,
    else Windows-1252 (a German comment written by Excel). Binary content is refused."""
    for bom, enc in ((b"\xef\xbb\xbf", "utf-8-sig"), (b"\xff\xfe\x00\x00", "utf-32"), (b"\x00\x00\xfe\xff", "utf-32"),
                     (b"\xff\xfe", "utf-16"), (b"\xfe\xff", "utf-16")):
        if raw.startswith(bom):
            try:
                return raw.decode(enc)
            except UnicodeDecodeError as e:
                raise RecordingError(f"{path}: byte {e.start}: not valid {enc.upper()} text although the file starts "
                                     f"with its byte-order mark; expected a text CSV file") from None
    head = raw[:4096]
    if len(head) >= 4 and head.count(0) >= len(head) // 3:
        enc = "utf-16-le" if head[1::2].count(0) > head[0::2].count(0) else "utf-16-be"
        try:
            return raw[: len(raw) - len(raw) % 2].decode(enc)
        except UnicodeDecodeError:
            pass
    nul = raw.find(b"\x00")
    if nul >= 0:
        raise RecordingError(f"{path}: byte {nul} is binary (a zero byte): expected a text CSV file "
                             f"(UTF-8, UTF-16 or Windows-1252)")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("cp1252", errors="replace")


def _delimiter(header: str) -> str:
    for d in (";", "\t", ","):
        if d in header:
            return d
    return ","


def _data_lines(text: str, where: list):
    """Non-empty, non-comment lines, lazily (a large file is never held twice as a list of lines); the
    current 1-based line number is kept in ``where[0]`` for messages."""
    for k, ln in enumerate(io.StringIO(text, newline=None)):
        if ln.strip() and not ln.lstrip().startswith("#"):
            where[0] = k + 1
            yield ln.rstrip("\n")


def _read_csv(path: Path) -> dict:
    text = _decode(path, path.read_bytes())
    where = [0]
    n_lines = sum(1 for _ in _data_lines(text, where))
    if not n_lines:
        raise RecordingError(f"{path}: the file holds no data (only empty or # comment lines): expected a header "
                             f"line and one row per sample")
    lines = _data_lines(text, where)
    first = next(lines)
    header_line = where[0]
    delim = _delimiter(first)
    header = [h.strip().strip('"').strip() for h in next(csv.reader([first], delimiter=delim))]
    if all(_is_number(h) for h in header):
        raise RecordingError(f"{path}: line {header_line}: the first line must be a header naming the columns "
                             f"(time_s, voltage_V or duty + supply_V, angle_deg, optional current_A)")
    for k, h in enumerate(header):
        if not h:
            raise RecordingError(f"{path}: line {header_line}: column {k + 1} of the header has no name: "
                                 f"expected a name for every column")
        if header.index(h) != k:
            raise RecordingError(f"{path}: column {h!r} appears twice (columns {header.index(h) + 1} and {k + 1}): "
                                 f"expected each column once")
    comma_decimal = delim != ","
    n = n_lines - 1
    data = {h: np.empty(n) for h in header}
    cols = [data[h] for h in header]
    for r, row in enumerate(csv.reader(lines, delimiter=delim)):
        if len(row) != len(header):
            hint = ""
            if r == n - 1 and len(row) < len(header):
                hint = " (the last line is incomplete: the file looks truncated)"
            elif delim == "," and len(row) > len(header):
                hint = " (decimal commas need ';' or tab as the separator)"
            raise RecordingError(f"{path}: data row {r} (line {where[0]}) has {len(row)} fields: expected "
                                 f"{len(header)} ({', '.join(header)}){hint}")
        for c, (h, v) in enumerate(zip(header, row)):
            v = v.strip()
            try:
                if "_" in v:            # Python's float() reads "6_0" as 60: not a decimal number in a CSV
                    raise ValueError(v)
                cols[c][r] = float(v) if v else math.nan
            except ValueError:
                if comma_decimal and v.count(",") == 1 and _is_number(v.replace(",", ".")):
                    cols[c][r] = float(v.replace(",", "."))
                else:
                    raise RecordingError(f"{path}: column {h!r}, row {r}: {v[:40]!r} is not a number "
                                         f"(line {where[0]}): expected a decimal number") from None
    return data


def _is_number(s: str) -> bool:
    if "_" in s:
        return False
    try:
        float(s)
        return True
    except ValueError:
        return False


def _read_npz(path: Path) -> dict:
    try:
        with np.load(path, allow_pickle=False) as z:
            if not hasattr(z, "files"):
                raise ValueError("it holds a single array, not named columns")
            return {k: np.asarray(z[k]) for k in z.files}
    except Exception as e:      # noqa: BLE001 -- a corrupt zip raises anything from BadZipFile to EOFError
        raise RecordingError(f"{path}: cannot read as .npz ({_short(e)}): expected a NumPy .npz archive with one "
                             f"array per column (np.savez)") from None


def _read_mat(path: Path) -> dict:
    from scipy.io import loadmat

    try:
        m = loadmat(str(path), squeeze_me=True)
    except NotImplementedError:
        raise RecordingError(f"{path}: MATLAB v7.3 (HDF5) files are not supported: save with -v7 "
                             f"(save('rec.mat', ..., '-v7')) or export CSV") from None
    except Exception as e:      # noqa: BLE001 -- a fake or truncated .mat raises IndexError, struct errors, ...
        raise RecordingError(f"{path}: cannot read as MATLAB .mat ({_short(e)}): expected a v4-v7.2 .mat file "
                             f"with one vector per column") from None
    return {k: np.asarray(v) for k, v in m.items() if not k.startswith("__")}


def _short(e: BaseException) -> str:
    msg = " ".join(str(e).split())[:120]
    return f"{type(e).__name__}: {msg}" if msg else type(e).__name__


def load_recording(path, *, name: str | None = None) -> Recording:
    """Read and validate one recording file (.csv, .npz or .mat). Never modifies the file."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such file")
    if not path.is_file():
        raise RecordingError(f"{path}: is not a file: expected a recording (.csv, .npz or .mat)")
    ext = path.suffix.lower()
    if ext not in FORMATS:
        raise RecordingError(f"{path}: unsupported file type {ext!r}: expected one of {', '.join(FORMATS)}")
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise RecordingError(f"{path}: {size / 2**20:.0f} MiB is larger than the {MAX_FILE_BYTES / 2**20:.0f} MiB "
                             f"a recording may be: split it into runs or decimate it")
    try:
        raw = {".csv": _read_csv, ".npz": _read_npz, ".mat": _read_mat}[ext](path)
    except OSError as e:
        raise RecordingError(f"{path}: cannot read the file ({e.strerror or e})") from None
    return validate(raw, source=str(path), name=name or path.name)


def _v(x) -> str:
    """A number for a message: plain, short, no numpy repr."""
    return f"{float(x):.6g}"


def _rows(idx) -> str:
    return ", ".join(str(int(i)) for i in idx)


def _spikes(a: np.ndarray, floor: float) -> np.ndarray:
    """Indices of at most three isolated samples far above all others (|a| > SPIKE_FACTOR x the 4th largest
    and > ``floor``, both neighbours small): sensor or logger glitches, not signal."""
    if a.size < 10:
        return np.empty(0, int)
    mag = np.abs(a)
    ref = float(np.partition(mag, -4)[-4])
    cand = np.flatnonzero((mag > SPIKE_FACTOR * ref) & (mag > floor))
    if not 1 <= cand.size <= 3:
        return np.empty(0, int)
    for k in cand:
        nb = [mag[j] for j in (k - 1, k + 1) if 0 <= j < a.size and j not in cand]
        if any(x * SPIKE_FACTOR > mag[k] for x in nb):
            return np.empty(0, int)
    return cand


def _check_magnitude(source, k, a, limit, unit, milli, floor):
    """Outliers named by row; a whole column beyond ``limit`` named as a unit mistake (milli-units)."""
    spikes = _spikes(a, floor)
    if spikes.size:
        rest = np.delete(np.abs(a), spikes)
        raise RecordingError(f"{source}: column {k!r}, row(s) {_rows(spikes)}: single-sample outlier(s) "
                             f"{', '.join(_v(a[i]) for i in spikes)} {unit} while every other sample stays within "
                             f"+-{_v(rest.max())} {unit}: expected a glitch-free recording; repair or remove "
                             f"these rows")
    over = np.abs(a) > limit
    if over.any():
        r = int(np.argmax(over))
        scaled = np.abs(a).max() / 1000.0
        hint = (f"this looks like {milli} (the largest value would be {_v(scaled)} {unit}): divide by 1000 or name "
                f"the column {k.split('_')[0].split(' ')[0]}_{milli}" if scaled <= limit else
                "expected physical values")
        raise RecordingError(f"{source}: column {k!r}, row {r}: {_v(a[r])} {unit} is beyond the +-{_v(limit)} {unit} "
                             f"of any automotive throttle; {hint}")


def _column(columns, key, source, required=True):
    """Column ``key`` (or an alias) as a float vector in SI units: ``(name found, values)``, or (None, None)."""
    k, scale = _find(columns, key, source)
    if k is None:
        if required:
            raise RecordingError(f"{source}: missing column {key!r}: expected it or one of its aliases "
                                 f"({', '.join(ALIASES[key])}); found {sorted(map(str, columns))}")
        return None, None
    a = np.asarray(columns[k])
    if a.dtype.kind not in "fiub":
        raise RecordingError(f"{source}: column {k!r} is not numeric (it holds {a.dtype.name} values): expected "
                             f"numbers")
    if a.dtype.kind == "b":
        raise RecordingError(f"{source}: column {k!r} holds true/false values: expected numbers")
    if not (a.ndim <= 1 or min(a.shape) == 1) or a.ndim > 2:
        raise RecordingError(f"{source}: column {k!r} has shape {' x '.join(map(str, np.shape(a)))}: expected "
                             f"one value per sample (a vector)")
    with np.errstate(over="ignore", invalid="ignore"):
        a = a.astype(float).reshape(-1) * scale
    return str(k), a


def _check_rows(source, named, kt, n):
    """Every column has ``n`` rows of finite numbers."""
    for k, a in named:
        if a is None:
            continue
        if a.size != n:
            raise RecordingError(f"{source}: column {k!r} has {a.size} rows but {kt!r} has {n}: expected the same "
                                 f"number of rows in every column")
        bad = ~np.isfinite(a)
        if bad.any():
            r = int(np.argmax(bad))
            raise RecordingError(f"{source}: column {k!r}, row {r}: value {_v(a[r])} is not a finite number: expected a finite number "
                                 f"in every row")
    if n < MIN_SAMPLES:
        raise RecordingError(f"{source}: too short: {n} rows, expected at least {MIN_SAMPLES}")


def _check_time(source, kt, t):
    """Strictly increasing, regularly sampled, at a throttle rig's rate, long enough."""
    dt = np.diff(t)
    if np.any(dt <= 0):
        r = int(np.argmax(dt <= 0)) + 1
        raise RecordingError(f"{source}: column {kt!r}, row {r}: time {_v(t[r])} s does not increase "
                             f"(previous row {_v(t[r - 1])} s): expected strictly increasing times")
    med = float(np.median(dt))
    dev = np.abs(dt - med) > SAMPLING_TOLERANCE * med
    if dev.any():
        r = int(np.argmax(dev)) + 1
        raise RecordingError(f"{source}: column {kt!r}, row {r}: irregular sampling: step {dt[r - 1]:.6g} s against "
                             f"the median {med:.6g} s: expected a regular sample period (tolerance {SAMPLING_TOLERANCE:.0%}); "
                             f"resample to a fixed rate")
    lo_dt, hi_dt = SAMPLE_PERIOD_RANGE_S
    if not lo_dt <= med <= hi_dt:
        hint = ("; if the time column is in milliseconds, name it time_ms (or divide by 1000)" if med > hi_dt
                else "")
        raise RecordingError(f"{source}: column {kt!r}: sample period {med:.6g} s ({1 / med:.6g} Hz) is outside "
                             f"{lo_dt:g}..{hi_dt:g} s expected of a throttle recording{hint}")
    if t[-1] - t[0] < MIN_DURATION_S:
        raise RecordingError(f"{source}: too short: {t[-1] - t[0]:.3g} s, expected at least {MIN_DURATION_S} s")


def _check_angle(source, ka, ang, kv, volt):
    """Degrees (not a fraction, radians or a sensor voltage), within -30..120 deg, no single-sample glitch."""
    lo, hi = float(ang.min()), float(ang.max())
    if hi - lo < 1.7 and -0.05 <= lo and hi <= 1.7:
        raise RecordingError(f"{source}: column {ka!r}: values span only {lo:.3g}..{hi:.3g}: this looks like a 0..1 "
                             f"fraction or radians, expected the plate angle in degrees")
    # a 0.5-4.5 V sensor track that moved over a good part of the stroke; a plate that barely moved (span under
    # 2 deg: resting at a limp-home of 2-8 deg, held at the closed stop, small steps near it) reads in degrees
    if 2.0 <= hi - lo < 5.0 and 0.0 <= lo and hi <= 5.5:
        raise RecordingError(f"{source}: column {ka!r}: values span only {lo:.3g}..{hi:.3g}: this looks like a sensor "
                             f"voltage (0-5 V), expected the plate angle in degrees")
    if lo < -30 or hi > 120:
        r = int(np.argmax((ang < -30) | (ang > 120)))
        swap = (f"; the columns {ka!r} and {kv!r} look swapped" if volt is not None
                and np.abs(ang).max() <= VOLTAGE_LIMIT_V and 0 <= volt.min() and volt.max() <= 120 else "")
        raise RecordingError(f"{source}: column {ka!r}, row {r}: angle {_v(ang[r])} deg is outside -30..120 deg; "
                             f"expected the plate angle in degrees (0 closed, 90 open){swap}")
    # a plate cannot jump out and back within one sample: an angle glitch
    if ang.size >= 3:
        d1, d2 = ang[1:-1] - ang[:-2], ang[1:-1] - ang[2:]
        glitch = (np.abs(d1) > 15.0) & (np.abs(d2) > 15.0) & (np.sign(d1) == np.sign(d2)) & \
                 (np.abs(ang[2:] - ang[:-2]) < 2.0)
        if glitch.any():
            rows = np.flatnonzero(glitch)[:5] + 1
            raise RecordingError(f"{source}: column {ka!r}, row(s) {_rows(rows)}: single-sample outlier(s) "
                                 f"({', '.join(_v(ang[i]) for i in rows)} deg between neighbours at "
                                 f"{', '.join(_v(ang[i - 1]) for i in rows)} deg): a plate cannot jump there and back "
                                 f"in one sample; repair or remove these rows")


def _check_supply(source, ks, sup):
    """Positive, no single-sample spike, volts (not mV)."""
    if np.any(sup <= 0):
        r = int(np.argmax(sup <= 0))
        raise RecordingError(f"{source}: column {ks!r}, row {r}: supply {_v(sup[r])} V: expected > 0 V")
    spikes = _spikes(sup - np.median(sup), 0.5 * float(np.median(sup)))
    if spikes.size:
        raise RecordingError(f"{source}: column {ks!r}, row(s) {_rows(spikes)}: single-sample outlier(s) "
                             f"{', '.join(_v(sup[i]) for i in spikes)} V against a median supply of "
                             f"{_v(np.median(sup))} V: repair or remove these rows")
    if np.max(sup) > VOLTAGE_LIMIT_V:
        r = int(np.argmax(sup))
        raise RecordingError(f"{source}: column {ks!r}, row {r}: supply {_v(sup[r])} V is beyond the "
                             f"{_v(VOLTAGE_LIMIT_V)} V of any automotive battery; "
                             + ("this looks like mV: divide by 1000 or name the column supply_mV"
                                if np.max(sup) / 1000 <= VOLTAGE_LIMIT_V else "expected volts"))


def _bridge_voltage(source, kv, volt, kd, duty, ks, sup):
    """The bridge voltage: the voltage column (within the supply, when one is recorded) or duty * supply."""
    if volt is None:
        if np.any(np.abs(duty) > 1 + 1e-9):
            r = int(np.argmax(np.abs(duty) > 1 + 1e-9))
            pct = "; this looks like percent: divide by 100" if np.abs(duty).max() <= 100 else ""
            raise RecordingError(f"{source}: column {kd!r}, row {r}: duty {_v(duty[r])}: expected a value in "
                                 f"[-1, 1]{pct}")
        return duty * sup
    if sup is not None and np.any(np.abs(volt) > sup * (1 + 1e-6)):
        r = int(np.argmax(np.abs(volt) > sup * (1 + 1e-6)))
        raise RecordingError(f"{source}: column {kv!r}, row {r}: voltage {_v(volt[r])} V exceeds the supply "
                             f"{_v(sup[r])} V: expected |voltage| <= supply")
    return volt


def validate(columns: dict, *, source: str = "<memory>", name: str | None = None) -> Recording:
    """Turn raw columns into a :class:`Recording`, or raise :class:`RecordingError` naming the problem.

    Besides format checks, the values must be plausible for a throttle rig: sample period within
    SAMPLE_PERIOD_RANGE_S, |voltage| and supply <= VOLTAGE_LIMIT_V, |current| <= CURRENT_LIMIT_A, no isolated
    single-sample outliers, no plate jumps out and back within one sample. Columns named in ms/mV/mA
    (``SCALED_ALIASES``) are converted to s/V/A."""
    if not isinstance(columns, dict) or not columns:
        raise RecordingError(f"{source}: holds no columns: expected time_s, voltage_V (or duty + supply_V), "
                             f"angle_deg, optional current_A")
    kt, t = _column(columns, "time_s", source)
    ka, ang = _column(columns, "angle_deg", source)
    kv, volt = _column(columns, "voltage_V", source, required=False)
    kd, duty = _column(columns, "duty", source, required=False)
    ks, sup = _column(columns, "supply_V", source, required=False)
    ki, cur = _column(columns, "current_A", source, required=False)
    if volt is None and (duty is None or sup is None):
        missing = "voltage_V" if duty is None else "supply_V (needed with duty)"
        raise RecordingError(f"{source}: missing column {missing}: expected voltage_V, or duty together with supply_V; "
                             f"found {sorted(map(str, columns))}")
    _check_rows(source, [(kt, t), (ka, ang), (kv, volt), (kd, duty), (ks, sup), (ki, cur)], kt, t.size)
    _check_time(source, kt, t)
    _check_angle(source, ka, ang, kv, volt)
    if volt is not None:
        _check_magnitude(source, kv, volt, VOLTAGE_LIMIT_V, "V", "mV", 2.0)
    if cur is not None:
        _check_magnitude(source, ki, cur, CURRENT_LIMIT_A, "A", "mA", 1.0)
    if sup is not None:
        _check_supply(source, ks, sup)
    volt = _bridge_voltage(source, kv, volt, kd, duty, ks, sup)
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
