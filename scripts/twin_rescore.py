"""Re-score the exported twin of a finished diagnosis (issue 15, round 7): the same diagnosis, the twin's held-out
RMS at the diagnosis's integrator step and at the step ``run.twin_substeps`` now gives it, and (``--refit``) with
the accepted family's table refitted from the same formula fit (``family_table.refine_family``, anchored knots).

The case's truth, training and held-out recordings are rebuilt exactly as the proof builds them
(``twin_harness.py`` cases ``FAMILY[@K]:SEED[:NAMEPLATE]``); OUT is the diagnosis folder of that case (report.json,
calibrated_plant.toml; e.g. from ``twin_harness.py --diagnose --keep DIR``). One JSON line per case.

    nice -n 10 .venv/bin/python scripts/twin_rescore.py clean:2:random=DIR/out_clean_2 [--plant DIR/clean_2_plant.toml]
    nice -n 10 .venv/bin/python scripts/twin_rescore.py airflow_torque@1:0=DIR/out_airflow_torque_s1_0 --refit

``--named`` (round 8) needs no diagnosis: the case's own family is taken as named, its formula fitted and its table
refined on this tree (:func:`named_case`); ``--static`` adds the twin's static torque against the truth's around
limp-home, and the rows give the held-out residual per angle band (``ho_bands``):

    nice -n 10 .venv/bin/python scripts/twin_rescore.py --named --static --duration 6 airflow_torque@2:1 shaft_flux_loss@1:1
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import twin_harness as TH  # noqa: E402

from etb_gym.diagnose.measurement import SensorModel  # noqa: E402
from etb_gym.diagnose.model import angle_residuals_deg, prepare, simulate  # noqa: E402
from etb_gym.diagnose.proof_truth import FAMILIES, family_shape, sensor_model, truth_for, truth_plant  # noqa: E402
from etb_gym.plantfile import load_plant  # noqa: E402


def rebuild(case: str, duration: float, work: Path):
    """(truth, sensor kwargs, recording, held-out recording, seed) of a proof case, drawn as run_case draws them."""
    fam, seed, nameplate = TH.parse_case(case, "3B")
    f0, shape = family_shape(fam)
    rng = np.random.default_rng(10_000 * (FAMILIES.index(f0) + 1) + 1_000_000 * shape + seed)
    scale = rng.uniform(0.0, 1.0)
    effects, sensor_kw, _, _ = truth_for(f0, rng, scale, shape)
    truth = truth_plant(rng, effects, substeps=200, nameplate=nameplate)
    rec, held = TH._recordings(fam.replace("@", "_s"), seed, truth, sensor_kw, rng,
                               argparse.Namespace(duration=duration), work, nameplate)
    return truth, sensor_kw, rec, held, seed


def rms_over(plant, sensor, data, noise) -> float:
    return math.sqrt(float(np.mean(angle_residuals_deg(simulate(plant, sensor, data), data)[0] ** 2))) / noise


def heldout_bands(plant, sensor, data, noise, edges_deg=(0.0, 6.0, 12.0, 30.0, 90.0)) -> dict:
    """Where the held-out residual sits: per band of the recorded angle, the share of the samples and the RMS
    residual over the noise."""
    r = angle_residuals_deg(simulate(plant, sensor, data), data)[0]
    ang = data.recs[0].rec.angle_deg
    out = {}
    for lo, hi in zip(edges_deg[:-1], edges_deg[1:]):
        m = (ang >= lo) & (ang < hi) if hi < edges_deg[-1] else ang >= lo
        if m.any():
            out[f"{lo:g}-{hi:g}"] = {"share": round(float(m.mean()), 3),
                                     "rms": round(math.sqrt(float(np.mean(r[m] ** 2))) / noise, 2)}
    return out


def static_torque_Nm(plant, angles_deg) -> np.ndarray:
    """The plant's torque at rest with no current (spring and every effect, states at 0), over ``angles_deg``."""
    comps = [c for c in (plant.spring,) + tuple(plant.effects) if c is not None]
    out = np.zeros(len(angles_deg))
    for c in comps:
        p = np.asarray(c.param_vector(), float)
        s = np.zeros(len(c.state_names))
        for k, a in enumerate(angles_deg):
            out[k] += float(c.kernel(0.0, math.radians(a), 0.0, 0.0, 0.0, s, p, np.zeros_like(s))[0])
    return out


