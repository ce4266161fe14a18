"""Does a named family's twin miss the held-out recording by extrapolating its formula? (issue 15, round 14)

Takes the pickles that ``scripts/twin_coverage.py`` keeps per proof case (truth, both recordings, the exported
twin) and reports, in units of the noise the truth added:

  * the twin's held-out RMS as the diagnosis exported it, and after a round trip through a plant file
    (.toml and .json: the export must not change the twin);
  * the same twin with every family's total over angle (formula + its learned table, ``penalized.formula_profile``)
    held at its value at the edge of the angles the *training* recording visited (0.1 % / 99.9 % quantiles),
    formula and table replaced by one table of the same kind on a 0.5 deg grid: what ``penalized.hold_rows`` makes
    the refinement do, applied to a twin fitted without it.

    nice -n 10 .venv/bin/python scripts/twin_coverage.py --cases angle_dependent_friction@1:5:3B --work /tmp/tw \\
        --out /tmp/tw/rows.jsonl
    .venv/bin/python scripts/twin_extrapolation.py /tmp/tw/angle_dependent_friction_s1_5_3B.pkl
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import twin_coverage as TC  # noqa: E402

from etb_gym.diagnose import shapes as S  # noqa: E402
from etb_gym.diagnose import penalized as P  # noqa: E402
from etb_gym.plantfile import load_plant, save_plant  # noqa: E402


def held_beyond(twin, lo_deg: float, hi_deg: float):
    """``twin`` with each (formula, table over angle) pair replaced by one table holding their sum beyond
    [lo_deg, hi_deg]; (plant, ids of the families changed)."""
    maps = {getattr(e, "name", None): e for e in twin.effects}
    grid = np.radians(np.arange(0.0, 90.001, 0.5))
    drop, add, ids = set(), [], []
    for e in twin.effects:
        m = maps.get(f"{getattr(e, 'effect_id', '')}_map")
        if m is None or m.grid_field != "angle_rad" or len(m.value_fields) != 1:
            continue
        fixed = tuple((f, getattr(m.params, f)) for f in m.scalar_fields)
        term = S.MapTerm(m.name, "", type(m), grid, m.value_fields, 1.0, "", fixed)
        prof = P.formula_profile(e, term)
        if prof is None:
            continue
        total = prof + m.evaluate(grid)
        d = np.degrees(grid)
        total = np.where(d < lo_deg, np.interp(lo_deg, d, total), np.where(d > hi_deg, np.interp(hi_deg, d, total), total))
        add.append(term.component(total))
        drop |= {id(e), id(m)}
        ids.append(e.effect_id)
    return twin.replace(effects=tuple(x for x in twin.effects if id(x) not in drop) + tuple(add)), ids


def rms_over(plant, sensor, rec, sig) -> float:
    return float(np.sqrt(np.mean(TC._resid(plant, sensor, rec) ** 2))) / sig


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pickles", nargs="+", type=Path, help="twin_coverage.py's per-case pickles")
    a = ap.parse_args(argv)
    for pk in a.pickles:
        k = pickle.loads(pk.read_bytes())
        sig, tw, ts = k["row"]["true_noise"], k["twin"], k["twin_sensor"]
        row = {"case": pk.stem, "effects": k["row"]["effects"], "held_twin": rms_over(tw, ts, k["held"], sig)}
        with tempfile.TemporaryDirectory() as d:
            for suf in (".toml", ".json"):
                back = load_plant(save_plant(tw, Path(d) / f"twin{suf}"))
                row[f"held_reloaded{suf}"] = rms_over(back, ts, k["held"], sig)
        lo, hi = np.quantile(k["rec"].angle_deg, [0.001, 0.999])
        held, ids = held_beyond(tw, float(lo), float(hi))
        row.update(train_range_deg=[float(lo), float(hi)],
                   held_range_deg=[float(np.min(k["held"].angle_deg)), float(np.max(k["held"].angle_deg))],
                   families_held=ids, held_twin_held_beyond=rms_over(held, ts, k["held"], sig) if ids else None)
        print(json.dumps(row))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
