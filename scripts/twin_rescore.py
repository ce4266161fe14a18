"""Re-score the exported twin of a finished diagnosis (issue 15, round 7): the same diagnosis, the twin's held-out
RMS at the diagnosis's integrator step and at the step ``run.twin_substeps`` now gives it, and (``--refit``) with
the accepted family's table refitted from the same formula fit (``shapes.refine_family``, anchored knots).

The case's truth, training and held-out recordings are rebuilt exactly as the proof builds them
(``twin_harness.py`` cases ``FAMILY[@K]:SEED[:NAMEPLATE]``); OUT is the diagnosis folder of that case (report.json,
calibrated_plant.toml; e.g. from ``twin_harness.py --diagnose --keep DIR``). One JSON line per case.

    nice -n 10 .venv/bin/python scripts/twin_rescore.py clean:2:random=DIR/out_clean_2 [--plant DIR/clean_2_plant.toml]
    nice -n 10 .venv/bin/python scripts/twin_rescore.py airflow_torque@1:0=DIR/out_airflow_torque_s1_0 --refit
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


def refit(case, out: Path, rep: dict, rec, plant_file):
    """The accepted family's table refitted (this tree's shapes.refine_family) from the report's formula fit."""
    from etb_gym.diagnose import fit as F
    from etb_gym.diagnose import shapes as S
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
    ref = S.refine_family(fr, cid, restart_view(data), log=lambda *a: None)
    return ref.fit.spec.build(ref.fit.x), ref


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0], epilog=__doc__.split("\n", 2)[2],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cases", nargs="+", help="CASE=OUT: a twin_harness case and its diagnosis folder")
    ap.add_argument("--duration", type=float, default=6.0, help="recording length [s] the diagnosis had (default 6)")
    ap.add_argument("--refit", action="store_true", help="refit the first effect's table from its formula fit")
    ap.add_argument("--plant", default=None, help="the plant file the diagnosis was given (random nameplates)")
    ap.add_argument("--work", default="out/twin_rescore", help="folder for the rebuilt plant files")
    a = ap.parse_args(argv)
    from etb_gym.diagnose.run import twin_substeps
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    for item in a.cases:
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
        print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
