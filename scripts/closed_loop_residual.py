"""Closed-loop recordings: the observer residual (etb_gym/diagnose/observer.py) against the replay, measured.

Two measurements, both on synthetic closed-loop recordings (``synthetic.make_recording(closed=True)``):

  --mode nominal    (fast) the calibrated nominal model's residual per residual kind and observer bandwidth:
                    RMS / noise floor, number of mismatch windows and whether the residual is significant
                    (result.significant_residual, what decides between `match` and a search for effects)
  --mode diagnose   the whole diagnosis (run.diagnose) per case: verdict, effects named, loop and residual used
  --mode scan       a candidate's screening fit without / with the profiled scan, and its held-out gain over
                    0.5 s and 0.1 s fold blocks (fit.py; docs/diagnosis-history.md round 13)

Cases: clean 3B under the default PID, the PID without friction compensation and a stiffer PID without it
(crossover 80 rad/s, phase margin 35 deg); clean random nameplates (``synthetic.random_nameplate``, the tool
given a plant file with friction and spring 10-20 % off, ``synthetic.nameplate_file_plant``, the PID designed
on that file); and concealed effects of the proof's families (``proof.truth_for``) under the default PID, with
the size of the effect (proof.effect_footprint: max 100 ms moving RMS of the reading with - without the effect,
replayed, in noise units).

    .venv/bin/python scripts/closed_loop_residual.py --mode nominal --seeds 3 --bandwidths 0,140,210,350
    .venv/bin/python scripts/closed_loop_residual.py --mode diagnose --seeds 3 --cases clean-stiff,flux
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings

import numpy as np

from etb_gym.controllers.pid import PIDController
from etb_gym.diagnose import fit as F
from etb_gym.diagnose import locate as L
from etb_gym.diagnose import observer as O
from etb_gym.diagnose.model import Spec, angle_residuals_deg, prepare, simulate
from etb_gym.diagnose.proof import _controller, effect_footprint, truth_for, truth_plant
from etb_gym.diagnose.result import significant_residual
from etb_gym.diagnose.run import Options, choose_substeps, diagnose, numerical_tolerance
from etb_gym.diagnose.synthetic import make_recording, nameplate_file_plant, random_nameplate
from etb_gym.plant import make_plant

CLEAN = {"clean-default": None, "clean-nofc": dict(friction_compensation=False),
         "clean-stiff": dict(crossover_rad_s=80.0, phase_margin_deg=35.0, friction_compensation=False)}
EFFECTS = {"flux": "shaft_flux_loss", "airflow": "airflow_torque", "spring": "spring_asymmetry",
           "stribeck": "stribeck_friction", "kc": "torque_constant_error", "heating": "coil_heating",
           "adf": "angle_dependent_friction", "supply": "supply_drop", "offset": "sensor_offset_gain",
           "backlash": "backlash", "stop": "end_stop_compliance", "delay": "sensor_delay"}
CASES = list(CLEAN) + ["clean-nameplate"] + list(EFFECTS)


def make_case(case: str, seed: int, duration_s: float, noise_deg: float):
    """(recording, base plant for the tool, truth, effects, sensor kwargs, family or None)."""
    rng = np.random.default_rng(1000 * (CASES.index(case) + 1) + seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if case in CLEAN:
            truth = truth_plant(rng, [], substeps=40)
            ctrl = None if CLEAN[case] is None else PIDController(**CLEAN[case])
            rec = make_recording(truth, rng, duration_s=duration_s, closed=True, noise_deg=noise_deg,
                                 controller=ctrl, name=f"{case}_{seed}.csv")
            return rec, make_plant("3B"), truth, [], {}, None
        if case == "clean-nameplate":
            truth = random_nameplate(rng, substeps=40)
            file_plant = nameplate_file_plant(truth, rng)
            rec = make_recording(truth, rng, duration_s=duration_s, closed=True, noise_deg=noise_deg,
                                 controller=_controller(file_plant), name=f"{case}_{seed}.csv")
            return rec, file_plant, truth, [], {}, None
        fam = EFFECTS[case]
        effects, sensor_kw, _, _ = truth_for(fam, rng, float(rng.uniform(0.0, 1.0)))
        truth = truth_plant(rng, effects, substeps=40)
        rec = make_recording(truth, rng, duration_s=duration_s, closed=True, noise_deg=noise_deg,
                             name=f"{case}_{seed}.csv", **sensor_kw)
        return rec, make_plant("3B"), truth, effects, sensor_kw, fam


def effect_size(rec, truth, effects, sensor_kw, noise_deg) -> float:
    if not effects and not sensor_kw:
        return 0.0
    w, wo = effect_footprint(truth, rec, effects, sensor_kw)
    q = sensor_kw.get("resolution_deg", 90.0 / 4096)
    d = w - wo
    return float(np.max(L.moving_rms(d, int(0.1 / rec.dt_s)))) / math.sqrt(noise_deg ** 2 + q ** 2 / 12.0)


def nominal_row(rec, base, bandwidth: float) -> dict:
    """The calibrated nominal model's residual with the replay (bandwidth 0) or the observer."""
    O.OMEGA_O = bandwidth if bandwidth > 0 else O.OMEGA_O
    data = prepare([rec], base.supply.voltage_V, residual="observer" if bandwidth > 0 else "replay")
    b = base.replace(control_period_s=rec.dt_s)
    b = b.replace(substeps=choose_substeps(b, data))
    spec = Spec(b)
    nom = F.calibrate(spec, data, max_nfev=40)
    numerical_tolerance(spec, nom.x, data)
    r = angle_residuals_deg(simulate(*spec.build(nom.x), data), data)
    rd = data.recs[0]
    return {"rms_over_noise": float(math.sqrt(np.mean(r[0] ** 2)) / rd.noise_deg),
            "windows": len(L.windows(rec.t_s, r[0], rd.noise_deg, rd.tol_deg)),
            "significant": bool(significant_residual(data, r))}


