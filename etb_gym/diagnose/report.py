"""Say it: report.json (contract: /work/shared/diagnosis-report.md, docs/diagnosis.md), report.md, PNG
residual plots before/after (over time and per regime), calibrated_plant.toml and a terminal summary."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from ..io import write_atomic
from ..plantfile import save_plant
from . import disturbance as D
from . import locate as L
from .candidates import CANDIDATES
from .model import angle_residuals_deg, simulate
from .result import QUANT_K, RMS_K, SCHEMA, Result, current_mismatch, significant_mismatch


FIGURES = ("residual_time.png", "residual_regimes.png", "angle_fit.png", "shapes.png")
REPORT_FILES = ("report.json", "report.md", "calibrated_plant.toml") + FIGURES


def _rms(x) -> float:
    return float(math.sqrt(np.mean(np.concatenate(x) ** 2))) if len(x) else 0.0


def _regimes(data, base, res, plant):
    lh = math.degrees(base.limp_home_rad)
    stops = (math.degrees(base.angle_min_rad), math.degrees(base.angle_max_rad)) if base.stops else (0.0, 90.0)
    pred = simulate(plant[0], plant[1], data) if plant is not None else None
    tables = []
    regs_all = []
    for k, rd in enumerate(data.recs):
        cur = rd.rec.current_A if rd.rec.current_A is not None else (pred[k][1] if pred else None)
        regs = L.regimes(rd.rec, lh, cur, stops)
        regs_all.append(regs)
        tables.append(L.regime_table(rd.rec, res[k], regs, rd.noise_deg))
    return tables, regs_all


def _merge_tables(tables):
    """Pool the per-recording regime tables (RMS weighted by samples)."""
    pooled = {}
    for tab in tables:
        for row in tab:
            p = pooled.setdefault(row["regime"], {"regime": row["regime"], "samples": 0, "ss": 0.0, "sum": 0.0,
                                                  "significant": False})
            p["samples"] += row["samples"]
            p["ss"] += row["rms_deg"] ** 2 * row["samples"]
            p["sum"] += row["mean_deg"] * row["samples"]
            p["significant"] |= row["significant"]
    out = []
    for p in pooled.values():
        out.append({"regime": p["regime"], "samples": p["samples"], "rms_deg": math.sqrt(p["ss"] / p["samples"]),
                    "mean_deg": p["sum"] / p["samples"], "significant": p["significant"]})
    return out


def _where(before, after, top=2):
    b = {r["regime"]: r for r in before}
    gains = []
    for r in after:
        if r["regime"] in b and b[r["regime"]]["significant"]:
            gains.append((b[r["regime"]]["rms_deg"] - r["rms_deg"], r["regime"]))
    gains.sort(reverse=True)
    return [g for d, g in gains[:top] if d > 0] or ["throughout"]


def _effects(data, base, nominal, final, steps, res0, opts) -> list:
    """One entry per accepted step (in order: where it helped, its parameters, what it gained), and the sensor's
    quantization when the readings lie on a grid coarser than the resolution assumed."""
    effects = []
    prev_res = res0
    errs = final.stderr()
    vals = final.values
    for st in steps:
        r_new = angle_residuals_deg(simulate(*st.fit.spec.build(st.fit.x), data), data)
        t_prev = _merge_tables(_regimes(data, base, prev_res, None)[0])
        t_new = _merge_tables(_regimes(data, base, r_new, None)[0])
        c = CANDIDATES[st.id]
        params = {}
        for p in c.fit:
            key = f"{c.id}.{p.name}"
            params[p.name] = {"value": vals[key], "stderr": errs[key], "unit": p.unit}
        effects.append({"id": c.id, "family": c.family, "description": c.description,
                        "where": _where(t_prev, t_new), "parameters": params,
                        "rms_gain_deg": _rms(prev_res) - _rms(r_new), "delta_bic": st.dbic,
                        "heldout_gain": st.cv_gain,
                        **({"discrimination": st.discrimination} if getattr(st, "discrimination", None) else {})})
        prev_res = r_new
    quant = max(rd.resolution_deg for rd in data.recs)
    if "sensor_quantization" in opts.candidates and quant > QUANT_K * opts.sensor_resolution_deg:
        effects.append({"id": "sensor_quantization", "family": "sensing",
                        "description": CANDIDATES["sensor_quantization"].description,
                        "where": ["every sample (the readings lie on a grid)"],
                        "parameters": {"resolution_deg": {"value": quant, "stderr": 0.0, "unit": "deg"}},
                        "rms_gain_deg": 0.0, "assumed_resolution_deg": opts.sensor_resolution_deg})
    return effects


def _unexplained(data, res1, tab1) -> list:
    """Per recording: where the final model's residual is still significant (windows, regimes, description)."""
    unexplained = []
    for rd, r, tab in zip(data.recs, res1, tab1):
        wins = L.windows(rd.rec.t_s, r, rd.noise_deg, rd.tol_deg)
        mask = np.zeros(r.size, bool)
        for a, b in wins:
            mask |= (rd.rec.t_s >= a) & (rd.rec.t_s <= b)
        sig_regs = sorted([row for row in tab if row["significant"]], key=lambda row: -row["rms_deg"])
        where = ", ".join(row["regime"] for row in sig_regs[:2]) or "throughout"
        rms = float(math.sqrt(np.mean(r[mask] ** 2))) if mask.any() else float(math.sqrt(np.mean(r ** 2)))
        unexplained.append({"recording": rd.rec.name, "where": where, "rms_deg": rms,
                            "windows_s": wins, "description": L.describe(rd.rec, r, None, rd.noise_deg, mask)})
    return unexplained


