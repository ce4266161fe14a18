"""What the calibration traded on one proof case (docs/diagnosis.md, "Effects the calibration absorbs", round 16):
the calibrated nominal parameters against the plant file the tool was given and against the truth, in % of the
file's value; the case's row (verdict, effects, twin on the held-out recording over the noise).

    python scripts/absorb_trade.py airflow_torque@1 11 --nameplate random
"""
import argparse
import json
import tempfile

import numpy as np
from scipy.optimize import least_squares

from etb_gym.diagnose import fit as F
from etb_gym.diagnose import proof
from etb_gym.diagnose.model import angle_residuals_deg, prepare, restart_view, simulate


def with_prior(nominal: F.FitResult, data, width: float, max_nfev: int = 40):
    """The calibration again from its optimum with a Gaussian prior on each nominal parameter: mean the file's
    value, standard deviation ``width`` x it (extra residual rows in the fit's units; ``width`` None: no prior, the
    same refit). Returns (x, data RSS before, data RSS after)."""
    spec = nominal.spec
    fun = F.make_fun(spec, data)
    init = np.array([p.init for _, p in spec.params])
    scale = np.array([p.scale for _, p in spec.params])
    lo, hi = spec.bounds()

    def objective(x):
        r = fun(x)
        return r if width is None else np.concatenate([r, scale * x / (width * init)])

    out = least_squares(objective, np.clip(nominal.x, lo + 1e-9, hi - 1e-9), bounds=(lo, hi), method="trf",
                        diff_step=0.03, max_nfev=max_nfev, ftol=1e-6, xtol=1e-6, gtol=1e-8)
    r0, r1 = fun(nominal.x), fun(out.x)
    return out.x, float(r0 @ r0), float(r1 @ r1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("case")
    ap.add_argument("seed", type=int)
    ap.add_argument("--nameplate", choices=("3B", "random"), default="3B")
    ap.add_argument("--duration", type=float, default=6.0)
    ap.add_argument("--row", help="append the result (JSON) to this file")
    ap.add_argument("--verbose", action="store_true", help="print the diagnosis's log")
    ap.add_argument("--calibration-only", action="store_true",
                    help="stop after the calibration (no candidate, no shape refinement): the verdict is then the "
                         "calibrated nominal model's, `match` or not; what the levels traded is the same")
    ap.add_argument("--prior-width", type=float, default=0.15,
                    help="the calibration refitted with a prior of this relative width around the file's values")
    a = ap.parse_args(argv)
    if a.verbose:
        quiet = proof.Options
        proof.Options = lambda **kw: quiet(**{**kw, "verbose": True})
    seen = {}
    truth_plant, diagnose, score_heldout = proof.truth_plant, proof.diagnose, proof.score_heldout

    def keep_heldout(row, res, held):
        seen["held"] = held
        return score_heldout(row, res, held)

    def keep_truth(*args, **kw):
        seen["truth"] = truth_plant(*args, **kw)
        return seen["truth"]

    def keep_result(paths, out=None, options=None):
        seen["file"] = options.plant if options.plant is not None else proof.make_plant("3B")
        seen["res"] = diagnose(paths, out=out, options=options)
        return seen["res"]

    proof.truth_plant, proof.diagnose, proof.score_heldout = keep_truth, keep_result, keep_heldout
    args = ["--duration", str(a.duration), "--jobs", "1", "--nameplate", a.nameplate]
    if a.calibration_only:
        import etb_gym.diagnose.refine as refine
        refine.refine = lambda nominal, final, steps, *r, **kw: (final, steps, None)
        args += ["--max-effects", "0"]
    opts = proof._parser().parse_args(args)
    with tempfile.TemporaryDirectory() as work:
        row, _ = proof.run_case(a.case, a.seed, opts, work)
    res, fpd, tpd = seen["res"], seen["file"].params_dict(), seen["truth"].params_dict()
    out = {"case": a.case, "seed": a.seed, "nameplate": a.nameplate, "verdict": row["verdict"],
           "calibration_only": a.calibration_only,
           "effects": row["effects"], "effect_size": row.get("effect_size"),
           "twin": row["heldout_rms_after"] / row["true_noise"], "cpu_s": row.get("cpu_s"),
           "rms_over_floor": row["rms_before"] / row["noise_floor"], "closed": row["closed"], "params": {}}
    se = res.nominal_fit.stderr()
    # the held-out miss of a model at the truth's own levels without the concealed effect (the calibration's trade
    # left out): how much of the calibrated model's miss is the effect itself
    nom_plant, nom_sensor = res.nominal_fit.spec.build(res.nominal_fit.x)
    hd = prepare([seen["held"]], 12.0)
    levels = seen["truth"].replace(effects=(), substeps=nom_plant.substeps)
    r = angle_residuals_deg(simulate(levels, nom_sensor, hd), hd)[0]
    out["heldout_truth_levels"] = float(np.sqrt(np.mean(r ** 2))) / row["true_noise"]
    out["heldout_calibrated"] = row["heldout_rms_before"] / row["true_noise"]
    fit_data = restart_view(res.data)
    xn, rss0, rss_n = with_prior(res.nominal_fit, fit_data, None)
    xp, _, rss_p = with_prior(res.nominal_fit, fit_data, a.prior_width)
    free_vals, prior_vals = res.nominal_fit.spec.values(xn), res.nominal_fit.spec.values(xp)
    out["prior"] = {"width": a.prior_width, "data_rss_reported": rss0, "data_rss_refit": rss_n,
                    "data_rss_with_prior": rss_p}
    for k, v in res.nominal_fit.values.items():
        if k in fpd:
            out["params"][k] = {"file": fpd[k], "truth": tpd.get(k), "calibrated": v, "stderr": se.get(k),
                                "truth_vs_file_pct": 100 * (tpd.get(k, float("nan")) / fpd[k] - 1),
                                "calibrated_vs_file_pct": 100 * (v / fpd[k] - 1),
                                "stderr_pct_of_file": 100 * se.get(k, float("nan")) / fpd[k],
                                "refit_vs_file_pct": 100 * (free_vals[k] / fpd[k] - 1),
                                "with_prior_vs_file_pct": 100 * (prior_vals[k] / fpd[k] - 1)}
    print(json.dumps(out, indent=1, default=float))
    if a.row:
        with open(a.row, "a") as fh:
            fh.write(json.dumps(out, default=float) + "\n")


if __name__ == "__main__":
    main()
