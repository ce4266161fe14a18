"""Evidence for shapes from the data and physics outside the catalogue: truths whose effects are NOT the
candidates' formulas, rig-like recordings of them, the diagnosis on the recordings only, and scores.

Truth effects (components below, kinds ``truth.*``; none of them is a candidate's equation):

    cogging          detent torque periodic in angle, period 10-30 deg, waveform a smoothed sawtooth, a
                     rounded square wave or narrow pulses (outside the catalogue)
    airflow_bump     a Gaussian bump of torque over angle (centre 30-70 deg, width 8-25 deg)   [airflow_torque]
    airflow_step     a logistic step of torque over angle (a table-like plateau)                [airflow_torque]
    speed_friction   friction that builds up with speed, T = -a tanh(omega/w0) |omega|/(|omega| + w1),
                     10-40 % stronger in one direction                                        [stribeck_friction]
    voltage_loss     a drop u = a i / sqrt(|i| + i0) (square-root-like in current)             [supply_drop]

Per run (seed): truth = model 3B with friction +-15 %, spring +-10 % (as scripts/prove_diagnosis.py), one
effect at a log-uniform magnitude; a 10 s recording (open or closed loop by seed parity, 0.01 / 0.03 deg
noise, white or AR(1), 12-bit quantization, synthetic.make_recording) is diagnosed; the exported plant file
is loaded back and replayed on a held-out recording with the other excitation (open <-> closed loop).

Scores: effect size (max 100 ms moving RMS of the truth with minus without the effect, over the true noise;
detectable >= 3), held-out RMS of the exported twin over the true noise (target <= 1.5 in >= 80 % of the
detectable runs), for outside-catalogue truths whether any catalogue effect was given as the explanation
(target: none in >= 90 %) and the reported period against the truth (within 10 %), the diagnosis time.

    python -m etb_gym.diagnose.shapes_eval --seeds 4 --out out/shapes_eval.jsonl
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from ..components.base import Component, Params
from ..jit import kernel
from ..plant import make_plant

DETECTABLE = 3.0
FAMILIES = ("cogging", "airflow_bump", "airflow_step", "speed_friction", "voltage_loss")
OUTSIDE = ("cogging",)
CATALOGUE_NAME = {"airflow_bump": "airflow_torque", "airflow_step": "airflow_torque",
                  "speed_friction": "stribeck_friction", "voltage_loss": "supply_drop"}


# ------------------------------------------------------------------------------------ truth components
@dataclasses.dataclass(frozen=True)
class CoggingParams(Params):
    amplitude_Nm: float = 0.01
    period_rad: float = math.radians(15.0)
    phase_rad: float = 0.0
    waveform: float = 0.0             # 0 smoothed sawtooth, 1 rounded square, 2 narrow pulses


@kernel
def cogging_kernel(t, phi, omega, i, u, s, p, ds):
    x = 2.0 * math.pi * (phi - p[2]) / p[1]
    w = p[3]
    if w < 0.5:                                   # sawtooth, six harmonics, scaled to about +-1
        v = 0.0
        for h in range(1, 7):
            v += (-1.0) ** (h + 1) * math.sin(h * x) / h
        v *= 0.6
    elif w < 1.5:                                 # rounded square wave
        v = math.tanh(3.0 * math.sin(x))
    else:                                         # narrow pulses, zero mean
        c = math.cos(x)
        v = 2.0 * (math.exp(4.0 * (c - 1.0)) - 0.2)
    return p[0] * v, 0.0, 0.0


class Cogging(Component):
    kind = "truth.cogging"
    role = "effect"
    Params = CoggingParams
    kernel = staticmethod(cogging_kernel)


@dataclasses.dataclass(frozen=True)
class AngleShapeParams(Params):
    peak_Nm: float = -0.05
    centre_rad: float = math.radians(50.0)
    width_rad: float = math.radians(15.0)
    step: float = 0.0                 # 0 Gaussian bump, 1 logistic step


@kernel
def angle_shape_kernel(t, phi, omega, i, u, s, p, ds):
    x = (phi - p[1]) / p[2]
    if p[3] < 0.5:
        return p[0] * math.exp(-0.5 * x * x), 0.0, 0.0
    return p[0] / (1.0 + math.exp(-4.0 * x)), 0.0, 0.0


class AngleShape(Component):
    kind = "truth.angle_shape"
    role = "effect"
    Params = AngleShapeParams
    kernel = staticmethod(angle_shape_kernel)


@dataclasses.dataclass(frozen=True)
class SpeedFrictionTruthParams(Params):
    level_Nm: float = 0.03
    smoothing_rad_s: float = 0.02
    build_up_rad_s: float = 0.5
    opening_factor: float = 1.2       # the level while opening, relative to closing


@kernel
def speed_friction_truth_kernel(t, phi, omega, i, u, s, p, ds):
    a = abs(omega)
    f = p[3] if omega > 0.0 else 1.0
    return -p[0] * f * math.tanh(omega / p[1]) * a / (a + p[2]), 0.0, 0.0


class SpeedFrictionTruth(Component):
    kind = "truth.speed_friction"
    role = "effect"
    Params = SpeedFrictionTruthParams
    kernel = staticmethod(speed_friction_truth_kernel)


@dataclasses.dataclass(frozen=True)
class VoltageLossParams(Params):
    level_V_per_sqrt_A: float = 0.3
    knee_A: float = 0.05


@kernel
def voltage_loss_kernel(t, phi, omega, i, u, s, p, ds):
    return 0.0, p[0] * i / math.sqrt(abs(i) + p[1]), 0.0


class VoltageLoss(Component):
    kind = "truth.voltage_loss"
    role = "effect"
    Params = VoltageLossParams
    kernel = staticmethod(voltage_loss_kernel)


def truth_effect(family: str, rng: np.random.Generator, scale: float):
    """(effect component, truth description) at magnitude ``scale`` in [0, 1] (1 large, log-uniform)."""
    m = lambda lo, hi: lo * (hi / lo) ** scale
    if family == "cogging":
        P = math.radians(rng.uniform(10.0, 30.0))
        wf = float(rng.integers(0, 3))
        a = m(0.004, 0.03)
        return Cogging(amplitude_Nm=a, period_rad=P, phase_rad=rng.uniform(0, P), waveform=wf), \
            {"period_deg": math.degrees(P), "amplitude_Nm": a, "waveform": ["sawtooth", "square", "pulses"][int(wf)]}
    if family in ("airflow_bump", "airflow_step"):
        a = -m(0.01, 0.1) * (1.0 if rng.random() < 0.8 else -1.0)
        c = math.radians(rng.uniform(30.0, 70.0))
        w = math.radians(rng.uniform(8.0, 25.0))
        return AngleShape(peak_Nm=a, centre_rad=c, width_rad=w, step=float(family == "airflow_step")), \
            {"peak_Nm": a, "centre_deg": math.degrees(c), "width_deg": math.degrees(w)}
    if family == "speed_friction":
        a = m(0.01, 0.06)
        return SpeedFrictionTruth(level_Nm=a, build_up_rad_s=rng.uniform(0.2, 2.0),
                                  opening_factor=rng.uniform(0.8, 1.4)), {"level_Nm": a}
    if family == "voltage_loss":
        a = m(0.05, 0.5)
        return VoltageLoss(level_V_per_sqrt_A=a), {"level_V_per_sqrt_A": a}
    raise ValueError(f"family {family!r}: expected one of {', '.join(FAMILIES)}")


def truth_plant(rng, effect, substeps: int = 100):
    over = {"friction.coulomb_Nm": 0.2 * rng.uniform(0.85, 1.15), "spring.preload_Nm": 0.15 * rng.uniform(0.9, 1.1),
            "spring.rate_Nm_per_rad": 0.36 * rng.uniform(0.9, 1.1)}
    over["friction.static_Nm"] = over["friction.coulomb_Nm"] * 1.1
    p = make_plant("3B", over, substeps=substeps)
    return p.replace(effects=(effect,)) if effect is not None else p


# ------------------------------------------------------------------------------------ one run
def run_case(family: str, seed: int, duration_s: float = 10.0, jobs: int = 1, workdir=None,
             truth_substeps: int = 100, candidates=None) -> dict:
    from ..plantfile import load_plant
    from .locate import moving_rms
    from .model import angle_residuals_deg, prepare, simulate
    from .measurement import SensorModel
    from .run import Options, diagnose
    from .synthetic import make_recording
    from .candidates import CANDIDATES

    rng = np.random.default_rng(7_000 * (FAMILIES.index(family) + 1) + seed)
    scale = float(rng.uniform(0.0, 1.0))
    effect, desc = truth_effect(family, rng, scale)
    truth = truth_plant(rng, effect, truth_substeps)
    closed = seed % 2 == 1
    noise = [0.01, 0.03][(seed // 2) % 2]
    colour = 0.5 if (seed // 4) % 2 else 0.0
    rseed = int(rng.integers(1 << 30))
    rec = make_recording(truth, np.random.default_rng(rseed), duration_s=duration_s, closed=closed,
                         noise_deg=noise, colour=colour, name=f"{family}_{seed}.csv")
    held = make_recording(truth, np.random.default_rng(rseed + 1), duration_s=duration_s, closed=not closed,
                          noise_deg=noise, colour=colour, name=f"{family}_{seed}_heldout.csv")
    true_noise = math.sqrt(noise ** 2 + (90.0 / 4096) ** 2 / 12.0)
    data = prepare([rec], 12.0)
    with_ = simulate(truth, SensorModel(), data)[0][0]
    without = simulate(truth.replace(effects=()), SensorModel(), data)[0][0]
    size = float(np.max(moving_rms(with_ - without, int(0.1 / rec.dt_s)))) / true_noise
    tmp = tempfile.TemporaryDirectory() if workdir is None else None
    out = Path(workdir if workdir is not None else tmp.name) / f"out_{family}_{seed}"
    opts = Options(model="3B", jobs=jobs, progress=False, verbose=False,
                   **({"candidates": tuple(candidates)} if candidates else {}))
    t0 = time.perf_counter()
    res = diagnose([rec], out=out, options=opts)
    elapsed = time.perf_counter() - t0
    rep = res.report
    twin = load_plant(out / "calibrated_plant.toml")          # the exported twin, loaded back
    hd = prepare([held], 12.0)
    r_twin = angle_residuals_deg(simulate(twin, res.sensor, hd), hd)[0]
    r_nom = angle_residuals_deg(simulate(*res.nominal_fit.spec.build(res.nominal_fit.x), hd), hd)[0]
    r_truth = angle_residuals_deg(simulate(truth, SensorModel(), hd), hd)[0]   # what the truth itself reaches
    ids = [e["id"] for e in rep["effects"]]
    catalogue_given = [i for i in ids if i in CANDIDATES and i != "sensor_quantization"]
    outside = [u for u in rep["unexplained"] if u.get("outside_catalogue")]
    row = {"family": family, "seed": seed, "scale": scale, "closed": closed, "noise_deg": noise, "colour": colour,
           "truth": desc, "effect_size": size, "detectable": size >= DETECTABLE, "verdict": rep["verdict"],
           "effects": ids, "outside_id": outside[0]["id"] if outside else None,
           "outside_summary": outside[0]["description"] if outside else None,
           "shaped": [e["id"] for e in rep["effects"] if "shape" in e],
           "heldout_twin_over_noise": float(np.sqrt(np.mean(r_twin ** 2))) / true_noise,
           "heldout_nominal_over_noise": float(np.sqrt(np.mean(r_nom ** 2))) / true_noise,
           "heldout_truth_over_noise": float(np.sqrt(np.mean(r_truth ** 2))) / true_noise,
           "time_s": elapsed, "true_noise_deg": true_noise}
    if family in OUTSIDE:
        row["catalogue_given"] = bool(catalogue_given)
        per = outside[0]["shape"]["angle"]["period_deg"] if outside and outside[0]["shape"]["angle"]["periodic"] else None
        row["period_deg"] = per
        row["period_ok"] = bool(per is not None and abs(per - desc["period_deg"]) <= 0.1 * desc["period_deg"])
    else:
        row["named"] = bool(ids) and ids[0] == CATALOGUE_NAME[family]
    if tmp is not None:
        tmp.cleanup()
    return row


def summarize(rows: list) -> dict:
    """Rates over the detectable runs, per family and over all."""
    out = {}
    for fam in list(FAMILIES) + ["all"]:
        rs = [r for r in rows if (fam == "all" or r["family"] == fam)]
        det = [r for r in rs if r["detectable"]]
        if not rs:
            continue
        d = {"runs": len(rs), "detectable": len(det),
             "heldout_within_1p5": sum(r["heldout_twin_over_noise"] <= 1.5 for r in det),
             "heldout_median": float(np.median([r["heldout_twin_over_noise"] for r in det])) if det else None,
             "heldout_truth_median": float(np.median([r["heldout_truth_over_noise"] for r in det])) if det else None,
             "heldout_nominal_median": float(np.median([r["heldout_nominal_over_noise"] for r in det])) if det else None,
             "time_median_s": float(np.median([r["time_s"] for r in rs])),
             "time_max_s": float(np.max([r["time_s"] for r in rs]))}
        o = [r for r in det if r["family"] in OUTSIDE]
        if o:
            d["no_catalogue_given"] = sum(not r["catalogue_given"] for r in o)
            d["period_within_10pct"] = sum(r["period_ok"] for r in o)
            d["outside_runs"] = len(o)
        out[fam] = d
    return out


def markdown(summary: dict) -> str:
    """The summary as a Markdown table (docs/diagnosis-shapes.md)."""
    lines = ["| family | runs (detectable) | held-out twin <= 1.5x noise | median held-out / noise: nominal, twin, truth | no "
             "catalogue effect given | period within 10 % | time median / max [s] |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for fam, d in summary.items():
        det = d["detectable"]
        pct = lambda k, n: f"{k}/{n} ({100 * k / n:.0f}%)" if n else "-"
        med = (f"{d['heldout_nominal_median']:.1f}, {d['heldout_median']:.2f}, {d['heldout_truth_median']:.2f}"
               if d["heldout_median"] is not None else "-")
        o = d.get("outside_runs", 0)
        lines.append(f"| {fam} | {d['runs']} ({det}) | {pct(d['heldout_within_1p5'], det)} | {med} | "
                     f"{pct(d.get('no_catalogue_given', 0), o)} | {pct(d.get('period_within_10pct', 0), o)} | "
                     f"{d['time_median_s']:.0f} / {d['time_max_s']:.0f} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description="Diagnose truths whose effects are not the candidates' formulas "
                                             "(shapes from the data, physics outside the catalogue) and score.")
    ap.add_argument("--families", nargs="+", default=list(FAMILIES), choices=FAMILIES)
    ap.add_argument("--seeds", type=int, default=4, help="seeds per family (default 4)")
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=10.0, help="recording length [s] (default 10)")
    ap.add_argument("--jobs", type=int, default=1, help="parallel fits per diagnosis (default 1)")
    ap.add_argument("--out", type=Path, required=True, help="JSON-lines file of the rows (appended; resumable)")
    ap.add_argument("--summarize", nargs="*", type=Path, default=None, metavar="ROWS",
                    help="only print the summary of --out and these further row files (Markdown)")
    a = ap.parse_args(argv)
    if a.summarize is not None:
        rows = [json.loads(line) for f in [a.out, *a.summarize] if f.exists() for line in f.read_text().splitlines()]
        print(markdown(summarize(rows)))
        return
    if a.seeds < 1 or a.duration <= 1.0:
        ap.error("--seeds must be >= 1 and --duration > 1 s")
    done = set()
    rows = []
    if a.out.exists():
        for line in a.out.read_text().splitlines():
            r = json.loads(line)
            rows.append(r)
            done.add((r["family"], r["seed"]))
    a.out.parent.mkdir(parents=True, exist_ok=True)
    from tqdm import tqdm
    todo = [(f, s) for s in range(a.first_seed, a.first_seed + a.seeds) for f in a.families if (f, s) not in done]
    for f, s in tqdm(todo, unit="run"):
        r = run_case(f, s, a.duration, a.jobs)
        rows.append(r)
        with open(a.out, "a") as fh:
            fh.write(json.dumps(r) + "\n")
        tqdm.write(f"{f} seed {s}: size {r['effect_size']:.1f}, effects {r['effects']}, outside {r['outside_id']}, "
                   f"held-out {r['heldout_twin_over_noise']:.2f}x noise, {r['time_s']:.0f} s"
                   + (f", period {r['period_deg']} vs {r['truth']['period_deg']:.1f}" if f in OUTSIDE else ""))
    print(json.dumps(summarize(rows), indent=2))


if __name__ == "__main__":
    main()
