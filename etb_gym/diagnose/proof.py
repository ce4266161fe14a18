"""Blind proof of the diagnosis tool: rig-like recordings from a truth plant with a concealed effect.

For every effect family and seed: build a truth plant (calibration parameters perturbed, integrator at 200
substeps, the concealed effect at a random magnitude between large and about the detection limit), record it
open-loop or closed-loop (the package's PID on the sensor's readings) with white or coloured (AR(1)) sensor
noise and 12-bit quantization, write the files, and run ``etb-gym diagnose`` on the files only. Then score:

  size       how far the effect moves the reading: max 100 ms moving RMS of (with - without) / noise;
             runs with size >= 3 are "detectable" (the issue's lower end of magnitudes)
  named      the concealed effect is the first one reported (clean runs: no effect reported)
  windows    precision / recall of mismatch_windows_s against where the concealed effect moves the angle
             by more than 3x the noise (truth with vs without the effect)
  params     relative error of the family's main parameter and whether its 90 % interval covers the truth
  improve    RMS on a held-out recording (other excitation): calibrated nominal vs final model
  time       wall time of the diagnosis

Nameplates (``--nameplate random``): the truth's R, L, c_M, J, limp-home, stops, friction and spring levels are
drawn from wide ranges (``synthetic.NAMEPLATE_RANGES``) and the tool is given a plant file of that nameplate
whose friction and spring are 10-20 % off (``synthetic.nameplate_file_plant``); closed-loop runs use the PID
designed on that plant file.

rows.jsonl survives SIGKILL: each finished run is appended as one line in a single write and flushed to disk;
on --resume a torn last line (a run killed while its row was written) is dropped and that run is redone.

    python -m etb_gym.diagnose.proof --quick            # a few families, short recordings (tests)
    python -m etb_gym.diagnose.proof --seeds 4 --out out/proof       # every family, both loops and noise levels
    python -m etb_gym.diagnose.proof --seeds 8 --out out/proof --resume    # more seeds later, nothing re-run
    python -m etb_gym.diagnose.proof --nameplate random --seeds 4 --out out/proof_np   # other nameplates
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import dataclasses

from ..components import effects as fx
from ..components.base import Component, Params
from ..io import write_atomic
from ..jit import kernel
from ..plant import make_plant
from ..plantfile import load_plant, save_plant
from ..recordings import save_recording
from .locate import moving_rms
from .measurement import SensorModel
from .model import angle_residuals_deg, prepare, simulate
from .run import Options, diagnose
from .synthetic import make_recording, nameplate_file_plant, random_nameplate


# ---------------------------------------------------------------- a truth that is not the candidate's equation
@dataclasses.dataclass(frozen=True)
class AirflowMapParams(Params):
    peak_Nm: float = -0.05          # smooth aerodynamic map: peak closing torque near 55 deg
    peak_angle_rad: float = math.radians(55.0)
    width_rad: float = math.radians(25.0)


@kernel
def airflow_map_kernel(t, phi, omega, i, u, s, p, ds):
    x = (phi - p[1]) / p[2]
    return p[0] * math.exp(-0.5 * x * x) * (1.0 - math.exp(-8.0 * max(phi, 0.0))), 0.0, 0.0


class AirflowMap(Component):
    kind = "truth.airflow_map"
    role = "effect"
    Params = AirflowMapParams
    kernel = staticmethod(airflow_map_kernel)


def loguniform(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def sign(rng):
    return 1.0 if rng.random() < 0.5 else -1.0


# family -> (effects or sensor kwargs, main parameter name in the report, true value of it)
def truth_for(family: str, rng, scale: float):
    """``scale`` in [0, 1]: 1 large, 0 near the detection limit (log-uniform in between)."""
    m = lambda lo, hi: lo * (hi / lo) ** scale
    if family == "clean":
        return [], {}, None, None
    if family == "shaft_flux_loss":
        k = m(0.004, 0.04)
        return [fx.ShaftFluxLoss(loss_at_open_Nm_per_A=k, exponent=rng.uniform(2.0, 4.0))], {}, "loss_at_open_Nm_per_A", k
    if family == "coil_heating":
        c = m(60.0, 4.0)
        return [fx.CoilHeating(heat_capacity_J_per_K=c, thermal_resistance_K_per_W=8.0)], {}, "heat_capacity_J_per_K", c
    if family == "spring_asymmetry":
        d = m(0.01, 0.08) * sign(rng)
        return [fx.SpringAsymmetry(closing_preload_delta_Nm=d)], {}, "closing_preload_delta_Nm", d
    if family == "airflow_torque":
        a = -m(0.01, 0.12)
        return [AirflowMap(peak_Nm=a)], {}, None, None
    if family == "stribeck_friction":
        s = m(0.01, 0.08)
        return [fx.StribeckFriction(stiction_Nm=s, stribeck_velocity_rad_s=0.03)], {}, "stiction_Nm", s
    if family == "sensor_offset_gain":
        o = m(0.04, 1.0) * sign(rng)
        return [], {"offset_deg": o, "gain": 1.0 + m(0.001, 0.02) * sign(rng)}, "offset_deg", o
    if family == "torque_constant_error":
        d = m(0.002, 0.015) * sign(rng)
        return [fx.TorqueConstantError(delta_Nm_per_A=d)], {}, "delta_Nm_per_A", d
    if family == "supply_drop":
        v = m(0.05, 0.6)
        return [fx.SupplyDrop(forward_drop_V=v)], {}, "forward_drop_V", v
    if family == "backlash":
        b = m(0.002, 0.02)
        return [fx.Backlash(play_rad=b)], {}, "play_rad", b
    if family == "angle_dependent_friction":
        a = m(0.01, 0.08) * sign(rng)
        return [fx.AngleDependentFriction(slope_Nm=a)], {}, "slope_Nm", a
    if family == "inductance_saturation":
        dl = m(0.0008, 0.0045)
        return [fx.InductanceSaturation(inductance_drop_H=dl, saturation_current_A=rng.uniform(1.0, 3.0))], {}, \
            "inductance_drop_H", dl
    if family == "end_stop_compliance":
        o = math.radians(90.0 - m(0.3, 4.0))                   # the open stop sits earlier than drawn
        return [fx.EndStopCompliance(open_rad=o, stiffness_Nm_per_rad=rng.uniform(300.0, 3000.0))], {}, "open_rad", o
    if family == "sensor_quantization":
        bits = int(rng.integers(8, 11))                        # 8..10 bits instead of the assumed 12
        return [], {"resolution_deg": 90.0 / 2 ** bits}, "resolution_deg", 90.0 / 2 ** bits
    if family == "sensor_delay":
        k = int(round(m(1.0, 6.0)))
        return [], {"delay_steps": k}, "delay_s", k * 1e-3
    raise ValueError(family)


FAMILIES = ["clean", "shaft_flux_loss", "coil_heating", "spring_asymmetry", "airflow_torque", "stribeck_friction",
            "sensor_offset_gain", "torque_constant_error", "supply_drop", "backlash", "angle_dependent_friction",
            "sensor_delay", "inductance_saturation", "end_stop_compliance", "sensor_quantization"]
QUICK = ["clean", "shaft_flux_loss", "sensor_offset_gain", "spring_asymmetry"]


def truth_plant(rng, effects, substeps=40, nameplate="3B"):
    """The truth: 3B with friction and spring perturbed, or (``nameplate="random"``) a random nameplate."""
    if nameplate == "random":
        p = random_nameplate(rng, substeps=substeps)
        return p.replace(effects=effects) if effects else p
    over = {"friction.coulomb_Nm": 0.2 * rng.uniform(0.85, 1.15), "spring.preload_Nm": 0.15 * rng.uniform(0.9, 1.1),
            "spring.rate_Nm_per_rad": 0.36 * rng.uniform(0.9, 1.1)}
    over["friction.static_Nm"] = over["friction.coulomb_Nm"] * 1.1
    p = make_plant("3B", over, substeps=substeps)
    if effects:
        p = p.replace(effects=effects)
    return p


def overlap(a, b):
    tot = 0.0
    for x0, x1 in a:
        for y0, y1 in b:
            tot += max(0.0, min(x1, y1) - max(x0, y0))
    return tot


def length(ws):
    return sum(b - a for a, b in ws)


def truth_windows(rec_t, ang_with, ang_without, sigma, dt):
    d = ang_with - ang_without
    m = moving_rms(d, int(0.1 / dt)) > 3 * sigma
    out = []
    idx = np.flatnonzero(np.diff(np.concatenate([[0], m.astype(int), [0]])))
    for a, b in zip(idx[::2], idx[1::2]):
        out.append([rec_t[a], rec_t[b - 1]])
    return out


def sensor_model(sensor_kw, dt_s) -> SensorModel:
    """The truth's sensor effects (``truth_for``'s sensor kwargs) as the diagnosis's SensorModel."""
    return SensorModel(offset_deg=sensor_kw.get("offset_deg", 0.0), gain=sensor_kw.get("gain", 1.0),
                       delay_s=sensor_kw.get("delay_steps", 0) * dt_s,
                       resolution_deg=sensor_kw.get("resolution_deg", 0.0))