def assemble(recs, data, base, nominal, final, steps, res0, res1, plant, sensor, opts, elapsed, ref0=None):
    """The Result and its report.json dict. ``ref0``: the nominal model's closed-loop Structures
    (disturbance.persistent_mismatch; computed here if None), the yardstick of every significance test."""

    names = [r.name for r in recs]
    model0 = nominal.spec.build(nominal.x)
    tab0, regs = _regimes(data, base, res0, model0)
    tab1, _ = _regimes(data, base, res1, (plant, sensor))
    before, after = _merge_tables(tab0), _merge_tables(tab1)
    if ref0 is None:                              # a closed loop: current, steady motion (the yardstick)
        ref0 = D.persistent_mismatch(data, *model0)
    cur0 = current_mismatch(data, *model0)        # open loop: the replayed current's miss, nominal and final
    sig0 = significant_mismatch(data, res0, *model0, ref=ref0, current_ref=cur0)
    sig1 = significant_mismatch(data, res1, plant, sensor, ref=ref0, current_ref=cur0)
    windows = {rd.rec.name: L.windows(rd.rec.t_s, r, rd.noise_deg, rd.tol_deg) for rd, r in zip(data.recs, res0)}
    effects = _effects(data, base, nominal, final, steps, res0, opts)
    quant = max(rd.resolution_deg for rd in data.recs)
    fitted = [e for e in effects if e["id"] != "sensor_quantization"]
    if not sig0:
        verdict = "explained" if effects else "match"
    elif fitted:
        verdict = "partly_explained" if sig1 else "explained"
    else:
        verdict = "unexplained"
    unexplained = _unexplained(data, res1, tab1) if sig1 else []
    tests = []
    for rd, r0, r1 in zip(data.recs, res0, res1):
        x0, bound = L.input_xcorr(r0, rd.rec.voltage_V)
        x1, _ = L.input_xcorr(r1, rd.rec.voltage_V)
        tests.append({"recording": rd.rec.name, "ljung_box_p_before": L.ljung_box(r0 / rd.noise_deg),
                      "ljung_box_p_after": L.ljung_box(r1 / rd.noise_deg), "input_xcorr_before": x0,
                      "input_xcorr_after": x1, "input_xcorr_bound_99": bound})
    nerr = nominal.stderr()
    calibrated = {n: {"value": v, "stderr": final.stderr()[n], "nominal_fit": nominal.values[n],
                      "unit": p.unit} for n, v, (_, p) in zip(final.spec.names, final.spec.values(final.x).values(),
                                                                final.spec.params) if _ == "nominal"}
    report = {
        "schema": SCHEMA,
        "model": base.model or "custom",
        "recordings": names,
        "verdict": verdict,
        "rms_before_deg": _rms(res0),
        "rms_after_deg": _rms(res1),
        "noise_floor_deg": data.noise_deg,
        "mismatch_windows_s": windows,
        "effects": effects,
        "unexplained": unexplained,
        "calibrated_plant": "calibrated_plant.toml",
        "calibrated_parameters": calibrated,
        "sensor": {"offset_deg": sensor.offset_deg, "gain": sensor.gain, "delay_s": sensor.delay_s,
                   "resolution_deg": quant, **sensor.section_maps()},
        "regimes_before": before,
        "regimes_after": after,
        "tests": tests,
        "integrator_substeps": int(plant.substeps),
        "elapsed_s": elapsed,
    }
    if any(x is not None for x in cur0):          # the replayed current's RMS miss over its noise (result.current_mismatch)
        cur1 = current_mismatch(data, plant, sensor)
        report["current_rms_over_noise"] = {rd.rec.name: {"before": a, "after": b}
                                            for rd, a, b in zip(data.recs, cur0, cur1) if a is not None}
    return Result(report, data, nominal, final, res0, res1, tab0, tab1, plant, sensor, elapsed)


