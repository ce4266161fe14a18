"""What a last joint fit of the final model on the continuous replay does to the twin (issue 15, round 15).

For each proof case (kept by ``twin_coverage.collect``: truth, recordings, the final fit and the prepared data) the
script reports the twin's held-out RMS / true noise as the diagnosis exported it, at 4x its integrator step, split
by motion (held / opening / closing), the calibrated parameters over the truth's, the twin's replay of its own
training recording, and the held-out after a plain output-error refit (``fit.fit``, at most --nfev evaluations,
from the final fit's optimum) of a set of the final model's parameters (--sets: all, nominal, formula,
nominal+formula, nominal+map) on the continuous replay (open loop) or, for a closed loop, on the replay of the
recorded voltage (``model.replay_view``; with the observer residual's cost before and after).

    nice -n 10 .venv/bin/python scripts/twin_polish.py --work /tmp/twin_cov --cases inductance_saturation@1:4:3B \\
        supply_drop@1:4:3B --sets all nominal+map --out docs/figures/diagnosis/twin_round15/polish_rows.jsonl
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

sys.path.insert(0, str(Path(__file__).resolve().parent))
import twin_coverage as TC  # noqa: E402

from etb_gym.diagnose import envelope as EV  # noqa: E402
from etb_gym.diagnose import fit as F  # noqa: E402
from etb_gym.diagnose.model import angle_residuals_deg, prepare, replay_view, simulate  # noqa: E402


def held_over_noise(plant, sensor, held, sig) -> tuple[float, np.ndarray | None]:
    hd = prepare([held], 12.0)                    # as proof.score_heldout
    p = simulate(plant, sensor, hd)
    if p is None:
        return float("nan"), None
    r = angle_residuals_deg(p, hd)[0]
    return float(np.sqrt(np.mean(r ** 2))) / sig, r


def sub_fit(spec, data, x0, idx, nfev):
    """Output-error refit of the parameters ``idx`` of ``x0`` (the others held): (x, cost, evaluations)."""
    fun = F.make_fun(spec, data)
    lo, hi = spec.bounds()

    def f(th):
        x = x0.copy()
        x[idx] = th
        return fun(x)

    res = least_squares(f, np.clip(x0[idx], lo[idx] + 1e-9, hi[idx] - 1e-9), bounds=(lo[idx], hi[idx]),
                        method="trf", diff_step=0.03, max_nfev=nfev, ftol=1e-6, xtol=1e-6, gtol=1e-8)
    x = x0.copy()
    x[idx] = res.x
    return x, float(res.fun @ res.fun), int(res.nfev)


def param_sets(spec) -> dict:
    owners = [o for o, _ in spec.params]
    fam = {o for o in owners if o != "nominal" and not o.endswith("_map")}
    pick = lambda keep: np.array([i for i, o in enumerate(owners) if keep(o)], int)   # noqa: E731
    return {"all": pick(lambda o: True), "nominal": pick(lambda o: o == "nominal"),
            "formula": pick(lambda o: o in fam), "nominal+formula": pick(lambda o: o == "nominal" or o in fam),
            "nominal+map": pick(lambda o: o == "nominal" or o.endswith("_map"))}


def analyse(case: str, k: dict, sets, nfev: int) -> dict:
    if "final_fit" not in k:
        raise SystemExit(f"{case}: the kept case has no final fit (collected before twin_polish.py); remove its pickle")
    row, held, sig, ff, data = k["row"], k["held"], k["row"]["true_noise"], k["final_fit"], k["data"]
    n = k["twin"].substeps
    h0, r0 = held_over_noise(k["twin"], k["twin_sensor"], held, sig)
    m = EV.motion_index(EV.speed_deg_s(held.t_s, held.angle_deg))
    pd, cal = k["truth"].params_dict(), k["report"]["calibrated_parameters"]
    rv = replay_view(data)
    own = angle_residuals_deg(simulate(k["twin"], k["twin_sensor"], rv), rv)
    out = {"case": case, "closed": row["closed"], "verdict": row["verdict"], "effects": row["effects"],
           "n_params": len(ff.x), "twin_substeps": n, "held_twin": h0,
           "held_twin_4x_step": held_over_noise(k["twin"].replace(substeps=4 * n), k["twin_sensor"], held, sig)[0],
           "held_by_motion": {nm: float(np.sqrt(np.mean(r0[m == i] ** 2))) / sig
                              for i, nm in enumerate(EV.MOTIONS) if np.any(m == i)},
           "time_by_motion": {nm: float(np.mean(m == i)) for i, nm in enumerate(EV.MOTIONS)},
           "final_over_truth": {p: v["value"] / pd[p] for p, v in cal.items() if pd.get(p)},
           "nominal_over_truth": {p: v["nominal_fit"] / pd[p] for p, v in cal.items() if pd.get(p)},
           "own_replay": float(np.sqrt(np.mean(np.concatenate(own) ** 2))) / sig, "refits": {}}
    view = rv if row["closed"] else dataclasses.replace(data, continuity=True)
    for name in sets:
        idx = param_sets(ff.spec)[name]
        if not idx.size:
            continue
        t = time.process_time()
        x, cost, ev = sub_fit(ff.spec, view, ff.x.copy(), idx, nfev)
        pl, se = ff.spec.build(x)
        r_a, r_b = F.evaluate(ff.spec, view, ff.x), F.evaluate(ff.spec, data, x)
        out["refits"][name] = {"n": int(idx.size), "cost_before": float(r_a @ r_a), "cost_after": cost, "nfev": ev,
                               "held": held_over_noise(pl.replace(substeps=n), se, held, sig)[0],
                               "fit_residual_cost_after": float(r_b @ r_b), "cpu_s": time.process_time() - t}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="+", required=True, help="FAMILY[@K]:SEED:3B|random")
    ap.add_argument("--work", type=Path, default=Path("/tmp/twin_cov"), help="twin_coverage's pickles (made if missing)")
    ap.add_argument("--sets", nargs="+", default=["all"], choices=["all", "nominal", "formula", "nominal+formula",
                                                                    "nominal+map"])
    ap.add_argument("--nfev", type=int, default=30)
    ap.add_argument("--duration", type=float, default=6.0)
    ap.add_argument("--out", type=Path, help="append one JSON line per case")
    a = ap.parse_args(argv)
    a.work.mkdir(parents=True, exist_ok=True)
    for case in a.cases:
        row = analyse(case, TC.collect(case, a.duration, a.work), a.sets, a.nfev)
        print(json.dumps(row), flush=True)
        if a.out:
            a.out.parent.mkdir(parents=True, exist_ok=True)
            with a.out.open("a") as fh:
                fh.write(json.dumps(row) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
