"""Where the proof's open-loop excitation puts the plate on random nameplates: share of the recording at the
open stop (within 1 deg of it), at the closed stop (within 0.5 deg), resting at limp-home (within 0.5 deg),
and the travel covered (5th-95th percentile of the reading, as a share of limp-home..open stop).

    python scripts/excitation_stops.py --nameplates 10 --duration 6 [--out rows.jsonl]

Recordings are made with ``synthetic.make_recording`` (open loop, 0.01 deg noise, 12-bit; the excitation
scaled to the recorded plant, ``nameplate=plant``, where the tree has it) on
``synthetic.random_nameplate(default_rng(1000 + k))`` for k < --nameplates, and on the default 3B plant; run it
on two trees (before/after a change of the excitation) and compare the printed tables.
"""
import argparse
import json
import math

import numpy as np

from etb_gym import make_plant
from etb_gym.diagnose.synthetic import make_recording, random_nameplate


def shares(plant, seed: int, duration: float) -> dict:
    import inspect
    kw = {"nameplate": plant} if "nameplate" in inspect.signature(make_recording).parameters else {}
    rec = make_recording(plant, np.random.default_rng(seed), duration_s=duration, noise_deg=0.01, **kw)
    y = rec.angle_deg
    lh, lo, hi = (math.degrees(v) for v in (plant.limp_home_rad, plant.angle_min_rad, plant.angle_max_rad))
    p5, p95 = np.percentile(y, [5, 95])
    return {"open_stop": float(np.mean(y > hi - 1.0)), "closed_stop": float(np.mean(y < lo + 0.5)),
            "limp_home": float(np.mean(np.abs(y - lh) < 0.5)), "travel": float((p95 - p5) / (hi - lh)),
            "max_deg": float(y.max()), "open_deg": hi, "limp_home_deg": lh,
            "stall_over_need": stall_ratio(plant)}


def stall_ratio(plant) -> float:
    """Stall torque c_M V / R over the torque the spring and the friction need at the open stop."""
    from etb_gym.controllers.model import NominalModel
    nom = NominalModel.from_plant(plant)
    need = nom.spring_torque_Nm(plant.angle_max_rad) + nom.coulomb_Nm
    return nom.supply_V / nom.volts_per_Nm / need


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], epilog=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--nameplates", type=int, default=10)
    ap.add_argument("--duration", type=float, default=6.0)
    ap.add_argument("--seeds", type=int, default=3, help="recordings per plant (rng seeds 0..N-1)")
    ap.add_argument("--out", default=None, help="also write the rows here (JSON lines)")
    a = ap.parse_args(argv)
    plants = [("3B", make_plant("3B"))] + [(f"random {k}", random_nameplate(np.random.default_rng(1000 + k)))
                                           for k in range(a.nameplates)]
    rows = []
    print("| plant | stall / need | open stop | closed stop | limp-home | travel 5-95 % |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name, p in plants:
        r = [shares(p, s, a.duration) for s in range(a.seeds)]
        m = {k: float(np.mean([x[k] for x in r])) for k in ("open_stop", "closed_stop", "limp_home", "travel")}
        rows.append({"plant": name, **m, "stall_over_need": r[0]["stall_over_need"]})
        print(f"| {name} | {r[0]['stall_over_need']:.1f} | {m['open_stop']:.0%} | {m['closed_stop']:.0%} | "
              f"{m['limp_home']:.0%} | {m['travel']:.2f} |")
    if a.out:
        with open(a.out, "w") as fh:
            fh.writelines(json.dumps(r) + "\n" for r in rows)


if __name__ == "__main__":
    main()