def effect_footprint(truth, rec, effects, sensor_kw):
    """(reading with the concealed effect, reading without it) along ``rec`` [deg]. Plate effects: the
    segment-wise simulation of the truth with and without the effect (re-initialized where the tool
    re-initializes, so a stick-slip event placed differently does not count for the rest of the recording).
    Sensor effects: the true angle (the truth replayed on the recorded voltage) read with and without them."""
    if effects:
        data = prepare([rec], 12.0)
        sm = SensorModel()
        return simulate(truth, sm, data)[0][0], simulate(truth.replace(effects=()), sm, data)[0][0]
    duty = rec.voltage_V / truth.supply.voltage_V
    phi = truth.simulate(duty=duty[:-1], angle_deg=math.degrees(truth.limp_home_rad)).angle_deg
    return sensor_model(sensor_kw, rec.dt_s).apply(rec.t_s, phi, quantize=True), phi


def _controller(plant_file):
    """The reference PID designed on the user's plant file (a lower crossover if the default cannot be met)."""
    from etb_gym.controllers.pid import PIDController
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for wc in (50.0, 30.0, 15.0):
            try:
                return PIDController(model=plant_file, crossover_rad_s=wc)
            except ValueError:
                continue
    return PIDController(model=plant_file, crossover_rad_s=15.0, phase_margin_deg=30.0)