# ------------------------------------------------------------------------------------------ writing
def _atomic_text(path: Path, text: str):
    write_atomic(path, text)


def _json_safe(o):
    if isinstance(o, dict):
        return {k: _json_safe(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_json_safe(v) for v in o]
    if isinstance(o, (np.floating, float)):
        return float(o) if math.isfinite(o) else None
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    return o


def _figure(figsize):
    """A figure on its own Agg canvas: no pyplot state, no backend switch for the caller's process."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    FigureCanvasAgg(fig)
    return fig


def plots(result, out: Path) -> list[str]:
    files = []
    data = result.data
    n = len(data.recs)
    fig = _figure((10, 2.8 * n))
    axes = fig.subplots(n, 1, squeeze=False)
    for ax, rd, r0, r1 in zip(axes[:, 0], data.recs, result.residual_before, result.residual_after):
        t = rd.rec.t_s
        for a, b in result.report["mismatch_windows_s"][rd.rec.name]:
            ax.axvspan(a, b, color="orange", alpha=0.2, lw=0)
        ax.plot(t, r0, lw=0.6, label="calibrated nominal model")
        ax.plot(t, r1, lw=0.6, label="with the added effects")
        s = rd.noise_deg
        ax.axhline(3 * s, color="k", ls=":", lw=0.8)
        ax.axhline(-3 * s, color="k", ls=":", lw=0.8, label="3x noise floor")
        ax.set_title(f"{rd.rec.name}: simulated minus recorded angle (shaded: mismatch windows)", fontsize=9)
        ax.set_ylabel("residual [deg]")
        ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    p = out / "residual_time.png"
    write_atomic(p, lambda fh: fig.savefig(fh, dpi=110, format="png"))
    files.append(p.name)

    before = {r["regime"]: r for r in result.report["regimes_before"]}
    after = {r["regime"]: r for r in result.report["regimes_after"]}
    keys = list(before)
    fig = _figure((8, 0.32 * len(keys) + 1.2))
    ax = fig.subplots()
    y = np.arange(len(keys))
    ax.barh(y - 0.2, [before[k]["rms_deg"] for k in keys], 0.4, label="calibrated nominal model")
    ax.barh(y + 0.2, [after[k]["rms_deg"] if k in after else 0 for k in keys], 0.4, label="with the added effects")
    ax.axvline(data.noise_deg, color="k", ls=":", label="noise floor")
    ax.set_yticks(y, keys, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("RMS residual [deg]")
    ax.set_title("residual by operating regime", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    p = out / "residual_regimes.png"
    write_atomic(p, lambda fh: fig.savefig(fh, dpi=110, format="png"))
    files.append(p.name)

    rd = data.recs[0]
    pred0 = simulate(*result.nominal_fit.spec.build(result.nominal_fit.x), data)[0][0]
    pred1 = simulate(result.plant, result.sensor, data)[0][0]
    fig = _figure((10, 3))
    ax = fig.subplots()
    ax.plot(rd.rec.t_s, rd.rec.angle_deg, "k", lw=0.8, label="recorded")
    ax.plot(rd.rec.t_s, pred0, lw=0.7, label="calibrated nominal model")
    ax.plot(rd.rec.t_s, pred1, lw=0.7, ls="--", label="with the added effects")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("angle [deg]")
    ax.set_title(f"{rd.rec.name}: segment-wise simulation of the recorded voltage", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    p = out / "angle_fit.png"
    write_atomic(p, lambda fh: fig.savefig(fh, dpi=110, format="png"))
    files.append(p.name)
    return files


def _fmt(v, e=None, unit=""):
    if e is None or not math.isfinite(e):
        return f"{v:.4g} {unit}".strip()
    return f"{v:.4g} +- {e:.2g} {unit}".strip()


def markdown(result, figures) -> str:
    r = result.report
    lines = [f"# Diagnosis: {', '.join(r['recordings'])} against model {r['model']}", "",
             f"**Verdict: {r['verdict']}.** RMS angle error {r['rms_before_deg']:.4f} deg (calibrated nominal model) "
             f"-> {r['rms_after_deg']:.4f} deg (final model); noise floor {r['noise_floor_deg']:.4f} deg. "
             f"Run time {r['elapsed_s']:.1f} s.", ""]
    lines += ["## Calibrated nominal parameters", "", "| parameter | nominal-only fit | final | unit |", "| --- | --- | --- | --- |"]
    for k, v in r["calibrated_parameters"].items():
        lines.append(f"| `{k}` | {v['nominal_fit']:.4g} | {_fmt(v['value'], v['stderr'])} | {v['unit']} |")
    lines += ["", "## Where the calibrated nominal model disagrees", ""]
    for name, w in r["mismatch_windows_s"].items():
        lines.append(f"- `{name}`: " + (", ".join(f"{a:.2f}-{b:.2f} s" for a, b in w) if w else "no window above 3x the noise floor"))
    lines += ["", "| regime | samples | RMS before [deg] | RMS after [deg] | significant before |", "| --- | --- | --- | --- | --- |"]
    after = {x["regime"]: x for x in r["regimes_after"]}
    for x in r["regimes_before"]:
        a = after.get(x["regime"], {}).get("rms_deg", float("nan"))
        lines.append(f"| {x['regime']} | {x['samples']} | {x['rms_deg']:.4f} | {a:.4f} | {'yes' if x['significant'] else ''} |")
    lines += ["", "## Effects added", ""]
    if not r["effects"]:
        lines.append("None.")
    for e in r["effects"]:
        lines.append(f"### `{e['id']}`: {e['description']}")
        lines.append("")
        lines.append(f"Shows in: {', '.join(e['where'])}. RMS gain {e['rms_gain_deg']:.4f} deg.")
        if "delta_bic" in e:
            lines.append(f" dBIC {e['delta_bic']:.0f}, held-out error {e['heldout_gain']:+.0%}.")
        lines.append("")
        for k, p in e["parameters"].items():
            lines.append(f"- `{k}` = {_fmt(p['value'], p['stderr'], p['unit'])}")
        if e.get("shape"):
            sh = e["shape"]
            lines.append(f"- shape: {sh.get('description', 'a table learned from the data')}; held-out error "
                         f"{sh.get('heldout_formula', float('nan')):.4g} with the formula, "
                         f"{sh.get('heldout_map', float('nan')):.4g} with the table (see shapes.png)")
        sm = e.get("sensor_map")
        if sm:                      # a sensing family's learned map (sensor_map.py)
            lines.append(f"- sensor {sm['kind']}: {sm['description']}; cross-validated error {sm['cv_error_with']:.4g} "
                         f"against {sm['cv_error_without']:.4g} without it"
                         + (" (see shapes.png)" if sm["kept"] else ": not kept, the twin reads without it"))
        lines.append("")
    skipped = r.get("skipped_candidates") or []
    if skipped:
        lines += ["## Candidates skipped", "", "These candidates could not be tried; the verdict holds without them:", ""]
        for s in skipped:
            if isinstance(s, dict):
                cid = s.get("id") or s.get("candidate") or "?"
                lines.append(f"- `{cid}`: {s.get('reason') or s.get('error') or 'no reason given'}")
            else:
                lines.append(f"- {s}")
        lines.append("")
    lines += ["## Unexplained", ""]
    if not r["unexplained"]:
        lines.append("Nothing significant remains." if r["verdict"] in ("match", "explained") else "")
    for u in r["unexplained"]:
        lines.append(f"- `{u['recording']}`: {u['where']}, RMS {u['rms_deg']:.4f} deg: {u['description']}")
    lines += ["", "## Residual tests", "", "| recording | Ljung-Box p before | after | max input xcorr before | after | 99 % bound |",
              "| --- | --- | --- | --- | --- | --- |"]
    for t in r["tests"]:
        lines.append(f"| {t['recording']} | {t['ljung_box_p_before']:.2g} | {t['ljung_box_p_after']:.2g} | "
                     f"{t['input_xcorr_before']:.3f} | {t['input_xcorr_after']:.3f} | {t['input_xcorr_bound_99']:.3f} |")
    if r.get("loop"):
        res = r.get("residual", {})
        lines += ["", "Loop type per recording (from how the voltage follows the angle) and the residual used: "
                  + ", ".join(f"`{k}` {v}" + (f" ({res[k]})" if k in res else "") for k, v in r["loop"].items()) + "."]
        if r.get("observer"):
            lines += ["", "Observer residual: one-step prediction error, the model's angle pulled towards the measured "
                      f"angle after every sample (bandwidth {r['observer']['bandwidth_rad_s']:g} rad/s); the calibrated "
                      "plant itself is unchanged."]
    if r.get("twin_replay"):
        lines += ["", "Twin check on closed-loop recordings (the exported twin replays the recorded voltage open loop; "
                  "a twin that predicts other excitations well stays near the noise): "
                  + ", ".join(f"`{k}` " + (f"{v['rms_deg']:.4f} deg ({v['over_noise']:.1f}x the noise floor)"
                                           if v["rms_deg"] is not None else "the simulation failed")
                              for k, v in r["twin_replay"].items()) + "."]
        worse = [k for k, v in r["twin_replay"].items() if v.get("worse_than_nominal")]
        if worse:
            lines += ["", "**The twin replays " + ", ".join(f"`{k}`" for k in worse) + " worse than the calibrated "
                      "nominal model** (" + ", ".join(f"{r['twin_replay'][k]['nominal_over_noise']:.1f}x the noise floor"
                                                      for k in worse) + "): it may predict other excitations worse "
                      "than the nominal model too."]
    rt = r.get("replay_tables")
    if rt and not rt.get("kept", True):
        lines += ["", f"Learned tables not kept ({', '.join(rt['tables'])}): on the replay of the recorded voltage, "
                  "which the closed loop's fits did not use, they did not lower the cost by more than its noise "
                  f"({rt['replay_cost_tables']:.0f} with, {rt['replay_cost_formula']:.0f} without, margin "
                  f"{rt['margin']:.0f}); the twin has the effects' formulas only."]
    tr = r.get("twin_range")
    if tr and (tr.get("beyond") or tr.get("slow_states") or tr.get("passed_only")):
        lines += ["", f"Where the twin extrapolates: {tr['words']}."]
    figures = list(figures) + [f for f in r.get("shape_figures", []) if f not in figures]
    lines += ["", "## Figures", ""] + [f"![{f}]({f})" for f in figures]
    lines += ["", f"The calibrated plant (with the effects that act on the plate) is `{r['calibrated_plant']}`: "
              "`gym.make(\"ETB-3B-v0\", plant=...)` loads it, its `[sensor]` section (the sensor-side effects, also in "
              "`report.json` `sensor`; `etb_gym.plantfile.load_sensor`) included.", ""]
    return "\n".join(lines)


def summary(result) -> str:
    r = result.report
    s = [f"verdict: {r['verdict']}   RMS {r['rms_before_deg']:.4f} -> {r['rms_after_deg']:.4f} deg   "
         f"(noise floor {r['noise_floor_deg']:.4f} deg, {r['elapsed_s']:.1f} s)"]
    for name, w in r["mismatch_windows_s"].items():
        s.append(f"  mismatch in {name}: {len(w)} window(s)" + (f", first {w[0][0]:.2f}-{w[0][1]:.2f} s" if w else ""))
    for e in r["effects"]:
        ps = ", ".join(f"{k} = {_fmt(p['value'], p['stderr'], p['unit'])}" for k, p in e["parameters"].items())
        s.append(f"  + {e['id']} ({', '.join(e['where'])}): {ps}")
    for u in r["unexplained"]:
        s.append(f"  ? unexplained in {u['recording']}: {u['where']} (RMS {u['rms_deg']:.3f} deg): {u['description']}")
    return "\n".join(s)


def prepare_out(out: Path) -> None:
    """Create the output folder now, or say why it cannot be (an existing file in the way, no permission)."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"out = {out}: is an existing file: expected a folder for the report")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ValueError(f"out = {out}: cannot create the folder ({e.strerror or e})") from None


def write_failed(out: Path, reason: str, *, model: str, recordings: list, exc: BaseException | None = None) -> None:
    """A diagnosis that could not proceed: report.json with verdict "failed" and the reason, a short report.md;
    figures and a calibrated plant of an earlier report in ``out`` are removed so nothing stale remains."""
    import traceback

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rep = {"schema": SCHEMA, "model": model, "recordings": list(recordings), "verdict": "failed",
           "reason": reason}
    if exc is not None:
        rep["error_type"] = type(exc).__name__
        rep["traceback"] = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    for f in ("calibrated_plant.toml",) + FIGURES:
        try:
            (out / f).unlink()
        except FileNotFoundError:
            pass
    _atomic_text(out / "report.json", json.dumps(_json_safe(rep), indent=2) + "\n")
    _atomic_text(out / "report.md", f"# Diagnosis of {', '.join(recordings)} against model {model}\n\n"
                                    f"**Verdict: failed.** {reason}\n\nNo model was fitted; nothing else was written. "
                                    f"The exit code was 3 (see docs/errors.md).\n")


def write(result, out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    figures = plots(result, out)
    stages = result.report.get("elapsed_breakdown_s")
    if isinstance(stages, dict):                 # the figures' wall time too (the report's json comes after)
        stages["figures"] = time.perf_counter() - t0
        result.elapsed_s = result.report["elapsed_s"] = result.report.get("elapsed_s", 0.0) + stages["figures"]
    save_plant(result.plant, out / "calibrated_plant.toml", sensor=result.sensor.section())
    _atomic_text(out / "report.json", json.dumps(_json_safe(result.report), indent=2) + "\n")
    _atomic_text(out / "report.md", markdown(result, figures))
