"""How finely must a twin know the friction to predict a held-out recording? (issue 15, round 15)

Takes a pickle that ``scripts/twin_coverage.py`` keeps per proof case (truth, both recordings, the twin) and
replays both recordings (recorded voltage, open loop; as ``proof.score_heldout``) with the *truth* itself, at the
twin's integrator step, after one small change of one parameter at a time: the friction level (Coulomb and static
together), the static level alone, the spring's preload, the Stribeck speed, the bristle stiffness sigma0, the
viscous coefficient. RMS over the noise the truth added; the unchanged truth is the floor (about 1.0).

    nice -n 10 .venv/bin/python scripts/twin_coverage.py --cases angle_dependent_friction@1:5:3B --work /tmp/tw \\
        --out /tmp/tw/rows.jsonl
    .venv/bin/python scripts/friction_sensitivity.py /tmp/tw/angle_dependent_friction_s1_5_3B.pkl --out ROWS
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import twin_coverage as TC  # noqa: E402


def changes(pd: dict) -> list:
    """(label, {param: value}) for each one-parameter change (only those the plant has)."""
    out = [("none", {})]
    for d in (-1e-3, 1e-3):
        if "friction.static_Nm" in pd:
            out.append((f"friction level (Coulomb and static) {d * 1e3:+.0f} mN m",
                        {"friction.coulomb_Nm": pd["friction.coulomb_Nm"] + d, "friction.static_Nm": pd["friction.static_Nm"] + d}))
            out.append((f"static level only {d * 1e3:+.0f} mN m", {"friction.static_Nm": pd["friction.static_Nm"] + d}))
        if "spring.preload_Nm" in pd:
            out.append((f"spring preload {d * 1e3:+.0f} mN m", {"spring.preload_Nm": pd["spring.preload_Nm"] + d}))
    for f in (0.8, 1.25):
        for key, name in (("friction.stribeck_velocity_rad_s", "Stribeck speed"),
                          ("friction.bristle_stiffness_Nm_per_rad", "bristle stiffness sigma0"),
                          ("friction.viscous_Nm_s_per_rad", "viscous coefficient")):
            if pd.get(key):
                out.append((f"{name} x{f:g}", {key: pd[key] * f}))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pickle", help="a case pickle of scripts/twin_coverage.py")
    ap.add_argument("--out", help="rows (JSON lines)")
    a = ap.parse_args(argv)
    k = pickle.loads(Path(a.pickle).read_bytes())
    sig = k["row"]["true_noise"]
    truth = k["truth"].replace(substeps=k["twin"].substeps)
    rows = []
    for label, over in changes(truth.params_dict()):
        p = truth.with_params(over) if over else truth
        r = {"case": Path(a.pickle).stem, "change": label,
             **{tag: float(np.sqrt(np.mean(TC._resid(p, k["twin_sensor"], k[key]) ** 2))) / sig
                for tag, key in (("held", "held"), ("train", "rec"))}}
        rows.append(r)
        print(f"{label:45s} held-out {r['held']:6.2f}x  training replay {r['train']:6.2f}x", flush=True)
    if a.out:
        Path(a.out).write_text("".join(json.dumps(r) + "\n" for r in rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