class _Captured(Exception):
    pass


def proof_recording(spec: str, duration_s: float, workdir: str):
    """The recording (and the plant the tool is given) of a proof case ``FAMILY[@SHAPE]:SEED[:random]``,
    made exactly as ``proof.run_case`` makes it (its diagnosis is not run)."""
    from pathlib import Path

    from etb_gym.diagnose import proof
    from etb_gym.recordings import load_recording
    fam, seed, *rest = spec.split(":")
    nameplate = rest[0] if rest else "3B"
    args = proof._parser().parse_args(["--duration", str(duration_s), "--jobs", "1", "--nameplate", nameplate])
    got = {}

    def capture(paths, out=None, options=None):
        got["rec"], got["options"] = load_recording(paths[0]), options
        raise _Captured

    real = proof.diagnose
    proof.diagnose = capture
    try:
        proof.run_case(fam, int(seed), args, str(Path(workdir)))
    except _Captured:
        pass
    finally:
        proof.diagnose = real
    opts = got["options"]
    return got["rec"], opts.plant if opts.plant is not None else make_plant("3B")


def structure_row(rec, base) -> dict:
    """The calibrated nominal model as run.diagnose calibrates it (auto residual), its observer residual's
    significance today (result.significant_residual) and its persistent structure (disturbance.py)."""
    from etb_gym.diagnose import disturbance as D
    from etb_gym.diagnose.model import restart_view
    from etb_gym.diagnose.run import _base_and_data, polish
    t0 = time.process_time()
    b, data = _base_and_data(Options(plant=base.replace(control_period_s=rec.dt_s)), [rec])
    spec = Spec(b)
    nom = polish(F.calibrate(spec, restart_view(data), max_nfev=40), data)
    numerical_tolerance(spec, nom.x, data)
    plant, sensor = spec.build(nom.x)
    pred = simulate(plant, sensor, data)
    r = angle_residuals_deg(pred, data)
    rd = data.recs[0]
    st = D.persistent(rd, pred[0], plant) if rd.residual == "observer" else []
    return {"residual": rd.residual, "rms_over_noise": float(math.sqrt(np.mean(r[0] ** 2)) / rd.noise_deg),
            "windows": len(L.windows(rec.t_s, r[0], rd.noise_deg, rd.tol_deg)),
            "significant_today": bool(significant_residual(data, r)),
            "structure": [s.as_dict() for s in st], "cpu_s": round(time.process_time() - t0, 2)}