def refit(case, out: Path, rep: dict, rec, plant_file):
    """The accepted family's table refitted (this tree's family_table.refine_family) from the report's formula fit."""
    from etb_gym.diagnose import fit as F
    from etb_gym.diagnose import family_table as FT
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.model import Spec, restart_view
    from etb_gym.plant import make_plant
    cid = rep["effects"][0]["id"]
    data = prepare([rec], 12.0, residual="auto")
    base = (load_plant(plant_file) if plant_file else make_plant("3B")).replace(substeps=rep["integrator_substeps"])
    spec = Spec(base).with_candidate(CANDIDATES[cid])
    vals = {k: v["value"] for k, v in rep["calibrated_parameters"].items()}
    vals.update({f"{cid}.{k}": v["value"] for k, v in rep["effects"][0]["parameters"].items()})
    fr = F.FitResult(spec, spec.x_from_values(vals), 0.0, 1, None, 0)
    ref = FT.refine_family(fr, cid, restart_view(data), log=lambda *a: None)
    return ref.fit.spec.build(ref.fit.x), ref


def named_case(case: str, duration: float, work: Path, static=None) -> dict:
    """Without a diagnosis: the case's own family taken as named (its formula fitted as the selection fits it: the
    nominal model first, then nominal + formula, FULL_NFEV each, at the step ``run.choose_substeps`` picks), its
    table refined by this tree's ``family_table.refine_family``; the twin (formula + table, at 40 substeps) replayed on
    the held-out recording. Isolates the refinement from the selection: the same formula fit on every tree."""
    from etb_gym.diagnose import fit as F
    from etb_gym.diagnose import family_table as FT
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.explain import FULL_NFEV
    from etb_gym.diagnose.model import Spec, restart_view
    from etb_gym.diagnose.run import choose_substeps
    from etb_gym.plant import make_plant
    fam, seed, nameplate = TH.parse_case(case, "3B")
    cid = fam.split("@")[0]
    truth, skw, rec, held, seed = rebuild(case, duration, work)
    q = getattr(skw.get("reading"), "resolution_deg", None) or skw.get("resolution_deg", 90.0 / 4096)
    noise = math.sqrt([0.01, 0.03][(seed // 2) % 2] ** 2 + q ** 2 / 12.0)
    base = (load_plant(work / f"h_{fam.replace('@', '_s')}_{seed}_plant.toml") if nameplate == "random"
            else make_plant("3B"))
    data = prepare([rec], base.supply.voltage_V, residual="auto")
    base = base.replace(substeps=choose_substeps(base, data))
    from etb_gym.diagnose.locate import moving_rms
    from etb_gym.diagnose.proof_truth import effect_footprint
    w, wo = effect_footprint(truth, rec, list(truth.effects), skw)
    size = float(np.max(moving_rms(w - wo, int(0.1 / rec.dt_s)))) / noise
    c0 = time.process_time()
    nominal = F.fit(Spec(base), data, max_nfev=FULL_NFEV)
    spec = Spec(base).with_candidate(CANDIDATES[cid])
    formula = F.fit(spec, data, np.concatenate([nominal.x, np.zeros(len(spec.params) - len(nominal.x))]),
                    max_nfev=FULL_NFEV, scan=len(nominal.x))
    c1 = time.process_time()
    ref = FT.refine_family(formula, cid, restart_view(data), log=lambda *a: None)
    c2 = time.process_time()
    hd = prepare([held], base.supply.voltage_V)
    smt = sensor_model({k: v for k, v in skw.items() if k != "resolution_deg"}, rec.dt_s)
    pf, sf = formula.spec.build(formula.x)
    row = {"case": case, "family": cid, "closed": seed % 2 == 1, "nameplate": nameplate, "n": base.substeps,
           "effect_size": size,
           "cpu_formula": c1 - c0, "cpu_refine": c2 - c1,
           "ho_nominal": rms_over(nominal.spec.build(nominal.x)[0].replace(substeps=40), sf, hd, noise),
           "ho_formula": rms_over(pf.replace(substeps=40), sf, hd, noise), "truth_40": rms_over(
               truth.replace(substeps=40), smt, hd, noise), "fit_formula": rms_over(pf, sf, data, noise)}
    if ref is not None:
        (pm, sm) = ref.fit.spec.build(ref.fit.x)
        row.update(kept=ref.kept, cv_formula=ref.heldout_formula, cv_map=ref.heldout_map,
                   fit_map=rms_over(pm, sm, data, noise), ho_map=rms_over(pm.replace(substeps=40), sm, hd, noise))
        twin = pm if ref.kept else pf
        row["ho_bands"] = heldout_bands(twin.replace(substeps=40), sm if ref.kept else sf, hd, noise)
        row["ho_twin"] = row["ho_map"] if ref.kept else row["ho_formula"]
        if twin.spring is not None and truth.spring is not None:
            row["spring_over_truth"] = {"preload": twin.spring.params.preload_Nm / truth.spring.params.preload_Nm,
                                        "rate": twin.spring.params.rate_Nm_per_rad / truth.spring.params.rate_Nm_per_rad}
        if static is not None:
            lh = math.degrees(truth.limp_home_rad)
            ang = static or [max(lh - 3.0, 0.0), lh - 1.0, lh, lh + 1.0, lh + 3.0, lh + 6.0, 20.0, 40.0, 60.0, 80.0]
            row["static_err_mNm"] = {f"{x:.1f}": round(float(e), 2) for x, e in zip(
                ang, 1e3 * (static_torque_Nm(twin, ang) - static_torque_Nm(truth, ang)))}
    else:
        row["ho_twin"] = row["ho_formula"]
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0], epilog=__doc__.split("\n", 2)[2],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="+", help="CASE=OUT: a twin_harness case and its diagnosis folder (CASE with --named)")
    ap.add_argument("--duration", type=float, default=6.0, help="recording length [s] the diagnosis had (default 6)")
    ap.add_argument("--refit", action="store_true", help="refit the first effect's table from its formula fit")
    ap.add_argument("--named", action="store_true",
                    help="CASE without a diagnosis: the case's family taken as named, formula and table fitted here")
    ap.add_argument("--static", type=float, nargs="*", default=None, metavar="DEG",
                    help="also give the twin's static torque (at rest, no current) minus the truth's at these "
                         "angles [mN m] (default with the flag: limp-home -3 .. +9 deg and 20 .. 80 deg)")
    ap.add_argument("--plant", default=None, help="the plant file the diagnosis was given (random nameplates)")
    ap.add_argument("--work", default="out/twin_rescore", help="folder for the rebuilt plant files")
    a = ap.parse_args(argv)
    from etb_gym.diagnose.run import twin_substeps
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    for item in a.cases:
        if a.named:
            print(json.dumps(named_case(item, a.duration, work, a.static), default=float), flush=True)
            continue
        if "=" not in item:
            ap.error(f"{item!r}: expected CASE=OUT (e.g. clean:0=out/dev/out_clean_0)")
        case, out = item.split("=", 1)
        out = Path(out)
        rep = json.loads((out / "report.json").read_text())
        truth, skw, rec, held, seed = rebuild(case, a.duration, work)
        q = getattr(skw.get("reading"), "resolution_deg", None) or skw.get("resolution_deg", 90.0 / 4096)
        noise = math.sqrt([0.01, 0.03][(seed // 2) % 2] ** 2 + q ** 2 / 12.0)
        s = rep["sensor"]
        sm = SensorModel(offset_deg=s["offset_deg"], gain=s["gain"], delay_s=s["delay_s"])
        row = {"case": case}
        if a.refit and rep["effects"]:
            (plant, sm), ref = refit(case, out, rep, rec, a.plant)
            row.update(kept=ref.kept, heldout_formula=ref.heldout_formula, heldout_map=ref.heldout_map)
        else:
            plant = load_plant(out / "calibrated_plant.toml")
        data = prepare([rec], plant.supply.voltage_V)
        c = time.process_time()
        nt = twin_substeps(plant, sm, data)
        row["cpu_twin_step"] = time.process_time() - c
        hd = prepare([held], 12.0)
        smt = sensor_model({k: v for k, v in skw.items() if k != "resolution_deg"}, rec.dt_s)
        row.update(n=plant.substeps, n_twin=nt, ho_n=rms_over(plant, sm, hd, noise),
                   ho_twin=rms_over(plant.replace(substeps=nt), sm, hd, noise),
                   ho_twin80=rms_over(plant.replace(substeps=80), sm, hd, noise),
                   truth_n=rms_over(truth.replace(substeps=plant.substeps), smt, hd, noise),
                   truth_80=rms_over(truth.replace(substeps=80), smt, hd, noise))
        if a.static is not None:
            lh = math.degrees(truth.limp_home_rad)
            ang = a.static or [max(lh - 3.0, 0.0), lh - 1.0, lh, lh + 1.0, lh + 3.0, lh + 6.0, lh + 9.0, 20.0, 40.0,
                               60.0, 80.0]
            err = 1e3 * (static_torque_Nm(plant, ang) - static_torque_Nm(truth, ang))
            row["static_err_mNm"] = {f"{x:.1f}": round(float(e), 2) for x, e in zip(ang, err)}
            sp_t, sp_p = truth.spring.params, plant.spring.params
            row["spring_over_truth"] = {"preload": sp_p.preload_Nm / sp_t.preload_Nm,
                                        "rate": sp_p.rate_Nm_per_rad / sp_t.rate_Nm_per_rad}
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
