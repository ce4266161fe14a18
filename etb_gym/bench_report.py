"""Tables, target checks and response plots of the controller benchmark (see etb_gym/benchmark.py).

Targets (issue 4), checked on the nominal variant for every controller, and across the robustness grid:

    T1 step_10_80: settling (2 % band) <= 80 ms and overshoot <= 2 %
    T2 0.5 deg steps (limp-home and 40 deg, both directions): within +-0.1 deg by 50 ms and staying
    T3 steady-state error <= 0.1 deg (every step scenario)
    T4 no sustained limit cycle above 0.05 deg (half peak-to-peak over the last 0.1 s, step scenarios)
    T5 robustness grid: stable in every variant, and settling <= 2 x nominal (step scenarios)
"""
from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np

from .io import write_atomic

from .benchmark import SCENARIOS, SMALL_STEP_SCENARIOS, VARIANTS, Job, load_trace

TABLE_COLUMNS = (("settling_time_s", "settle [ms]", 1e3), ("rise_time_s", "rise [ms]", 1e3),
                 ("overshoot_pct", "overshoot [%]", 1.0), ("steady_state_error_deg", "SSE [deg]", 1.0),
                 ("limit_cycle_deg", "LC [deg]", 1.0), ("rms_error_deg", "RMS [deg]", 1.0),
                 ("peak_current_A", "peak i [A]", 1.0), ("duty_total_variation", "duty TV", 1.0))


def _mean(vals):
    v = [x for x in vals if not (isinstance(x, float) and math.isnan(x))]
    return float(np.mean(v)) if v else float("nan")


def _worst(vals):
    if any(isinstance(x, float) and math.isnan(x) for x in vals):
        return float("nan")
    return float(np.max(vals)) if vals else float("nan")


def aggregate(rows):
    """{(env, controller, scenario, variant): {metric: mean over seeds, "stable": all, "n": seeds}}.
    Settling time is the worst seed (NaN if any seed never settled)."""
    groups = defaultdict(list)
    for r in rows:
        groups[(r["env"], r["controller"], r["scenario"], r["variant"])].append(r)
    out = {}
    for k, rs in groups.items():
        agg = {c: _mean([r[c] for r in rs]) for c, _, _ in TABLE_COLUMNS}
        agg["settling_time_s"] = _worst([r["settling_time_s"] for r in rs])
        agg["stable"] = all(r["stable"] for r in rs)
        agg["n"] = len(rs)
        out[k] = agg
    return out


def _f(v, scale=1.0, nd=3):
    if isinstance(v, float) and math.isnan(v):
        return "-"
    x = v * scale
    return f"{x:.{nd}g}" if abs(x) < 1000 else f"{x:.0f}"


def check_targets(rows):
    """[(env, controller, target id, description, measured text, passed or None)] in table order."""
    agg = aggregate(rows)
    out = []
    envs = sorted({r["env"] for r in rows})
    ctrls = list(dict.fromkeys(r["controller"] for r in rows))
    for env in envs:
        for c in ctrls:
            def get(sc, var="nominal"):
                return agg.get((env, c, sc, var))

            a = get("step_10_80")
            if a is not None:
                ok = a["settling_time_s"] <= 0.080 and a["overshoot_pct"] <= 2.0
                out.append((env, c, "T1", "10->80 deg: settle <= 80 ms (2 % band), overshoot <= 2 %",
                            f"{_f(a['settling_time_s'], 1e3)} ms, {_f(a['overshoot_pct'])} %", bool(ok)))
            small = [(s, get(s)) for s in SMALL_STEP_SCENARIOS if get(s) is not None]
            if small:
                worst = max(x["settling_time_s"] if not math.isnan(x["settling_time_s"]) else math.inf for _, x in small)
                out.append((env, c, "T2", "0.5 deg steps: within +-0.1 deg by 50 ms and stay",
                            "worst " + (f"{worst * 1e3:.0f} ms" if math.isfinite(worst) else "never"),
                            bool(worst <= 0.050)))
            steps = [(s, get(s)) for s, sc in SCENARIOS.items() if sc.kind == "step" and get(s) is not None]
            if steps:
                sse = max(x["steady_state_error_deg"] for _, x in steps)
                out.append((env, c, "T3", "steady-state error <= 0.1 deg", f"worst {sse:.3f} deg", bool(sse <= 0.1)))
                lc = max(x["limit_cycle_deg"] for _, x in steps)
                out.append((env, c, "T4", "no limit cycle above 0.05 deg", f"worst {lc:.3f} deg", bool(lc <= 0.05)))
            others = sorted({k[3] for k in agg if k[0] == env and k[1] == c and k[3] != "nominal"})
            if others:
                bad = []
                for v in others:
                    for s, sc in SCENARIOS.items():
                        x, n = get(s, v), get(s)
                        if x is None:
                            continue
                        if not x["stable"]:
                            bad.append(f"{s}/{v} unstable")
                        elif sc.kind == "step" and n is not None:
                            ts, tn = x["settling_time_s"], n["settling_time_s"]
                            if math.isnan(ts) or (not math.isnan(tn) and ts > 2 * max(tn, 0.005)):
                                bad.append(f"{s}/{v} settles {_f(ts, 1e3)} ms vs {_f(tn, 1e3)} nominal")
                out.append((env, c, "T5", "robustness grid: stable, settling <= 2x nominal",
                            ("all " + str(len(others)) + " variants ok") if not bad else
                            f"{len(bad)} misses, e.g. " + "; ".join(bad[:3]), not bad))
    return out


