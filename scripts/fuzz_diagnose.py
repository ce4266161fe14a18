#!/usr/bin/env python
"""Fuzz `etb-gym diagnose` end to end (issue 15: "no crash on any input the recording format accepts, with any
valid plant file; every failure is a clear message naming what failed").

Each case draws a truth plant (any base model 1A..3C, a nameplate from wide ranges with the extremes pinned:
L 1 or 30 mH, limp-home 2 or 8 deg, stops near or far), a plant file that describes it with friction and spring
10-20 % off, and a recording of the truth made either by etb_gym's own plant or by a plain ``solve_ivp``
re-implementation of the documented equations (docs/model.md; so the data are not our stepper's): sample rate
0.5-5 kHz, a 12-bit sensor, white or coloured noise, with or without current and supply columns, short (1 s) or
long, open or closed loop, written as CSV (with varying column names), .npz or .mat. Then it runs the command
line in a subprocess (``etb-gym diagnose REC --plant FILE --model M``, small budgets) and classifies the
outcome:

    ok        exit 0, a report with a known verdict and finite RMS figures
    refused   exit 2 (the input was refused): the message must name the file and what is wrong
    failed    exit 3 (the diagnosis could not proceed): report.json verdict "failed", a one-sentence reason
    BUG       anything else: another exit code, "internal error", a traceback, NaN/inf in the report, an
              unknown verdict, a message without the file's name, a timeout

Rows (JSON lines, one per case) go to --out; exit status 1 when a BUG was found.

    nice -n 10 python scripts/fuzz_diagnose.py --cases 24 --seed 0 --out out/fuzz.jsonl
    python scripts/fuzz_diagnose.py --summary out/fuzz.jsonl
    python scripts/fuzz_diagnose.py --rerun out/fuzz.jsonl 5 out/case5     # one case again, with its log
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

VERDICTS = {"match", "explained", "partly_explained", "unexplained", "outside_catalogue"}
MODELS = ("1A", "1B", "1C", "2A", "2B", "2C", "3A", "3B", "3C")
FORMATS = (".csv", ".npz", ".mat")
WALL_PER_CPU = 10.0         # the wall-clock limit per case, in multiples of --timeout (CPU seconds)
CANDIDATE_POOL = ("torque_constant_error", "shaft_flux_loss", "spring_asymmetry", "airflow_torque",
                  "sensor_offset_gain", "stribeck_friction", "backlash", "coil_heating", "supply_drop",
                  "sensor_delay", "angle_dependent_friction", "inductance_saturation", "end_stop_compliance")


# ------------------------------------------------------------------------------------------- the draw
def draw_case(rng: np.random.Generator, k: int, effect_share: float = 0.0) -> dict:
    """One case's settings (plain numbers, JSON-able). Case k cycles the base model and the recording's
    source so that every model meets both sources in 18 cases. ``effect_share``: the share of cases whose truth
    carries a concealed effect (a proof family and truth shape, :func:`draw_effect`), drawn from a generator of
    the case's own seed so that the other settings of a seed stay what they were without effects."""
    pins = {}
    if rng.random() < 0.7:
        pins["drive.inductance_H"] = float(rng.choice([1e-3, 30e-3]))
    if rng.random() < 0.7:
        pins["spring.limp_home_deg"] = float(rng.choice([2.0, 8.0]))
    if rng.random() < 0.7:
        near = rng.random() < 0.5
        pins["stops.closed_deg"] = float(rng.uniform(-1.0, -0.5) if near else rng.uniform(0.5, 1.0))
        pins["stops.open_deg"] = 80.0 if near else 95.0
    fs = float(rng.choice([500.0, 5000.0])) if rng.random() < 0.4 else float(math.exp(rng.uniform(math.log(500),
                                                                                                  math.log(5000))))
    c = {
        "case": k, "model": MODELS[k % len(MODELS)], "source": ("etb", "ivp")[(k // len(MODELS)) % 2],
        "pins": pins, "fs_hz": fs,
        "duration_s": 1.0 if rng.random() < 0.7 else float(rng.choice([3.0, 6.0], p=[0.7, 0.3])),
        "closed": bool(rng.random() < 0.3),
        "noise_deg": float(math.exp(rng.uniform(math.log(0.005), math.log(0.1)))),
        "colour": 0.0 if rng.random() < 0.5 else float(rng.uniform(0.5, 0.95)),
        "bits_span_deg": float(rng.choice([90.0, 100.0, 120.0])),      # 12 bits over this span
        "current": bool(rng.random() < 0.6), "supply": bool(rng.random() < 0.4),
        "format": FORMATS[int(rng.integers(0, len(FORMATS)))],
        "names": int(rng.integers(0, 3)),
        "candidates": [str(c) for c in rng.choice(CANDIDATE_POOL, size=2, replace=False)],
        "seed": int(rng.integers(0, 2 ** 31)),
        "plant_file": bool(rng.random() < 0.8),          # else --model only (the model's default nameplate)
        "file_period": bool(rng.random() < 0.5),         # the file keeps the 1 ms default, not the recording's
    }
    c.update(draw_effect(np.random.default_rng([c["seed"], 15]), effect_share))
    return c


def draw_effect(rng: np.random.Generator, share: float) -> dict:
    """``effect``: None (a clean truth) or a proof family with its truth shape ("backlash@2"; shapes 1-2 are
    not the candidate's formula); ``effect_scale`` in [0, 1] (the proof's: 0 near the detection limit); with an
    effect, its family replaces the first of the two candidates, so the refine/explain/export paths run."""
    from etb_gym.diagnose.proof_truth import FAMILIES, OUTSIDE, SHAPES
    if share <= 0 or rng.random() >= share:
        return {"effect": None, "effect_scale": None}
    fam = str(rng.choice([f for f in FAMILIES if f != "clean"]))
    shape = 0 if fam in OUTSIDE else int(rng.choice(SHAPES))
    return {"effect": fam if shape == 0 else f"{fam}@{shape}", "effect_scale": float(rng.uniform(0.2, 1.0))}


def truth_and_file(c: dict):
    """(truth plant, the user's plant file plant, the truth's sensor kwargs) of a case. With an effect, the truth
    carries it (the proof's truth_for and tie) and the file describes the truth without it."""
    from etb_gym.diagnose.synthetic import nameplate_file_plant, random_nameplate
    rng = np.random.default_rng(c["seed"])
    dt = 1.0 / c["fs_hz"]
    truth = random_nameplate(rng, c["model"], fixed=c["pins"], control_period_s=dt,
                             substeps=max(5, int(math.ceil(dt / 50e-6))))
    file_plant = nameplate_file_plant(truth, rng)
    sensor_kw = {}
    if c.get("effect"):
        from etb_gym.diagnose.proof_truth import family_shape, tie, truth_for
        fam, shape = family_shape(c["effect"])
        effects, sensor_kw, _, _ = truth_for(fam, np.random.default_rng([c["seed"], 16]), c["effect_scale"], shape)
        if effects:
            truth = truth.replace(effects=tie(effects, truth))
    return truth, file_plant, sensor_kw


def candidates(c: dict) -> list:
    """The case's two candidates; with a catalogue effect, its family first."""
    fam = (c.get("effect") or "").partition("@")[0]
    if fam not in CANDIDATE_POOL + ("sensor_quantization",):     # clean, or outside the catalogue
        return list(c["candidates"])
    return [fam] + [x for x in c["candidates"] if x != fam][:1]


# ------------------------------------------------------------------------------ solve_ivp re-implementation
class IvpPlant:
    """The documented equations of docs/model.md (sections 2-7), written out again from the parameter values
    alone (no etb_gym stepper): drive A/B/C, viscous/Dahl/LuGre friction, the limp-home spring and the stops;
    duty held over each sample period (averaged bridge), integrated by scipy's LSODA."""

    def __init__(self, plant):
        p = plant.params_dict()
        self.p = p
        self.kind = {c: plant.to_dict()[c]["kind"] if plant.to_dict().get(c) else None
                     for c in ("drive", "friction")}
        self.V = p["supply.voltage_V"]
        self.dt = plant.control_period_s
        self.lh = p["spring.limp_home_rad"]
        d = self.kind["drive"]
        if d == "drive.C":                       # eq. 13: the flux amplitude, k_C = N psi_hat
            b, r1 = p["drive.yoke_angle_rad"], p["drive.armature_radius_m"]
            psi = (2 * p["drive.remanence_T"] * r1 * p["drive.iron_length_m"] * math.cos(b / 2)
                   / (math.sin(0.5 * (math.pi / 2 + b / 2)) + p["drive.magnet_permeability"] * p["drive.air_gap_m"] / r1))
            self.kc = p["drive.ampere_turns"] * psi
        else:
            self.kc = p["drive.torque_constant_Nm_per_A"]
        if d == "drive.B" and p.get("drive.inductance_table"):
            raise ValueError("an inductance table is not re-implemented here")

    def k(self, phi):
        return self.kc * math.cos(phi) if self.kind["drive"] == "drive.C" else self.kc

    def inductance(self, i, phi):
        p = self.p
        if self.kind["drive"] != "drive.B":
            return p["drive.inductance_H"]
        r = p["drive.saturated_inductance_ratio"]
        return (p["drive.inductance_H"] * (1 - p["drive.angle_coefficient"] * phi / (math.pi / 2))
                * (r + (1 - r) / (1 + (i / p["drive.saturation_current_A"]) ** 2)))

    def rhs(self, t, x, u):
        p = self.p
        phi, w, i = x[0], x[1], x[2]
        d = phi - self.lh
        eps = p["spring.limp_home_compliance_rad"]
        t_sp = (p["spring.rate_Nm_per_rad"] * d + p["spring.preload_Nm"] * max(-1.0, min(1.0, d / eps))
                + (p["spring.limp_home_damping_Nm_s_per_rad"] * w if abs(d) < eps else 0.0))
        ks, cs = p["stops.stiffness_Nm_per_rad"], p["stops.damping_Nm_s_per_rad"]
        lo, hi = p["stops.closed_rad"] - phi, phi - p["stops.open_rad"]
        t_stop = (max(0.0, ks * lo - cs * w) if lo > 0 else 0.0) - (max(0.0, ks * hi + cs * w) if hi > 0 else 0.0)
        f = self.kind["friction"]
        dz = 0.0
        if f == "friction.viscous":
            t_f = p["friction.viscous_Nm_s_per_rad"] * w
        else:
            s0, z = p["friction.bristle_stiffness_Nm_per_rad"], x[3]
            if f == "friction.dahl":
                g = p["friction.coulomb_Nm"]
                dz = w - s0 * abs(w) * z / g
                t_f = s0 * z + p.get("friction.viscous_Nm_s_per_rad", 0.0) * w
            else:
                tc, ts = p["friction.coulomb_Nm"], p["friction.static_Nm"]
                g = tc + (ts - tc) * math.exp(-math.sqrt(abs(w / p["friction.stribeck_velocity_rad_s"])))
                dz = w - s0 * abs(w) * z / g
                t_f = s0 * z + p["friction.bristle_damping_Nm_s_per_rad"] * dz + p["friction.viscous_Nm_s_per_rad"] * w
        k = self.k(phi)
        di = (u - p["drive.resistance_ohm"] * i - k * w) / self.inductance(i, phi)
        dw = (k * i - t_sp - t_f + t_stop) / p["rotor.inertia_kg_m2"]
        out = [w, dw, di]
        if f != "friction.viscous":
            out.append(dz)
        return out

    def simulate(self, duty: np.ndarray) -> np.ndarray:
        """States (angle, speed, current) at the n + 1 sample instants, starting at rest at limp-home."""
        from scipy.integrate import solve_ivp
        x = [self.lh, 0.0, 0.0] + ([] if self.kind["friction"] == "friction.viscous" else [0.0])
        X = [x[:3]]
        for dk in duty:
            s = solve_ivp(self.rhs, (0.0, self.dt), x, args=(float(dk) * self.V,), method="LSODA",
                          rtol=1e-6, atol=[1e-7, 1e-4, 1e-6] + [1e-9] * (len(x) - 3))
            if not s.success:
                raise FloatingPointError(f"solve_ivp: {s.message}")
            x = list(s.y[:, -1])
            X.append(x[:3])
        return np.asarray(X)


def ivp_recording(truth, c: dict, rng: np.random.Generator, name: str, file_plant=None, sensor_kw=None):
    """An open-loop recording of ``truth`` by IvpPlant: the same duty (scaled to ``file_plant``, the plant the
    tool is given, as the proof does), sensor (noise, 12 bits) and current sensor as ``synthetic.make_recording``;
    ``sensor_kw``: a concealed sensor effect (the proof's truth_for sensor kwargs: offset/gain, delay, resolution,
    or a reading shape), read through etb_gym's PositionSensor."""
    from etb_gym.diagnose.synthetic import QUIET_S, open_loop_duty
    from etb_gym.recordings import Recording
    dt = truth.control_period_s
    nq = int(round(QUIET_S / dt))
    n = nq + int(round((c["duration_s"] - QUIET_S) / dt))
    duty = np.concatenate([np.zeros(nq), open_loop_duty(c["duration_s"] - QUIET_S, rng, dt, plant=file_plant)])[:n]
    X = IvpPlant(truth).simulate(duty[:-1])
    e = rng.normal(0.0, 1.0, n)
    if c["colour"] > 0:
        from scipy.signal import lfilter
        e = lfilter([1.0], [1.0, -c["colour"]], e) * math.sqrt(1 - c["colour"] ** 2)
    q = c["bits_span_deg"] / 4096
    if sensor_kw:
        from etb_gym.components.sensor import PositionSensor, PositionSensorParams
        kw = {"resolution_deg": q, **sensor_kw}
        gain = kw.get("gain", 1.0)
        noise = math.radians(c["noise_deg"]) * e / gain
        v = X[:, 0] + noise if kw.get("reading") is None else kw["reading"].apply(X[:, 0], noise)
        sensor = PositionSensor(PositionSensorParams(
            noise_std_rad=0.0, resolution_rad=math.radians(kw["resolution_deg"]),
            offset_rad=math.radians(kw.get("offset_deg", 0.0)), gain=gain, delay_steps=int(kw.get("delay_steps", 0))))
        y = np.degrees(sensor.measure(v, rng))
    else:
        y = q * np.round((np.degrees(X[:, 0]) + c["noise_deg"] * e) / q)
    cur = X[:, 2] + 0.01 * rng.normal(size=n) if c["current"] else None
    return Recording(name=name, t_s=np.arange(n) * dt, voltage_V=duty * truth.supply.voltage_V, angle_deg=y,
                     current_A=cur, supply_V=None)


def recording(truth, file_plant, c: dict, name: str, sensor_kw=None):
    """The case's recording: by IvpPlant (source "ivp", open loop, no torque-side effect: IvpPlant has none)
    or by etb_gym's plant (closed loop: the PID designed on the file)."""
    from etb_gym.diagnose.synthetic import make_recording
    rng = np.random.default_rng(c["seed"] + 1)
    sensor_kw = dict(sensor_kw or {})
    if ivp_source(c, truth):
        return ivp_recording(truth, c, rng, name, file_plant, sensor_kw)
    ctrl = None
    if c["closed"]:
        from etb_gym.diagnose.proof import _controller
        try:
            ctrl = _controller(file_plant)
        except ValueError:              # no PID design for this file: the package's default PID drives it
            ctrl = None
    return make_recording(truth, rng, duration_s=c["duration_s"], closed=c["closed"], noise_deg=c["noise_deg"],
                          colour=c["colour"], with_current=c["current"], name=name, controller=ctrl,
                          nameplate=file_plant, **{"resolution_deg": c["bits_span_deg"] / 4096, **sensor_kw})


def effect_size(truth, rec, sensor_kw: dict, c: dict) -> float:
    """The concealed effect's size as the proof measures it: the largest 0.1 s moving RMS of (reading with it -
    reading without it) over the noise the truth added (>= 3: detectable)."""
    from etb_gym.diagnose.locate import moving_rms
    from etb_gym.diagnose.proof_truth import effect_footprint
    with_, without = effect_footprint(truth, rec, truth.effects, sensor_kw)
    q = sensor_kw.get("resolution_deg") or c["bits_span_deg"] / 4096
    noise = math.sqrt(c["noise_deg"] ** 2 + q ** 2 / 12.0)
    return float(np.max(moving_rms(with_ - without, max(1, int(0.1 / rec.dt_s))))) / noise


def ivp_source(c: dict, truth) -> bool:
    """Whether the case's recording comes from IvpPlant (else etb_gym's plant)."""
    return c["source"] == "ivp" and not c["closed"] and not truth.effects


NAME_SETS = ({"t": "time_s", "v": "voltage_V", "d": "duty", "s": "supply_V", "a": "angle_deg", "i": "current_A"},
             {"t": "Time", "v": "U", "d": "duty_cycle", "s": "Battery_V", "a": "phi_deg", "i": "I"},
             {"t": "time_ms", "v": "voltage_mV", "d": "duty", "s": "supply_mV", "a": "position_deg", "i": "current_mA"})


def write(rec, c: dict, path: Path) -> Path:
    """The recording in the case's format and column names; with ``supply`` as duty + a measured supply."""
    names = NAME_SETS[c["names"]]
    milli = c["names"] == 2
    cols = {names["t"]: rec.t_s * (1e3 if milli else 1.0), names["a"]: rec.angle_deg}
    if c["supply"]:
        sup = rec.supply_V if rec.supply_V is not None else np.full(rec.n, 12.0)
        sup = sup + 0.05 * np.sin(2 * math.pi * 3.0 * rec.t_s)            # a battery that sags a little
        cols[names["d"]] = np.clip(rec.voltage_V / sup, -1.0, 1.0)
        cols[names["s"]] = sup * (1e3 if milli else 1.0)
    else:
        cols[names["v"]] = rec.voltage_V * (1e3 if milli else 1.0)
    if rec.current_A is not None:
        cols[names["i"]] = rec.current_A * (1e3 if milli else 1.0)
    if path.suffix == ".npz":
        np.savez(path, **cols)
    elif path.suffix == ".mat":
        from scipy.io import savemat
        savemat(path, cols)
    else:
        keys = list(cols)
        arr = np.column_stack([cols[k] for k in keys])
        np.savetxt(path, arr, delimiter=",", header=",".join(keys), comments="", fmt="%.9g")
    return path


# ------------------------------------------------------------------------------------------- one case
def _finite_json(text: str):
    """report.json parsed; raises ValueError on NaN/Infinity tokens (a silent NaN is a bug)."""
    def bad(tok):
        raise ValueError(f"report.json holds {tok}")
    return json.loads(text, parse_constant=bad)


def classify(code: int | None, err: str, out: Path, rec_path: Path) -> tuple[str, str]:
    if code is None:
        return "BUG", "timeout: " + err
    if "internal error" in err or "Traceback" in err:
        return "BUG", err.strip()[-400:]
    if code == 2:
        return ("refused", err.strip()) if rec_path.name in err or "--plant" in err else \
            ("BUG", "refusal without the file's name: " + err.strip())
    rp = out / "report.json"
    if code not in (0, 3) or not rp.exists():
        return "BUG", f"exit {code}, report.json {'present' if rp.exists() else 'missing'}: {err.strip()[-300:]}"
    try:
        rep = _finite_json(rp.read_text())
    except ValueError as e:
        return "BUG", str(e)
    if code == 3:
        return ("failed", err.strip()) if rep.get("verdict") == "failed" else ("BUG", f"exit 3, verdict {rep.get('verdict')}")
    if rep.get("verdict") not in VERDICTS:
        return "BUG", f"verdict {rep.get('verdict')!r}"
    return "ok", f"{rep['verdict']}; effects {[e.get('id') for e in rep.get('effects', [])]}"


def run_case(c: dict, timeout_s: float, keep: Path | None = None) -> dict:
    from etb_gym.plantfile import save_plant
    row = dict(c)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="etb_fuzz_") as tmp:
        tmp = Path(tmp)
        try:
            truth, file_plant, sensor_kw = truth_and_file(c)
            rec = recording(truth, file_plant, c, "rec" + c["format"], sensor_kw)
            row["source_used"] = "ivp" if ivp_source(c, truth) else "etb"
            row["effect_size"] = effect_size(truth, rec, sensor_kw, c) if c.get("effect") else None
        except Exception as e:          # noqa: BLE001 -- the harness's own data failed: a finding, not the CLI's
            row.update(outcome="NO DATA", detail=f"{type(e).__name__}: {e}", time_s=time.perf_counter() - t0)
            return row
        row["truth"] = {k: truth.params_dict()[k] for k in ("drive.resistance_ohm", "drive.inductance_H",
                                                            "rotor.inertia_kg_m2", "spring.limp_home_rad",
                                                            "stops.open_rad") if k in truth.params_dict()}
        rec_path = write(rec, c, tmp / ("rec" + c["format"]))
        if c.get("file_period"):
            file_plant = file_plant.replace(control_period_s=1e-3, substeps=20)
        pf = save_plant(file_plant, tmp / "plant.toml")
        out = tmp / "out"
        exe = Path(sys.executable).with_name("etb-gym")
        cmd = [str(exe), "diagnose", str(rec_path), *(["--plant", str(pf)] if c.get("plant_file", True) else []),
               "--model", c["model"], "--out", str(out),
               "--jobs", "1", "--quiet", "--max-effects", "1", "--candidates", *candidates(c)]
        ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        try:             # the limit is on the diagnosis's CPU time (a loaded machine stretches the wall clock)
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=WALL_PER_CPU * timeout_s,
                               env={**os.environ, "PYTHONWARNINGS": "ignore,default::RuntimeWarning"},
                               preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_CPU, (int(timeout_s),) * 2))
            code, err = p.returncode, p.stderr
            row["runtime_warnings"] = sorted({w.strip()[-200:] for w in err.splitlines() if "RuntimeWarning" in w})
            err = "\n".join(w for w in err.splitlines() if "Warning" not in w and not w.startswith("  "))
            if code in (-signal.SIGXCPU, -signal.SIGKILL):
                code, err = None, f"CPU time over {timeout_s:g} s"
        except subprocess.TimeoutExpired:
            code, err = None, f"wall time over {WALL_PER_CPU * timeout_s:g} s"
        ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        row["cpu_s"] = (ru1.ru_utime + ru1.ru_stime) - (ru0.ru_utime + ru0.ru_stime)
        row["outcome"], row["detail"] = classify(code, err, out, rec_path)
        row["exit"] = code
        if row["outcome"] == "ok":
            rep = json.loads((out / "report.json").read_text())
            row["verdict"], row["effects"] = rep["verdict"], [e.get("id") for e in rep.get("effects", [])]
            row["twin"] = check_twin(out / "calibrated_plant.toml", rec)
            if row["twin"].startswith("BUG"):
                row["outcome"], row["detail"] = "BUG", row["twin"]
        if keep is not None and row["outcome"] != "ok":
            dest = keep / f"case{c['case']}"
            dest.mkdir(parents=True, exist_ok=True)
            for f in (rec_path, pf, out / "report.json"):
                if f.exists():
                    (dest / f.name).write_bytes(f.read_bytes())
    row["time_s"] = time.perf_counter() - t0
    return row