def _cv(spec, data, x, block_s: float) -> float:
    """fit.cross_validate's held-out angle error with every recording's folds of ``block_s``."""
    real = F.fold_block_s
    F.fold_block_s = lambda rd, b=F.FOLD_BLOCK_S: block_s
    try:
        from etb_gym.diagnose.explain import SCREEN_NFEV
        return F.cross_validate(spec, data, x, max_nfev=SCREEN_NFEV)
    finally:
        F.fold_block_s = real


def scan_row(rec, base, candidate: str) -> dict:
    """A candidate's screening fit (explain.SCREEN_NFEV evaluations from the calibrated nominal model, the scan on
    its main parameter) without and with the profiled scan (fit.scan_start), and the held-out error of the
    nominal model and of the candidate (from the profiled fit) over folds of 0.5 s and FOLD_BLOCK_OBSERVER_S."""
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.explain import SCREEN_NFEV, extend
    from etb_gym.diagnose.model import restart_view
    from etb_gym.diagnose.run import _base_and_data
    b, data = _base_and_data(Options(plant=base.replace(control_period_s=rec.dt_s)), [rec])
    fd = restart_view(data)
    nom = F.calibrate(Spec(b), fd, max_nfev=40)
    spec = nom.spec.with_candidate(CANDIDATES[candidate])
    x0, k = extend(nom.x, spec), len(nom.x)
    row = {"residual": data.recs[0].residual, "candidate": candidate, "rss_nominal": nom.rss}
    for name, prof in (("plain", False), ("profiled", True)):
        fr = F.fit(spec, fd, x0, max_nfev=SCREEN_NFEV, scan=k, profile_scan=prof)
        row[name] = {"rss": fr.rss, "nfev": fr.nfev, "values": fr.values}
    for bs in (F.FOLD_BLOCK_S, F.FOLD_BLOCK_OBSERVER_S):
        cv0 = _cv(nom.spec, fd, nom.x, bs)
        cv1 = _cv(spec, fd, F.fit(spec, fd, x0, max_nfev=SCREEN_NFEV, scan=k).x, bs)
        row[f"heldout_{bs:g}s"] = {"nominal": cv0, candidate: cv1, "gain": 1.0 - cv1 / cv0}
    return row


