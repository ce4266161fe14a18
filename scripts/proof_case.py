"""Diagnose one proof case (family[@shape], seed) with the proof's settings and keep its output
(report.json, shapes.png, ...) in out/dev_<case>_<seed>/; prints the proof's row for it.

    python scripts/proof_case.py shaft_flux_loss@1 0 --duration 6
"""
import argparse
import json
from pathlib import Path

from etb_gym.diagnose import proof

KEYS = ("family", "effects", "verdict", "named", "outside_summary", "period_deg", "period_true_deg", "effect_size",
        "heldout_rms_before", "heldout_rms_after", "true_noise", "time_s", "cpu_s")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("case", help="proof family, optionally with a truth shape: NAME or NAME@K (K = 0, 1, 2)")
    ap.add_argument("seed", type=int, help="the proof's seed for this case")
    ap.add_argument("--duration", type=float, default=6.0, help="recording length [s] (default 6)")
    ap.add_argument("--nameplate", choices=("3B", "random"), default="3B",
                    help="the truth's nameplate: the default 3B, or a random one diagnosed from a plant file 10-20 %% off")
    ap.add_argument("--out", default="out", help="parent folder of the case's output folder (default out)")
    ap.add_argument("--verbose", action="store_true", help="print the diagnosis's log (the proof runs it quietly)")
    ap.add_argument("--row", help="append the row (all its fields, JSON) to this file")
    a = ap.parse_args(argv)
    if a.duration <= 0:
        ap.error(f"--duration = {a.duration} is invalid: expected a positive length in seconds")
    opts = proof._parser().parse_args(["--duration", str(a.duration), "--jobs", "1", "--nameplate", a.nameplate])
    work = Path(a.out) / ("dev_" + a.case.replace("@", "_s") + f"_{a.seed}")
    work.mkdir(parents=True, exist_ok=True)
    if a.verbose:
        quiet = proof.Options
        proof.Options = lambda **kw: quiet(**{**kw, "verbose": True})
    row, _ = proof.run_case(a.case, a.seed, opts, str(work))
    print(json.dumps({k: row.get(k) for k in KEYS}, indent=1))
    if a.row:
        with open(a.row, "a") as fh:
            fh.write(json.dumps({"case": a.case, "nameplate": a.nameplate, **row}, default=str) + "\n")


if __name__ == "__main__":
    main()