def check_twin(path: Path, rec) -> str:
    """The exported twin loads back (plant file and its [sensor] section), simulates the recording's voltage to
    finite angles within its stops (+-5 deg), and drives the Gymnasium env for 50 steps. "ok: replay N x noise"
    (the twin's replay RMS over the recording's noise estimate: a sanity figure, not a score), else "BUG: ..."."""
    import warnings
    try:
        from etb_gym.plantfile import load_plant_and_sensor
        plant, _ = load_plant_and_sensor(path)
        V = plant.supply.voltage_V
        tr = plant.simulate(duty=np.clip(rec.voltage_V[:-1] / V, -1.0, 1.0), angle_deg=math.degrees(plant.limp_home_rad))
        a = np.degrees(np.asarray(tr.angle_rad))
        if not np.all(np.isfinite(a)):
            return "BUG: the twin's simulation gives non-finite angles"
        lo, hi = math.degrees(plant.angle_min_rad) - 5.0, math.degrees(plant.angle_max_rad) + 5.0
        if a.min() < lo or a.max() > hi:
            return f"BUG: the twin's angle {a.min():.1f}..{a.max():.1f} deg leaves its stops {lo + 5:.1f}..{hi - 5:.1f}"
        import gymnasium as gym
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = gym.make("ETB-3B-v0", plant=str(path))
            obs, _ = env.reset(seed=0)
            for _ in range(50):
                obs, r, *_ = env.step(env.action_space.sample())
            env.close()
        if not (np.all(np.isfinite(np.asarray(obs, float))) and math.isfinite(float(r))):
            return "BUG: the env on the twin gives non-finite observations or rewards"
        rms = float(np.sqrt(np.mean((a[: rec.n] - rec.angle_deg[: a.size]) ** 2)))
        return f"ok: replay {rms:.3g} deg"
    except Exception as e:          # noqa: BLE001 -- any failure to load or run the twin is the finding
        return f"BUG: the twin {path.name}: {type(e).__name__}: {e}"


