"""Where a friction twin's held-out error comes from: its levels against the truth's, and the knife edge.

Takes the pickles that ``scripts/twin_coverage.py --work DIR`` keeps per proof case (truth, both recordings, the
twin, the final fit and the data) and prints, per case (round 26, docs/diagnosis-history.md, round 26 p26friction):

  * the twin's nominal levels (Coulomb, static, spring preload and rate) minus the truth's, with the standard
    error the report gives them (report.json ``calibrated_parameters``),
  * the held-out error by the plate's speed (from the readings): time share, share of the squared error, mean,
  * replays of both recordings (recorded voltage, as ``proof.score_heldout``) with the twin's Coulomb level
    (static following) or preload moved by +-1 mN m, and with the truth's spring / Coulomb level put in,
  * the knife edge: the *truth* replayed with its Coulomb level (static following) moved by +-0.5 mN m,
  * with ``--refit``: the final model refitted on the continuous replay of the training recording (the whole
    refit of ``run.polish_replay``, whatever its guard decided) and its held-out error.

Analysis only: the truth is read for the comparison, never by the diagnosis.

    nice -n 5 .venv/bin/python scripts/twin_coverage.py --cases stribeck_friction@2:31:3B --work out/cov
    nice -n 5 .venv/bin/python scripts/friction_levels.py out/cov/stribeck_friction_s2_31_3B.pkl --refit
"""
from __future__ import annotations

import argparse
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import twin_coverage as TC  # noqa: E402

LEVELS = ("friction.coulomb_Nm", "friction.static_Nm", "spring.preload_Nm", "spring.rate_Nm_per_rad")
SPEED_BANDS = ((0.0, 0.03), (0.03, 0.3), (0.3, 3.0), (3.0, np.inf))     # |omega| [rad/s]


def _rms(plant, sensor, rec, sig) -> tuple[float, np.ndarray]:
    r = TC._resid(plant, sensor, rec)
    return float(np.sqrt(np.mean(r ** 2))) / sig, r


def _level_shift(pd: dict, d: float) -> dict:
    out = {"friction.coulomb_Nm": pd["friction.coulomb_Nm"] + d}
    if "friction.static_Nm" in pd:
        out["friction.static_Nm"] = pd["friction.static_Nm"] + d
    return out


def analyse(path: Path, refit: bool) -> None:
    from scipy.ndimage import uniform_filter1d
    k = pickle.loads(path.read_bytes())
    sig, truth, twin, ts = k["row"]["true_noise"], k["truth"], k["twin"], k["twin_sensor"]
    tp, wp = truth.params_dict(), twin.params_dict()
    cal = k["report"]["calibrated_parameters"]
    print(f"== {path.stem}: {k['row']['verdict']}, {k['row']['effects']}, held-out twin "
          f"{k['row']['heldout_rms_after'] / sig:.2f}x")
    for p in LEVELS:
        if p in tp and p in wp:
            se = (cal.get(p) or {}).get("stderr")
            print(f"  {p:28s} twin - truth {1e3 * (wp[p] - tp[p]):+7.2f} mN m   reported stderr "
                  + ("-" if se is None else f"{1e3 * se:.2f} mN m"))
    held, rec = k["held"], k["rec"]
    h0, rh = _rms(twin, ts, held, sig)
    t0, _ = _rms(twin, ts, rec, sig)
    print(f"  twin: held-out {h0:.2f}x, training replay {t0:.2f}x")
    w = np.abs(uniform_filter1d(np.gradient(np.radians(held.angle_deg), held.t_s), 11))
    for lo, hi in SPEED_BANDS:
        m = (w >= lo) & (w < hi)
        if m.any():
            print(f"    |omega| {lo:g}-{hi:g} rad/s: time {m.mean():4.0%}, squared error {np.sum(rh[m] ** 2) / np.sum(rh ** 2):4.0%}, "
                  f"mean {np.mean(rh[m]) / sig:+.1f}x")

    def rep(label, plant, over):
        p = plant.with_params(over) if over else plant
        print(f"    {label:40s} held-out {_rms(p, ts, held, sig)[0]:7.2f}x  training replay {_rms(p, ts, rec, sig)[0]:7.2f}x")
    for d in (-1e-3, 1e-3):
        rep(f"twin, Coulomb {d * 1e3:+.0f} mN m", twin, _level_shift(wp, d))
    for d in (-1e-3, 1e-3):
        rep(f"twin, preload {d * 1e3:+.0f} mN m", twin, {"spring.preload_Nm": wp["spring.preload_Nm"] + d})
    rep("twin with the truth's spring", twin, {p: tp[p] for p in LEVELS[2:]})
    rep("twin with the truth's Coulomb level", twin, _level_shift(wp, tp["friction.coulomb_Nm"] - wp["friction.coulomb_Nm"]))
    tr = truth.replace(substeps=twin.substeps)
    rep("truth", tr, {})
    for d in (-0.5e-3, 0.5e-3):
        rep(f"truth, Coulomb {d * 1e3:+.1f} mN m", tr, _level_shift(tp, d))
    if refit:
        from etb_gym.diagnose import fit as F
        from etb_gym.diagnose.model import replay_view
        fr = k["final_fit"]
        out = F.fit(fr.spec, replay_view(k["data"]), fr.x, max_nfev=30)
        plant, sensor = fr.spec.build(out.x)
        pd = plant.params_dict()
        print(f"    replay refit: held-out {_rms(plant.replace(substeps=twin.substeps), sensor, held, sig)[0]:.2f}x; "
              + ", ".join(f"{p.split('.')[1]} {1e3 * (pd[p] - tp[p]):+.2f}" for p in LEVELS if p in tp and p in pd)
              + " mN m against the truth")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pickles", nargs="+", help="case pickles of scripts/twin_coverage.py --work")
    ap.add_argument("--refit", action="store_true", help="also refit the final model on the training replay")
    a = ap.parse_args(argv)
    for p in a.pickles:
        analyse(Path(p), a.refit)
    return 0


if __name__ == "__main__":
    sys.exit(main())
