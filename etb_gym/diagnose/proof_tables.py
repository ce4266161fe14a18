"""The proof's tables (:mod:`.proof`): per family, per loop type and nameplate, two-effect pairs, and the
issue's targets, from the rows of the runs (Markdown)."""
from __future__ import annotations

import math

import numpy as np

from .proof_truth import FAMILIES, PAIRS


DETECTABLE = 3.0     # an effect that moves the reading by >= 3 x the noise (100 ms moving RMS) somewhere


def summarize(rows):
    """Per family: rates over all runs and over the runs whose effect is detectable (DETECTABLE)."""
    fams = []
    # a family's truth shapes k > 0 ("NAME@k", proof --shapes) get their own rows, after its shape 0
    names = [n for f in FAMILIES for n in sorted({r["family"] for r in rows if r["family"].split("@")[0] == f})]
    for f in names:
        rs = [r for r in rows if r["family"] == f]
        if not rs:
            continue
        # clean runs have nothing to detect; a coarse grid is read off the values whatever the noise
        det = [r for r in rs if f.split("@")[0] in ("clean", "sensor_quantization")
               or r.get("effect_size", 0.0) >= DETECTABLE]
        d = {"family": f, "runs": len(rs), "detectable": len(det),
             "named_rate": float(np.mean([r["named"] for r in rs])),
             "named_rate_detectable": float(np.mean([r["named"] for r in det])) if det else float("nan"),
             "rms_before": float(np.median([r["rms_before"] for r in rs])),
             "rms_after": float(np.median([r["rms_after"] for r in rs])),
             "heldout_reduction": float(np.median([1 - r["heldout_rms_after"] / r["heldout_rms_before"] for r in det or rs])),
             "heldout_after_over_noise": float(np.median([r["heldout_rms_after"] / r["true_noise"] for r in det or rs])),
             "time_s": float(np.median([r["time_s"] for r in rs])),
             "verdicts": {v: sum(r["verdict"] == v for r in rs)
                          for v in ("match", "explained", "partly_explained", "unexplained") if any(r["verdict"] == v for r in rs)}}
        wp = [r for r in det if "win_precision" in r]
        if wp:
            d["win_precision"] = float(np.mean([r["win_precision"] for r in wp]))
            d["win_recall"] = float(np.mean([r["win_recall"] for r in wp]))
        pe = [r for r in rs if "param_rel_err" in r]
        if pe:
            d["param_median_rel_err"] = float(np.median([r["param_rel_err"] for r in pe]))
            d["param_coverage"] = float(np.mean([r["param_covered"] for r in pe]))
        fams.append(d)
    return fams