def _size(r: dict) -> str:
    return "" if r.get("effect_size") is None else " (size %.1f)" % r["effect_size"]


def summary(rows: list) -> str:
    from collections import Counter
    n = Counter(r["outcome"] for r in rows)
    lines = [f"{len(rows)} cases: " + ", ".join(f"{k} {v}" for k, v in sorted(n.items()))]
    for r in rows:
        if r.get("outcome") == "ok":
            lines.append(f"  case {r['case']} {r['model']} {r.get('source_used', r['source'])} {r['fs_hz']:.0f} Hz "
                         f"{'closed' if r['closed'] else 'open'} truth {r.get('effect') or 'clean'}"
                         f"{_size(r)}"
                         f"{'' if r.get('plant_file', True) else ' (--model only)'}: {r.get('verdict')} "
                         f"{r.get('effects')}, twin {r.get('twin', '-')}")
    for r in rows:
        if r["outcome"] != "ok":
            lines.append(f"- case {r['case']} {r['model']} {r.get('source_used', r['source'])} {r['fs_hz']:.0f} Hz "
                         f"{r['format']} "
                         f"{'closed' if r['closed'] else 'open'}{'' if r.get('plant_file', True) else ' --model only'}: {r['outcome']}: {r['detail'][:300]}")
    return "\n".join(lines)