def record_and_diagnose(name, seed, rng, truth, sensor_kw, args, workdir):
    """The case's recording and held-out recording of ``truth`` (loop, noise level and colour from the seed),
    the diagnosis of the recording's file, and the row's common fields."""
    closed = seed % 2 == 1                      # seeds cycle open/closed loop, then noise level, then colour:
    noise = [0.01, 0.03][(seed // 2) % 2]       # any 4 consecutive seeds cover both loops and both levels
    colour = 0.5 if (seed // 4) % 2 else 0.0
    kw = dict(noise_deg=noise, colour=colour, **sensor_kw)
    rec_seed = int(rng.integers(1 << 30))
    plant_file, ctrl = None, None
    if args.nameplate == "random":              # the user's file: this nameplate, friction and spring 10-20 % off
        plant_file = Path(workdir) / f"{name}_{seed}_plant.toml"
        save_plant(nameplate_file_plant(truth, rng), plant_file)
        ctrl = _controller(load_plant(plant_file))
    rec = make_recording(truth, np.random.default_rng(rec_seed), duration_s=args.duration, closed=closed,
                         name=f"{name}_{seed}.csv", controller=ctrl, **kw)
    held = make_recording(truth, np.random.default_rng(rec_seed + 1), duration_s=args.duration, closed=not closed,
                          name=f"{name}_{seed}_heldout.csv", controller=ctrl, **kw)
    path = Path(workdir) / rec.name
    save_recording(rec, path)
    out = Path(workdir) / f"out_{name}_{seed}"
    t0 = time.perf_counter()
    opts = Options(model="3B", plant=load_plant(plant_file) if plant_file else None, jobs=args.jobs, progress=False,
                   verbose=False, max_effects=args.max_effects,
                   candidates=tuple(args.candidates) if args.candidates else Options().candidates)
    res = diagnose([path], out=out, options=opts)
    elapsed = time.perf_counter() - t0
    rep = res.report
    row = {"seed": seed, "noise_deg": noise, "colour": colour, "closed": closed, "nameplate": args.nameplate,
           "loop_detected": rep.get("loop", {}).get(rec.name), "skipped": rep.get("skipped_candidates", []),
           "verdict": rep["verdict"], "effects": [e["id"] for e in rep["effects"]], "rms_before": rep["rms_before_deg"],
           "rms_after": rep["rms_after_deg"], "noise_floor": rep["noise_floor_deg"], "time_s": elapsed}
    q = sensor_kw.get("resolution_deg", 90.0 / 4096)
    row["true_noise"] = math.sqrt(noise ** 2 + q ** 2 / 12.0)        # what the truth added (incl. quantization)
    return rec, held, res, row, out


def score_windows(row, rec, rep, with_, without):
    """Effect size and window precision / recall against where (with - without) exceeds 3x the noise."""
    d = with_ - without
    row["effect_size"] = float(np.max(moving_rms(d, int(0.1 / rec.dt_s)))) / row["true_noise"]
    row["effect_rms"] = float(np.sqrt(np.mean(d ** 2)))
    tw = truth_windows(rec.t_s, with_, without, row["true_noise"], rec.dt_s)
    rw = rep["mismatch_windows_s"][rec.name]
    row["win_precision"] = overlap(rw, tw) / length(rw) if length(rw) > 0 else (1.0 if not tw else 0.0)
    row["win_recall"] = overlap(rw, tw) / length(tw) if length(tw) > 0 else 1.0


def score_param(rep, fid, pname, ptrue):
    """The fitted main parameter of effect ``fid`` against the truth (None if the effect was not reported)."""
    for e in rep["effects"]:
        if e["id"] == fid and pname in e["parameters"]:
            v, se = e["parameters"][pname]["value"], e["parameters"][pname]["stderr"]
            return {"param": pname, "param_true": ptrue, "param_fit": v, "param_stderr": se,
                    "param_rel_err": abs(v - ptrue) / abs(ptrue),
                    "param_covered": bool(se is not None and abs(v - ptrue) <= 1.645 * se)}
    return None


def score_heldout(row, res, held):
    """RMS on the held-out recording (other excitation): calibrated nominal vs final model."""
    hd = prepare([held], 12.0)
    nom_plant, nom_sensor = res.nominal_fit.spec.build(res.nominal_fit.x)
    r0 = angle_residuals_deg(simulate(nom_plant, nom_sensor, hd), hd)[0]
    r1 = angle_residuals_deg(simulate(res.plant, res.sensor, hd), hd)[0]
    row["heldout_rms_before"] = float(np.sqrt(np.mean(r0 ** 2)))
    row["heldout_rms_after"] = float(np.sqrt(np.mean(r1 ** 2)))
    row["heldout_noise"] = hd.recs[0].noise_deg                     # the tool's estimate from the held-out file


def run_case(family, seed, args, workdir):
    if family.startswith("pair:"):
        return run_pair(family[5:], seed, args, workdir)
    rng = np.random.default_rng(10_000 * (FAMILIES.index(family) + 1) + seed)
    scale = rng.uniform(0.0, 1.0)
    effects, sensor_kw, pname, ptrue = truth_for(family, rng, scale)
    truth = truth_plant(rng, effects, substeps=args.truth_substeps, nameplate=args.nameplate)
    rec, held, res, row, out = record_and_diagnose(family, seed, rng, truth, sensor_kw, args, workdir)
    rep = res.report
    ids = row["effects"]
    row = {"family": family, "seed": seed, "scale": scale, **row}
    row["named"] = (not ids) if family == "clean" else (bool(ids) and ids[0] == family)
    if family != "clean":                   # where the concealed effect acts: truth with vs without it (deg)
        score_windows(row, rec, rep, *effect_footprint(truth, rec, effects, sensor_kw))
    if pname and row["named"]:
        row.update(score_param(rep, family, pname, ptrue) or {})
    score_heldout(row, res, held)
    return row, out


# ---------------------------------------------------------------- two concealed effects at once
PAIRS = ["shaft_flux_loss+coil_heating", "angle_dependent_friction+supply_drop", "sensor_delay+torque_constant_error"]


def pair_footprints(truth, rec, parts, sensor_kw):
    """Reading with both effects, reading with neither, and per effect (reading with both - reading without
    that one), all by the segment-wise simulation of the truth (deg)."""
    data = prepare([rec], 12.0)
    sim = lambda effects, kw: simulate(truth.replace(effects=tuple(effects)), sensor_model(kw, rec.dt_s), data)[0][0]
    both = sim(truth.effects, sensor_kw)
    each = []
    for _, _, fx_k, kw_k, _, _ in parts:
        rest = [e for e in truth.effects if all(e is not f for f in fx_k)]
        each.append(both - sim(rest, {k: v for k, v in sensor_kw.items() if k not in kw_k}))
    return both, sim((), {}), each


def run_pair(pair, seed, args, workdir):
    """Two families concealed at once, each at a moderate to large magnitude. Named: both reported (either
    order); detectable: each moves the reading by >= DETECTABLE x the noise on its own."""
    fams = pair.split("+")
    rng = np.random.default_rng(10_000 * (100 + PAIRS.index(pair)) + seed)
    parts = []
    for f in fams:
        scale = rng.uniform(0.3, 1.0)
        parts.append((f, scale) + tuple(truth_for(f, rng, scale)))
    effects = [e for p in parts for e in p[2]]
    sensor_kw = {k: v for p in parts for k, v in p[3].items()}
    truth = truth_plant(rng, effects, substeps=args.truth_substeps, nameplate=args.nameplate)
    rec, held, res, row, out = record_and_diagnose("pair_" + "_".join(fams), seed, rng, truth, sensor_kw, args, workdir)
    rep = res.report
    ids = row["effects"]
    row = {"family": "pair:" + pair, "seed": seed, "scales": [p[1] for p in parts], **row}
    row["named"] = set(ids[:2]) == set(fams)
    row["named_first"] = bool(ids) and ids[0] in fams
    both, neither, each = pair_footprints(truth, rec, parts, sensor_kw)
    score_windows(row, rec, rep, both, neither)
    row["effect_sizes"] = [float(np.max(moving_rms(d, int(0.1 / rec.dt_s)))) / row["true_noise"] for d in each]
    row["params"] = [dict(family=f, **(score_param(rep, f, pn, pt) or {})) for f, _, _, _, pn, pt in parts if pn]
    score_heldout(row, res, held)
    return row, out


DETECTABLE = 3.0     # an effect that moves the reading by >= 3 x the noise (100 ms moving RMS) somewhere


def summarize(rows):
    """Per family: rates over all runs and over the runs whose effect is detectable (DETECTABLE)."""
    fams = []
    for f in FAMILIES:
        rs = [r for r in rows if r["family"] == f]
        if not rs:
            continue
        # clean runs have nothing to detect; a coarse grid is read off the values whatever the noise
        det = [r for r in rs if f in ("clean", "sensor_quantization") or r.get("effect_size", 0.0) >= DETECTABLE]
        d = {"family": f, "runs": len(rs), "detectable": len(det),
             "named_rate": float(np.mean([r["named"] for r in rs])),
             "named_rate_detectable": float(np.mean([r["named"] for r in det])) if det else float("nan"),
             "rms_before": float(np.median([r["rms_before"] for r in rs])),
             "rms_after": float(np.median([r["rms_after"] for r in rs])),
             "heldout_reduction": float(np.median([1 - r["heldout_rms_after"] / r["heldout_rms_before"] for r in det or rs])),
             "heldout_after_over_noise": float(np.median([r["heldout_rms_after"] / r["true_noise"] for r in det or rs])),
             "time_s": float(np.median([r["time_s"] for r in rs])),
             "verdicts": {v: sum(r["verdict"] == v for r in rs)
                          for v in ("match", "explained", "partly_explained", "unexplained") if any(r["verdict"] == v for r in rs)}}
        wp = [r for r in det if "win_precision" in r]
        if wp:
            d["win_precision"] = float(np.mean([r["win_precision"] for r in wp]))
            d["win_recall"] = float(np.mean([r["win_recall"] for r in wp]))
        pe = [r for r in rs if "param_rel_err" in r]
        if pe:
            d["param_median_rel_err"] = float(np.median([r["param_rel_err"] for r in pe]))
            d["param_coverage"] = float(np.mean([r["param_covered"] for r in pe]))
        fams.append(d)
    return fams


def table(fams) -> str:
    L = ["| family | runs (detectable) | named first: all / detectable (clean: none claimed) | RMS before / after [deg] | "
         "held-out RMS reduction | held-out after / noise | windows P / R | param median rel. err | 90 % coverage | time [s] | verdicts |",
         "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for d in fams:
        w = f"{d['win_precision']:.2f} / {d['win_recall']:.2f}" if "win_precision" in d else "-"
        p = f"{d['param_median_rel_err']:.1%}" if "param_median_rel_err" in d else "-"
        c = f"{d['param_coverage']:.0%}" if "param_coverage" in d else "-"
        nd = "-" if d["named_rate_detectable"] != d["named_rate_detectable"] else f"{d['named_rate_detectable']:.0%}"
        L.append(f"| {d['family']} | {d['runs']} ({d['detectable']}) | {d['named_rate']:.0%} / {nd} | "
                 f"{d['rms_before']:.4f} / {d['rms_after']:.4f} | {d['heldout_reduction']:.0%} | "
                 f"{d['heldout_after_over_noise']:.2f} | {w} | {p} | {c} | {d['time_s']:.0f} | "
                 + ", ".join(f"{k} {n}" for k, n in d["verdicts"].items()) + " |")
    return "\n".join(L)


def _frac(xs) -> str:
    xs = list(xs)
    return f"{sum(xs)}/{len(xs)} ({sum(xs) / len(xs):.0%})" if xs else "-"


def pair_table(rows) -> str:
    """Runs with two concealed effects, per pair (Markdown; empty if there are none)."""
    L = []
    for pair in PAIRS:
        rs = [r for r in rows if r["family"] == "pair:" + pair]
        if not rs:
            continue
        det = [r for r in rs if min(r["effect_sizes"]) >= DETECTABLE]
        ps = [p for r in rs for p in r["params"] if "param_rel_err" in p]
        L.append(f"| {pair.replace('+', ' + ')} | {len(rs)} ({len(det)}) | {_frac(r['named'] for r in det)} | "
                 f"{_frac(r['named_first'] for r in det)} | "
                 f"{np.median([r['rms_before'] for r in rs]):.4f} / {np.median([r['rms_after'] for r in rs]):.4f} | "
                 f"{_frac(r['heldout_rms_after'] <= 0.5 * r['heldout_rms_before'] for r in det)} | "
                 f"{np.median([r['heldout_rms_after'] / r['true_noise'] for r in det or rs]):.2f} | "
                 f"{np.mean([r['win_precision'] for r in det or rs]):.2f} / {np.mean([r['win_recall'] for r in det or rs]):.2f} | "
                 + (f"{np.median([p['param_rel_err'] for p in ps]):.1%} | {_frac(p['param_covered'] for p in ps)} | " if ps else "- | - | ")
                 + f"{np.median([r['time_s'] for r in rs]):.0f} |")
    if not L:
        return ""
    return "\n".join(["| pair | runs (both detectable) | both named (detectable) | one of them named first | "
                      "RMS before / after [deg] | held-out RMS falls >= 50 % | held-out after / noise | windows P / R | "
                      "param median rel. err (both) | 90 % coverage | time [s] |",
                      "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"] + L)


def targets(rows) -> str:
    """The issue's targets against what the single-effect rows measured (Markdown)."""
    rows = [r for r in rows if not r["family"].startswith("pair:")]
    det = [r for r in rows if r["family"] != "clean" and
           (r["family"] == "sensor_quantization" or r.get("effect_size", 0.0) >= DETECTABLE)]
    clean = [r for r in rows if r["family"] == "clean"]
    win = [r for r in det if "win_precision" in r and r["family"] not in ("sensor_quantization",)]
    par = [r for r in det if "param_rel_err" in r]
    moderate = [r for r in par if r.get("effect_size", math.inf) >= 10.0]
    t = sorted(r["time_s"] for r in rows)
    L = ["| target | measured |", "| --- | --- |",
         f"| right effect named first >= 90 % (detectable runs) | {_frac(r['named'] for r in det)} |",
         f"| clean recordings: no effect claimed >= 95 % | {_frac(r['named'] for r in clean)} |",
         f"| clean recordings: verdict `match` | {_frac(r['verdict'] == 'match' for r in clean)} |",
         "| mismatch windows precision / recall >= 0.8 (mean over detectable runs) | "
         + (f"{np.mean([r['win_precision'] for r in win]):.2f} / {np.mean([r['win_recall'] for r in win]):.2f}" if win else "-") + " |",
         f"| main parameter within +-10 % (named runs, effect >= 10x noise) | {_frac(r['param_rel_err'] <= 0.10 for r in moderate)} |",
         f"| 90 % interval covers the truth >= 85 % (named runs) | {_frac(r['param_covered'] for r in par)} |",
         f"| held-out RMS falls >= 50 % (detectable runs) | {_frac(r['heldout_rms_after'] <= 0.5 * r['heldout_rms_before'] for r in det)} |",
         f"| held-out RMS ends <= 1.5x the noise (detectable runs) | {_frac(r['heldout_rms_after'] <= 1.5 * r['true_noise'] for r in det)} |",
         f"| diagnosis of 10 s at 1 kHz, full library, <= 120 s | {_frac(x <= 120.0 for x in t)}; median {np.median(t):.0f} s, max {t[-1]:.0f} s |"
         if t else "| time | - |"]
    return "\n".join(L)


def _atomic(path: Path, text: str) -> None:
    write_atomic(path, text)


DOCS = {"docs/diagnosis.md": ("targets", "families", "pairs"), "README.md": ("targets",)}


def update_docs(root: Path, blocks: dict) -> list:
    """Replace the text between ``<!-- proof:NAME -->`` and ``<!-- /proof:NAME -->`` in the files of DOCS."""
    import re
    changed = []
    for rel, names in DOCS.items():
        path = root / rel
        text = path.read_text()
        for name in names:
            pat = re.compile(rf"(<!-- proof:{name} -->\n).*?(\n<!-- /proof:{name} -->)", re.S)
            if not pat.search(text):
                raise SystemExit(f"{path}: markers <!-- proof:{name} --> ... <!-- /proof:{name} --> not found")
            text = pat.sub(lambda m: m.group(1) + blocks[name] + m.group(2), text)
        _atomic(path, text)
        changed.append(str(path))
    return changed


def read_rows(rows_file: Path) -> list:
    """The finished runs of ``rows_file``. A torn last line (the proof was killed while writing it) is cut off
    the file, so that run is done again and appended whole; a torn line anywhere else is an error."""
    raw = rows_file.read_bytes()
    lines = raw.split(b"\n")
    rows, good = [], 0
    for k, line in enumerate(lines):
        if not line.strip():
            good += len(line) + (1 if k < len(lines) - 1 else 0)
            continue
        try:
            rows.append(json.loads(line))
        except ValueError:
            if k < len(lines) - 1 and any(x.strip() for x in lines[k + 1:]):
                raise SystemExit(f"{rows_file}: line {k + 1} is not a JSON row: repair or remove it")
            break
        if k == len(lines) - 1:          # a last row without its newline was not written whole
            rows.pop()
            break
        good += len(line) + 1
    if good < len(raw):
        with open(rows_file, "r+b") as fh:
            fh.truncate(good)
    return rows


def append_row(rows_file: Path, row: dict) -> None:
    """Append one run as one line: a single write on an O_APPEND descriptor, then fsync. A SIGKILL leaves the
    row whole or (at worst) a torn last line without its newline, which :func:`read_rows` drops."""
    data = (json.dumps(row, default=float) + "\n").encode()
    fd = os.open(rows_file, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)


def _key(r) -> tuple:
    return r["family"], r["seed"], r.get("nameplate", "3B")


def loop_table(rows) -> str:
    """Rates per loop type and nameplate (single-effect runs): named first on detectable runs, clean runs."""
    rows = [r for r in rows if not r["family"].startswith("pair:")]
    L = ["| nameplate | loop | detectable runs: named first | clean: no effect claimed | clean: `match` | "
         "held-out after / noise (detectable, median) | time median / max [s] |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for npl in sorted({r.get("nameplate", "3B") for r in rows}):
        for closed in (False, True):
            rs = [r for r in rows if r.get("nameplate", "3B") == npl and r["closed"] == closed]
            if not rs:
                continue
            det = [r for r in rs if r["family"] != "clean" and
                   (r["family"] == "sensor_quantization" or r.get("effect_size", 0.0) >= DETECTABLE)]
            cl = [r for r in rs if r["family"] == "clean"]
            t = [r["time_s"] for r in rs]
            ho = f"{np.median([r['heldout_rms_after'] / r['true_noise'] for r in det]):.2f}" if det else "-"
            L.append(f"| {npl} | {'closed' if closed else 'open'} | {_frac(r['named'] for r in det)} | "
                     f"{_frac(r['named'] for r in cl)} | {_frac(r['verdict'] == 'match' for r in cl)} | {ho} | "
                     f"{np.median(t):.0f} / {np.max(t):.0f} |")
    return "\n".join(L)


def main(argv=None) -> int:
    """``etb-gym prove`` / ``python -m etb_gym.diagnose.proof``: exit code 0, or 2 on a usage error."""
    try:
        run(argv)
    except SystemExit as e:
        if e.code in (None, 0):
            return 0
        if isinstance(e.code, str):
            print(f"etb-gym prove: {e.code}", file=sys.stderr)
            return 2
        return int(e.code)
    return 0


def run(argv=None):
    """Run (or summarize) the proof; returns (rows, per-family summary)."""
    ap = argparse.ArgumentParser(prog="etb-gym prove", description=__doc__.split("\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n", 2)[2])
    ap.add_argument("--quick", action="store_true", help=f"families {QUICK}, 1 seed, 4 s recordings, small library")
    ap.add_argument("--families", nargs="+", choices=FAMILIES, default=None)
    ap.add_argument("--pairs", nargs="*", choices=PAIRS, default=None, metavar="PAIR",
                    help=f"run two-effect cases: these, or all of {PAIRS} if none is named (with --families: as well)")
    ap.add_argument("--seeds", type=int, default=20, help="seeds per family (default 20)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=10.0, help="recording length [s] (default 10)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--max-effects", type=int, default=2)
    ap.add_argument("--candidates", nargs="+", default=None, help="restrict the library")
    ap.add_argument("--nameplate", choices=("3B", "random"), default="3B",
                    help="the truth's nameplate: the default 3B (the tool runs with --model 3B), or drawn from wide "
                         "ranges (the tool gets a plant file of it with friction and spring 10-20 %% off)")
    ap.add_argument("--truth-substeps", type=int, default=200,
                    help="integrator substeps of the truth plant (default 200: 5 us, near the exact solution)")
    ap.add_argument("--out", default=None, help="write rows.jsonl (one line per run), proof.json, proof.md and "
                    "example figures here")
    ap.add_argument("--resume", action="store_true", help="continue the proof in --out (skips finished runs)")
    ap.add_argument("--summarize", action="store_true", help="only rebuild proof.md/proof.json from --out's rows")
    ap.add_argument("--update-docs", action="store_true",
                    help="also write the tables into docs/diagnosis.md and README.md (between <!-- proof:... --> markers)")
    a = ap.parse_args(argv)
    if a.quick:
        a.families = a.families or QUICK
        a.seeds = min(a.seeds, 1) if a.seeds == 20 else a.seeds
        a.duration = min(a.duration, 4.0)
        a.candidates = a.candidates or ["shaft_flux_loss", "spring_asymmetry", "sensor_offset_gain", "airflow_torque",
                                        "stribeck_friction"]
    fams = a.families or ([] if a.pairs is not None else FAMILIES)
    if a.pairs is not None:
        fams = list(fams) + ["pair:" + p for p in (a.pairs or PAIRS)]
    out = Path(a.out) if a.out else None
    rows_file = out / "rows.jsonl" if out else None
    rows = []
    if out:
        out.mkdir(parents=True, exist_ok=True)
        if rows_file.exists():
            if not (a.resume or a.summarize):
                raise SystemExit(f"{rows_file} exists: pass --resume to continue that proof (or --summarize), "
                                 "or choose another --out")
            rows = read_rows(rows_file)
    elif a.resume or a.summarize:
        raise SystemExit("--resume and --summarize need --out DIR")
    done = {_key(r) for r in rows}
    todo = [(f, s) for s in range(a.first_seed, a.first_seed + a.seeds) for f in fams
            if (f, s, a.nameplate) not in done]
    if a.summarize:
        todo = []
    from tqdm import tqdm
    with tempfile.TemporaryDirectory() as work:
        bar = tqdm(total=len(todo), unit="run", disable=not todo)
        for f, s in todo:                   # seeds outer: a stopped proof still covers every family
            row, outdir = run_case(f, s, a, work)
            rows.append(row)
            if rows_file:
                append_row(rows_file, row)       # whole or not at all, also on SIGKILL
            bar.set_description(f"{f} seed {s}: {row['effects']} ({row['time_s']:.0f} s)")
            bar.update(1)
            if out and s == a.first_seed:
                import shutil
                dst = out / ("example_" + f.replace("pair:", "pair_").replace("+", "_"))
                dst.mkdir(parents=True, exist_ok=True)
                for fn in ("residual_time.png", "residual_regimes.png", "angle_fit.png", "report.json", "report.md"):
                    if (outdir / fn).exists():
                        shutil.copy(outdir / fn, dst / fn)
        bar.close()
    fam = summarize(rows)
    pairs = pair_table(rows)
    loops = loop_table(rows) if rows else ""
    txt = table(fam) + "\n\n" + targets(rows) + ("\n\n" + loops if loops else "") + ("\n\n" + pairs if pairs else "")
    print(txt)
    if rows:
        total_time = [r["time_s"] for r in rows]
        print(f"\n{len(rows)} runs, diagnosis time median {np.median(total_time):.0f} s, max {np.max(total_time):.0f} s")
    if out:
        _atomic(out / "proof.json", json.dumps({"rows": rows, "families": fam, "args": vars(a)}, indent=1, default=float))
        _atomic(out / "proof.md", txt + "\n")
    if a.update_docs:
        for f in update_docs(Path(__file__).resolve().parents[2], {"targets": targets(rows), "families": table(fam),
                                                                  "pairs": pairs or "(no two-effect runs)"}):
            print(f"updated {f}")
    return rows, fam


if __name__ == "__main__":
    sys.exit(main())