def _cases(a, cases):
    """(case, seed, recording, plant given to the tool, family, effect size) per case to run."""
    if a.proof:
        import tempfile
        for spec in a.proof:
            with tempfile.TemporaryDirectory() as tmp:
                rec, base = proof_recording(spec, a.duration, tmp)
            fam = spec.split(":")[0]
            yield spec, int(spec.split(":")[1]), rec, base, None if fam == "clean" else fam, None
        return
    for case in cases:
        for seed in range(a.first_seed, a.first_seed + a.seeds):
            rec, base, truth, effects, sensor_kw, fam = make_case(case, seed, a.duration, a.noise)
            yield case, seed, rec, base, fam, round(effect_size(rec, truth, effects, sensor_kw, a.noise), 2)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mode", choices=("nominal", "diagnose", "structure", "scan"), default="nominal")
    ap.add_argument("--candidate", default="backlash", help="scan mode: the candidate whose screening fit is shown")
    ap.add_argument("--proof", nargs="*", default=None, metavar="FAMILY@SHAPE:SEED[:random]",
                    help="proof cases (proof.run_case's recordings) instead of --cases")
    ap.add_argument("--cases", default=",".join(CASES), help=f"comma-separated, of {', '.join(CASES)}")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=6.0, help="recording length [s]")
    ap.add_argument("--noise", type=float, default=0.01, help="sensor noise [deg]")
    ap.add_argument("--bandwidths", default="0,210", help="observer bandwidths [rad/s]; 0: the replay")
    ap.add_argument("--residual", default="auto", choices=("auto", "replay", "observer"), help="diagnose mode")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--verbose", action="store_true", help="diagnose mode: the diagnosis's own log")
    ap.add_argument("--out", default=None, help="append one JSON line per case to this file")
    a = ap.parse_args(argv)
    cases = [c for c in a.cases.split(",") if c]
    bad = [c for c in cases if c not in CASES]
    if bad:
        ap.error(f"unknown case(s) {bad}: expected some of {', '.join(CASES)}")
    bws = [float(b) for b in a.bandwidths.split(",")]
    out = open(a.out, "a") if a.out else None
    for case, seed, rec, base, fam, size in _cases(a, cases):
        row = {"case": case, "seed": seed, "family": fam, "size": size}
        t0 = time.perf_counter()
        if a.mode == "nominal":
            for bw in bws:
                row[f"bw{bw:g}"] = nominal_row(rec, base, bw)
            txt = " | ".join(f"{k}: {v['rms_over_noise']:.2f}x w{v['windows']} {'SIG' if v['significant'] else 'ok'}"
                             for k, v in row.items() if k.startswith("bw"))
        elif a.mode == "structure":
            row.update(structure_row(rec, base))
            txt = f"{row['residual']} {row['rms_over_noise']:.2f}x {'SIG' if row['significant_today'] else 'ok'} " + \
                " ".join(f"{s['kind']}: z {s['z']:.1f} share {s['share_of_noise']:.2f} "
                         f"{'SIG' if s['significant'] else 'ok'} top {max(s['groups'], key=s['groups'].get)}"
                         for s in row["structure"])
        elif a.mode == "scan":
            row.update(scan_row(rec, base, a.candidate))
            txt = (f"{a.candidate}: RSS nominal {row['rss_nominal']:.0f}, screening plain {row['plain']['rss']:.0f} "
                   f"profiled {row['profiled']['rss']:.0f} ({row['profiled']['values']}); held-out gain "
                   + ", ".join(f"{k[8:]} {v['gain']:+.0%}" for k, v in row.items() if k.startswith("heldout_")))
        else:
            res = diagnose([rec], options=Options(plant=base, jobs=a.jobs, progress=False, verbose=a.verbose,
                                                  residual=a.residual))
            rep = res.report
            ids = [e["id"] for e in rep["effects"]]
            row.update(verdict=rep["verdict"], effects=ids, loop=rep["loop"],
                       named_first=(not ids) if fam is None else bool(ids) and ids[0] == fam.split("@")[0],
                       rms_before=rep["rms_before_deg"], rms_after=rep["rms_after_deg"],
                       noise=rep["noise_floor_deg"], cpu_s=rep.get("cpu_s"),
                       persistent=rep.get("persistent_structure"),
                       outside=[{"id": u["id"], "description": u.get("description"),
                                 "period_deg": next((d.get("period_deg") for d in (u.get("shape", {}).get("angle", {}),
                                                                                 u.get("shape", {}).get("current", {}))
                                                     if d.get("periodic")), None)}
                                for u in rep.get("unexplained", []) if u.get("outside_catalogue")])
            txt = f"{row['verdict']:16s} {ids} named_first={row['named_first']} cpu {rep.get('cpu_s', 0):.1f} s"
        row["time_s"] = round(time.perf_counter() - t0, 1)
        print(f"{case:24s} s{seed} size {size if size is not None else '-'}  {txt}  ({row['time_s']} s)", flush=True)
        if out:
            out.write(json.dumps(row) + "\n")
            out.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