def markdown(rows, title="Controller benchmark") -> str:
    """The benchmark report: targets, nominal table, robustness table."""
    agg = aggregate(rows)
    lines = [f"# {title}", ""]
    envs = sorted({r["env"] for r in rows})
    seeds = sorted({r["seed"] for r in rows})
    lines.append(f"envs {', '.join(envs)}; seeds {seeds}; metrics on the true plate angle, means over seeds "
                 "(settling: worst seed; `-` = not reached / not applicable).")
    lines += ["", "## Targets (nominal plant unless stated)", "", "| env | controller | target | measured | result |",
              "|---|---|---|---|---|"]
    for env, c, tid, desc, meas, ok in check_targets(rows):
        lines.append(f"| {env} | {c} | {tid}: {desc} | {meas} | {'pass' if ok else '**FAIL**'} |")
    head = "| env | controller | scenario | " + " | ".join(h for _, h, _ in TABLE_COLUMNS) + " |"
    sep = "|---" * (3 + len(TABLE_COLUMNS)) + "|"
    lines += ["", "## Nominal plant", "", head, sep]
    for (env, c, s, v), a in sorted(agg.items(), key=lambda kv: (kv[0][0], kv[0][1], list(SCENARIOS).index(kv[0][2]))):
        if v == "nominal":
            lines.append(f"| {env} | {c} | {s} | " + " | ".join(_f(a[k], sc) for k, _, sc in TABLE_COLUMNS) + " |")
    variants = [v for v in VARIANTS if v != "nominal" and any(k[3] == v for k in agg)]
    if variants:
        lines += ["", "## Robustness grid: settling [ms] (`x` unstable, `-` never settled; tracking scenarios: RMS error [deg])",
                  "", "| env | controller | scenario | " + " | ".join(variants) + " |", "|---" * (3 + len(variants)) + "|"]
        keys = sorted({k[:3] for k in agg}, key=lambda k: (k[0], k[1], list(SCENARIOS).index(k[2])))
        for env, c, s in keys:
            cells = []
            for v in variants:
                a = agg.get((env, c, s, v))
                if a is None:
                    cells.append(" ")
                elif not a["stable"]:
                    cells.append("x")
                elif SCENARIOS[s].kind == "step":
                    cells.append(_f(a["settling_time_s"], 1e3))
                else:
                    cells.append(_f(a["rms_error_deg"]))
            lines.append(f"| {env} | {c} | {s} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_text(path, text: str) -> None:
    write_atomic(path, text)


def plot_scenarios(out_dir, rows, env_id=None, seed=None, variant="nominal") -> list[Path]:
    """One PNG per scenario: angle vs reference (top) and duty (bottom) of every controller."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    traces = out / "traces"
    files = []
    envs = sorted({r["env"] for r in rows}) if env_id is None else [env_id]
    for env in envs:
        sel = [r for r in rows if r["env"] == env and r["variant"] == variant]
        if not sel:
            continue
        sd = min(r["seed"] for r in sel) if seed is None else seed
        ctrls = list(dict.fromkeys(r["controller"] for r in sel))
        for s in dict.fromkeys(r["scenario"] for r in sel):
            got = [(c, load_trace(traces, Job(env, c, s, variant, sd))) for c in ctrls]
            got = [(c, t) for c, t in got if t is not None]
            if not got:
                continue
            sc = SCENARIOS[s]
            fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 5), sharex=True, height_ratios=(2, 1))
            t0 = sc.step_at_s - 0.02 if sc.kind == "step" else 0.0
            for c, tr in got:
                k = tr["t_s"] >= t0
                ax1.plot((tr["t_s"][k] - sc.step_at_s) * 1e3, tr["angle_deg"][k], label=c, lw=1.2)
                ax2.plot((tr["t_s"][k] - sc.step_at_s) * 1e3, tr["duty"][k], lw=0.8, label=c)
            tr = got[0][1]
            k = tr["t_s"] >= t0
            ax1.plot((tr["t_s"][k] - sc.step_at_s) * 1e3, tr["reference_deg"][k], "k--", lw=0.8, label="reference")
            if sc.kind == "step":
                band = max(0.02 * abs(sc.step_to_deg - sc.step_from_deg), 0.1)
                ax1.axhspan(sc.step_to_deg - band, sc.step_to_deg + band, color="0.85", zorder=0,
                            label="settling band")
            ax1.set_ylabel("angle [deg]")
            ax1.set_title(f"{env} {s} ({variant}, seed {sd}): {sc.description}", fontsize=9)
            ax1.legend(fontsize=8, loc="best")
            ax1.grid(alpha=0.3)
            ax2.set_ylabel("duty")
            ax2.set_xlabel("time from step [ms]" if sc.kind == "step" else "time from start of profile [ms]")
            ax2.grid(alpha=0.3)
            fig.tight_layout()
            p = out / f"response_{env}_{s}.png"
            try:
                write_atomic(p, lambda fh: fig.savefig(fh, dpi=90, format="png"))
            finally:
                plt.close(fig)
            files.append(p)
    return files
