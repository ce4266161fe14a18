"""Per-cell table of a controller's 0.5 deg steps on the robustness grid: settling / the variant's bound,
steady-state error, overshoot, first entry into the band, and (ptos) the self-tuned friction and spring levels
at the step and at the end. The diagnosis tool of the small-step misses (docs/controllers.md).

    python scripts/small_step_cells.py --variants friction_-50 friction_+50 springs_-20 springs_+20 --seeds 0 1
    python scripts/small_step_cells.py --kw '{"innovation_gain": 0}'      # a variant of ptos side by side
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from etb_gym.bench_scenarios import SCENARIOS, SMALL_STEP_SCENARIOS, VARIANTS, step_band_deg  # noqa: E402


def run_cell(args):
    env_id, ctrl_name, kw, scenario, variant, seed, bounds = args
    import numpy as np

    from etb_gym.benchmark import Job, build_controller, metrics, simulate

    ctrl = build_controller(ctrl_name, env_id, kw)
    levels = []
    act = ctrl.act

    def traced(obs):                                   # record the self-tuned levels each period (ptos)
        d = act(obs)
        st = getattr(ctrl, "tuning", None)
        levels.append((st.friction_level, st.spring_level) if st is not None else (math.nan, math.nan))
        return d

    ctrl.act = traced
    job = Job(env_id, ctrl_name, scenario, variant, seed)
    trace, _ = simulate(job, ctrl)
    sc = SCENARIOS[scenario]
    row = metrics(trace, sc)
    dt = trace["t_s"][1] - trace["t_s"][0]
    k0 = int(round(sc.step_at_s / dt))
    phi = np.asarray(trace["angle_deg"])[k0:]
    inside = np.nonzero(np.abs(phi - sc.step_to_deg) <= step_band_deg(sc))[0]
    lv = np.asarray(levels)
    b = bounds.get(f"{env_id}|{scenario}|{variant}", {}).get("bound_s", math.nan)
    return dict(scenario=scenario, variant=variant, seed=seed, settle_ms=row["settling_time_s"] * 1e3,
                bound_ms=b * 1e3, ratio=row["settling_time_s"] / b if b else math.nan,
                first_in_ms=float(inside[0] * dt * 1e3) if inside.size else math.nan,
                overshoot_pct=row["overshoot_pct"], sse_deg=row["steady_state_error_deg"],
                lc_deg=row["limit_cycle_deg"], start_deg=row["step_start_deg"],
                theta_f_step=float(lv[k0 - 1, 0]), theta_s_step=float(lv[k0 - 1, 1]),
                theta_f_end=float(lv[-1, 0]), theta_s_end=float(lv[-1, 1]),
                min_after_ms=float(np.argmin(np.abs(phi - sc.step_to_deg)) * dt * 1e3))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--env", default="ETB-3B-v0")
    ap.add_argument("--controller", default="ptos")
    ap.add_argument("--kw", default="{}", help="controller keyword arguments as JSON (default {})")
    ap.add_argument("--scenarios", nargs="+", default=list(SMALL_STEP_SCENARIOS))
    ap.add_argument("--variants", nargs="+", default=["nominal", "friction_-50", "friction_+50", "springs_-20",
                                                      "springs_+20"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    ap.add_argument("--bounds", default="out/bounds.json", help="bounds cache (computed and added when missing)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", default=None, help="write the rows to this JSON file")
    a = ap.parse_args(argv)
    try:
        kw = json.loads(a.kw)
    except ValueError as exc:
        ap.error(f"--kw {a.kw!r} is not JSON: {exc}")
    if not isinstance(kw, dict):
        ap.error(f"--kw {a.kw!r} is invalid: expected a JSON object of keyword arguments")
    for s in a.scenarios:
        if s not in SCENARIOS or SCENARIOS[s].kind != "step":
            ap.error(f"--scenarios: {s!r} is not a step scenario")
    for v in a.variants:
        if v not in VARIANTS:
            ap.error(f"--variants: unknown variant {v!r}; valid are {list(VARIANTS)}")

    from etb_gym.bench_bounds import BoundJob, bound_fingerprint, compute_bound, read_bounds, write_bounds

    bounds = read_bounds(a.bounds)
    need = [BoundJob(a.env, s, v) for s in a.scenarios for v in a.variants]
    missing = [j for j in need if bounds.get(j.key, {}).get("fingerprint") != bound_fingerprint(j)]
    cells = [(a.env, a.controller, kw, s, v, seed, None) for v in a.variants for s in a.scenarios for seed in a.seeds]
    with ProcessPoolExecutor(a.workers) as ex:
        for j, b in zip(missing, ex.map(compute_bound, missing)):
            bounds[j.key] = b
        if missing:
            Path(a.bounds).parent.mkdir(parents=True, exist_ok=True)
            write_bounds(a.bounds, bounds)
        small = {k: {"bound_s": v["bound_s"]} for k, v in bounds.items()}
        rows = list(ex.map(run_cell, [c[:-1] + (small,) for c in cells]))
    hdr = ("scenario", "variant", "seed", "settle_ms", "bound_ms", "ratio", "first_in_ms", "overshoot_pct",
           "sse_deg", "lc_deg", "theta_f_step", "theta_s_step", "theta_f_end", "theta_s_end")
    print("| " + " | ".join(hdr) + " |")
    print("|" + "---|" * len(hdr))
    for r in rows:
        print("| " + " | ".join(f"{r[h]:.3g}" if isinstance(r[h], float) else str(r[h]) for h in hdr) + " |")
    ok = sum(1 for r in rows if r["ratio"] <= 2.0 + 1e-9 and r["sse_deg"] <= 0.1)
    print(f"\nwithin 2x own bound and SSE <= 0.1 deg: {ok} / {len(rows)}; "
          f"worst ratio {max(r['ratio'] if not math.isnan(r['ratio']) else math.inf for r in rows):.3g}")
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