def rerun(rows_file: Path, case: int, d: Path) -> int:
    """A case of a rows file rebuilt from its settings (the draw's fields) in ``d`` and diagnosed with the log."""
    from etb_gym.plantfile import save_plant
    rows = [json.loads(x) for x in rows_file.read_text().splitlines() if x.strip()]
    r = next((x for x in rows if x["case"] == case), None)
    if r is None:
        raise SystemExit(f"{rows_file}: no case {case}")
    c = {k: r.get(k) for k in draw_case(np.random.default_rng(0), 0, 1.0)}
    d.mkdir(parents=True, exist_ok=True)
    truth, file_plant, sensor_kw = truth_and_file(c)
    rec_path = write(recording(truth, file_plant, c, "rec" + c["format"], sensor_kw), c, d / ("rec" + c["format"]))
    if c.get("file_period"):
        file_plant = file_plant.replace(control_period_s=1e-3, substeps=20)
    pf = save_plant(file_plant, d / "plant.toml")
    cmd = [str(Path(sys.executable).with_name("etb-gym")), "diagnose", str(rec_path),
           *(["--plant", str(pf)] if c.get("plant_file", True) else []), "--model", c["model"], "--out",
           str(d / "out"), "--force", "--jobs", "1", "--max-effects", "1", "--candidates", *candidates(c)]
    print(" ".join(cmd), flush=True)
    return subprocess.run(cmd).returncode


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--cases", type=int, default=18, help="number of cases (default 18)")
    ap.add_argument("--first", type=int, default=0, help="index of the first case (default 0)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the draw (default 0)")
    ap.add_argument("--out", help="rows file (JSON lines; appended)")
    ap.add_argument("--timeout", type=float, default=600.0,
                    help="CPU seconds per diagnosis before it counts as a BUG (default 600; the issue's worst case "
                         "is 4 min per 10 s); the wall clock gets 10 times that")
    ap.add_argument("--keep", metavar="DIR", help="keep the inputs and report of every case that is not ok")
    ap.add_argument("--summary", metavar="ROWS", help="print the summary of a rows file and exit")
    ap.add_argument("--effects", type=float, default=0.5, metavar="SHARE",
                    help="share of cases whose truth carries a concealed effect (a proof family and truth shape; "
                         "default 0.5; 0: the clean cases of rounds 10-22, same draws)")
    ap.add_argument("--rerun", nargs=3, metavar=("ROWS", "CASE", "DIR"),
                    help="rebuild case CASE of a rows file (its recording and plant file, in DIR) and run the command "
                         "on it with its log shown, then exit")
    a = ap.parse_args(argv)
    if a.rerun:
        return rerun(Path(a.rerun[0]), int(a.rerun[1]), Path(a.rerun[2]))
    if a.summary:
        rows = [json.loads(x) for x in Path(a.summary).read_text().splitlines() if x.strip()]
        print(summary(rows))
        return 0
    if a.cases < 1:
        ap.error(f"--cases = {a.cases}: expected 1 or more")
    rng = np.random.default_rng(a.seed)
    if not 0.0 <= a.effects <= 1.0:
        ap.error(f"--effects = {a.effects}: expected a share between 0 and 1")
    cases = [draw_case(rng, k, a.effects) for k in range(a.first + a.cases)][a.first:]
    rows = []
    for c in cases:
        r = run_case(c, a.timeout, Path(a.keep) if a.keep else None)
        rows.append(r)
        print(f"case {c['case']} {c['model']} {r.get('source_used', c['source'])} {c['fs_hz']:.0f} Hz "
              f"{c['duration_s']:g} s "
              f"{'closed' if c['closed'] else 'open'} {c['format']} truth {c.get('effect') or 'clean'}: "
              f"{r['outcome']} ({r['time_s']:.0f} s, CPU {r.get('cpu_s') or 0:.0f} s) "
              f"{r['detail'][:160]}", flush=True)
        if a.out:
            Path(a.out).parent.mkdir(parents=True, exist_ok=True)
            with open(a.out, "a") as f:
                f.write(json.dumps(r, default=float) + "\n")
    print(summary(rows))
    return 1 if any(r["outcome"] in ("BUG", "NO DATA") for r in rows) else 0


if __name__ == "__main__":
    os.environ.setdefault("PYTHONWARNINGS", "ignore")
    sys.exit(main())