def table(fams) -> str:
    L = ["| family | runs (detectable) | named first: all / detectable (clean: none claimed) | RMS before / after [deg] | "
         "held-out RMS reduction | held-out after / noise | windows P / R | param median rel. err | 90 % coverage | time [s] | verdicts |",
         "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for d in fams:
        w = f"{d['win_precision']:.2f} / {d['win_recall']:.2f}" if "win_precision" in d else "-"
        p = f"{d['param_median_rel_err']:.1%}" if "param_median_rel_err" in d else "-"
        c = f"{d['param_coverage']:.0%}" if "param_coverage" in d else "-"
        nd = "-" if d["named_rate_detectable"] != d["named_rate_detectable"] else f"{d['named_rate_detectable']:.0%}"
        L.append(f"| {d['family']} | {d['runs']} ({d['detectable']}) | {d['named_rate']:.0%} / {nd} | "
                 f"{d['rms_before']:.4f} / {d['rms_after']:.4f} | {d['heldout_reduction']:.0%} | "
                 f"{d['heldout_after_over_noise']:.2f} | {w} | {p} | {c} | {d['time_s']:.0f} | "
                 + ", ".join(f"{k} {n}" for k, n in d["verdicts"].items()) + " |")
    return "\n".join(L)


def _frac(xs) -> str:
    xs = list(xs)
    return f"{sum(xs)}/{len(xs)} ({sum(xs) / len(xs):.0%})" if xs else "-"


def pair_table(rows) -> str:
    """Runs with two concealed effects, per pair (Markdown; empty if there are none)."""
    L = []
    for pair in PAIRS:
        rs = [r for r in rows if r["family"] == "pair:" + pair]
        if not rs:
            continue
        det = [r for r in rs if min(r["effect_sizes"]) >= DETECTABLE]
        ps = [p for r in rs for p in r["params"] if "param_rel_err" in p]
        L.append(f"| {pair.replace('+', ' + ')} | {len(rs)} ({len(det)}) | {_frac(r['named'] for r in det)} | "
                 f"{_frac(r['named_first'] for r in det)} | "
                 f"{np.median([r['rms_before'] for r in rs]):.4f} / {np.median([r['rms_after'] for r in rs]):.4f} | "
                 f"{_frac(r['heldout_rms_after'] <= 0.5 * r['heldout_rms_before'] for r in det)} | "
                 f"{np.median([r['heldout_rms_after'] / r['true_noise'] for r in det or rs]):.2f} | "
                 f"{np.mean([r['win_precision'] for r in det or rs]):.2f} / {np.mean([r['win_recall'] for r in det or rs]):.2f} | "
                 + (f"{np.median([p['param_rel_err'] for p in ps]):.1%} | {_frac(p['param_covered'] for p in ps)} | " if ps else "- | - | ")
                 + f"{np.median([r['time_s'] for r in rs]):.0f} |")
    if not L:
        return ""
    return "\n".join(["| pair | runs (both detectable) | both named (detectable) | one of them named first | "
                      "RMS before / after [deg] | held-out RMS falls >= 50 % | held-out after / noise | windows P / R | "
                      "param median rel. err (both) | 90 % coverage | time [s] |",
                      "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"] + L)


def targets(rows) -> str:
    """The issue's targets against what the single-effect rows measured (Markdown)."""
    rows = [r for r in rows if not r["family"].startswith("pair:")]
    det = [r for r in rows if r["family"] != "clean" and
           (r["family"].split("@")[0] == "sensor_quantization" or r.get("effect_size", 0.0) >= DETECTABLE)]
    clean = [r for r in rows if r["family"] == "clean"]
    win = [r for r in det if "win_precision" in r and r["family"] not in ("sensor_quantization",)]
    par = [r for r in det if "param_rel_err" in r]
    moderate = [r for r in par if r.get("effect_size", math.inf) >= 10.0]
    t = sorted(r["time_s"] for r in rows)
    L = ["| target | measured |", "| --- | --- |",
         f"| right effect named first >= 90 % (detectable runs) | {_frac(r['named'] for r in det)} |",
         f"| clean recordings: no effect claimed >= 95 % | {_frac(r['named'] for r in clean)} |",
         f"| clean recordings: verdict `match` | {_frac(r['verdict'] == 'match' for r in clean)} |",
         "| mismatch windows precision / recall >= 0.8 (mean over detectable runs) | "
         + (f"{np.mean([r['win_precision'] for r in win]):.2f} / {np.mean([r['win_recall'] for r in win]):.2f}" if win else "-") + " |",
         f"| main parameter within +-10 % (named runs, effect >= 10x noise) | {_frac(r['param_rel_err'] <= 0.10 for r in moderate)} |",
         f"| 90 % interval covers the truth >= 85 % (named runs) | {_frac(r['param_covered'] for r in par)} |",
         f"| held-out RMS falls >= 50 % (detectable runs) | {_frac(r['heldout_rms_after'] <= 0.5 * r['heldout_rms_before'] for r in det)} |",
         f"| held-out RMS ends <= 1.5x the noise (detectable runs) | {_frac(r['heldout_rms_after'] <= 1.5 * r['true_noise'] for r in det)} |",
         f"| diagnosis of 10 s at 1 kHz, full library, <= 120 s | {_frac(x <= 120.0 for x in t)}; median {np.median(t):.0f} s, max {t[-1]:.0f} s |"
         if t else "| time | - |"]
    return "\n".join(L)


def loop_table(rows) -> str:
    """Rates per loop type and nameplate (single-effect runs): named first on detectable runs, clean runs."""
    rows = [r for r in rows if not r["family"].startswith("pair:")]
    L = ["| nameplate | loop | detectable runs: named first | clean: no effect claimed | clean: `match` | "
         "held-out after / noise (detectable, median) | time median / max [s] |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for npl in sorted({r.get("nameplate", "3B") for r in rows}):
        for closed in (False, True):
            rs = [r for r in rows if r.get("nameplate", "3B") == npl and r["closed"] == closed]
            if not rs:
                continue
            det = [r for r in rs if r["family"] != "clean" and
                   (r["family"].split("@")[0] == "sensor_quantization" or r.get("effect_size", 0.0) >= DETECTABLE)]
            cl = [r for r in rs if r["family"] == "clean"]
            t = [r["time_s"] for r in rs]
            ho = f"{np.median([r['heldout_rms_after'] / r['true_noise'] for r in det]):.2f}" if det else "-"
            L.append(f"| {npl} | {'closed' if closed else 'open'} | {_frac(r['named'] for r in det)} | "
                     f"{_frac(r['named'] for r in cl)} | {_frac(r['verdict'] == 'match' for r in cl)} | {ho} | "
                     f"{np.median(t):.0f} / {np.max(t):.0f} |")
    return "\n".join(L)
