"""One proof case (family[@shape], seed) diagnosed with the proof's settings, its output kept in out/dev_<case>/
(report.json, shapes.png, ...); prints the row. Usage: python scripts/proof_case.py FAMILY[@K] SEED [DURATION_S]"""
import sys, json, argparse, tempfile
from pathlib import Path
from etb_gym.diagnose import proof
a = proof._parser().parse_args(["--duration", sys.argv[3] if len(sys.argv) > 3 else "6", "--jobs", "1"])
fam, seed = sys.argv[1], int(sys.argv[2])
work = Path("out/dev_" + fam.replace("@", "_s") + f"_{seed}")
work.mkdir(parents=True, exist_ok=True)
row, outdir = proof.run_case(fam, seed, a, str(work))
print(json.dumps({k: row.get(k) for k in ("family", "effects", "verdict", "named", "outside_summary", "period_deg",
      "period_true_deg", "effect_size", "heldout_rms_before", "heldout_rms_after", "true_noise", "time_s")}, indent=1))
