"""Evaluation with the controller benchmark's metrics: a policy scored against PID and sliding mode during
training (``eval.csv``), and the RMS comparison table of an agent in benchmark results
(``python -m etb_gym.rl compare``).

score = geometric mean over the evaluation runs of rms_error_deg(agent) / min(rms_error_deg(PID),
rms_error_deg(SMC)); < 1: better than both classical controllers.
"""
from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from .config import RunConfig
from .files import atomic_bytes, atomic_json


def _eval_jobs(cfg: RunConfig, controller: str):
    from etb_gym.benchmark import make_jobs

    return make_jobs([controller], cfg.eval_scenarios, cfg.eval_variants, [0], env_id=cfg.env_id)


def evaluate_controller(ctrl, cfg: RunConfig, label: str) -> dict:
    """{(scenario, variant): benchmark metrics} of one controller on the run's evaluation jobs (seed 0)."""
    from etb_gym.benchmark import SCENARIOS, metrics, simulate

    out = {}
    for job in _eval_jobs(cfg, label):
        trace, _ = simulate(job, controller=ctrl)
        out[(job.scenario, job.variant)] = metrics(trace, SCENARIOS[job.scenario])
    return out


def classical_reference(cfg: RunConfig, cache: Path | None = None) -> dict:
    """{"scenario/variant": {"pid": rms, "smc": rms, "best": min}} on the evaluation jobs (cached in ``cache``)."""
    if cache is not None and cache.exists():
        ref = json.loads(cache.read_text())
        want = {f"{s}/{v}" for s in cfg.eval_scenarios for v in cfg.eval_variants}
        if want <= set(ref):
            return ref
    from etb_gym.benchmark import build_controller

    ref: dict = {}
    for name in ("pid", "smc"):
        ctrl = build_controller(name, cfg.env_id)
        for (s, v), m in evaluate_controller(ctrl, cfg, name).items():
            ref.setdefault(f"{s}/{v}", {})[name] = m["rms_error_deg"]
    for r in ref.values():
        r["best"] = min(r["pid"], r["smc"])
    if cache is not None:
        atomic_json(cache, ref)
    return ref


def score_of(rms: Mapping[str, float], ref: Mapping[str, Mapping]) -> float:
    """Geometric mean of rms / best-classical rms over the evaluation runs (inf if any run is non-finite)."""
    logs = []
    for k, v in rms.items():
        if not math.isfinite(v):
            return math.inf
        logs.append(math.log(max(v, 1e-9) / max(ref[k]["best"], 1e-9)))
    return float(math.exp(np.mean(logs))) if logs else math.nan


EVAL_COLUMNS = ("timesteps", "wall_time_s", "score", "worst_ratio", "train_return")


def read_eval_csv(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path, newline="") as fh:
        return [{k: float(v) for k, v in r.items()} for r in csv.DictReader(fh)]


def write_eval_csv(path: Path, rows: list[dict]) -> None:
    cols = list(EVAL_COLUMNS) + sorted({k for r in rows for k in r} - set(EVAL_COLUMNS))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols)
    w.writeheader()
    for r in rows:
        w.writerow({c: (f"{r[c]:.6g}" if isinstance(r.get(c), float) else r.get(c, "")) for c in cols})
    atomic_bytes(path, buf.getvalue().encode())



def rms_comparison(rows: Sequence[Mapping], agent: str, others: Sequence[str] = ("pid", "smc")) -> tuple[str, list]:
    """The issue's target table from benchmark rows (``etb_gym.benchmark.read_results``): per scenario and
    variant the RMS tracking error of ``agent`` and of the classical controllers (means over seeds), and
    ratio = agent / min(others). Returns (Markdown, list of dict rows)."""
    from collections import defaultdict

    others = [c for c in others if c != agent]
    acc = defaultdict(list)
    for r in rows:
        acc[(r["env"], r["scenario"], r["variant"], r["controller"])].append(float(r["rms_error_deg"]))
    keys = sorted({(e, s, v) for e, s, v, c in acc if c == agent},
                  key=lambda k: (k[0], k[2] != "nominal", k[2], k[1]))
    if not keys:
        raise ValueError(f"no benchmark rows for controller {agent!r}: controllers present are "
                         f"{sorted({c for *_, c in acc})}")
    table = []
    for e, s, v in keys:
        row = {"env": e, "scenario": s, "variant": v, agent: float(np.mean(acc[(e, s, v, agent)]))}
        for c in others:
            row[c] = float(np.mean(acc[(e, s, v, c)])) if (e, s, v, c) in acc else math.nan
        best = min((row[c] for c in others if math.isfinite(row[c])), default=math.nan)
        row["ratio"] = row[agent] / best if math.isfinite(best) and best > 0 else math.nan
        table.append(row)
    ratios = np.array([r["ratio"] for r in table])
    all_ = "both" if len(others) == 2 else "all"
    ok = ratios <= 1.2
    better = ratios < 1.0
    lines = [f"# RMS tracking error: {agent} vs {' / '.join(others)}", "",
             f"ratio = RMS({agent}) / min(RMS of {', '.join(others)}); target <= 1.2 everywhere, < 1 somewhere.",
             "", f"**{int(ok.sum())}/{len(table)}** runs within 1.2x, **{int(better.sum())}/{len(table)}** better than "
             f"{all_} (nominal: {int(sum(o for o, r in zip(ok, table) if r['variant'] == 'nominal'))}/"
             f"{sum(r['variant'] == 'nominal' for r in table)} within 1.2x; geometric-mean ratio "
             f"{float(np.exp(np.mean(np.log(np.clip(ratios, 1e-9, None))))):.3g}).", "",
             f"| scenario | variant | {agent} [deg] | " + " | ".join(f"{c} [deg]" for c in others) + " | ratio | |",
             "|---|---|---|" + "---|" * len(others) + "---|---|"]
    for r in table:
        mark = f"better than {all_}" if r["ratio"] < 1.0 else ("within 1.2x" if r["ratio"] <= 1.2 else "**miss**")
        lines.append(f"| {r['scenario']} | {r['variant']} | {r[agent]:.4g} | "
                     + " | ".join(f"{r[c]:.4g}" for c in others) + f" | {r['ratio']:.3g} | {mark} |")
    return "\n".join(lines) + "\n", table



def compare_main(argv=None) -> int:
    """``python -m etb_gym.rl compare OUT/results.csv --agent rl:DIR [--md FILE] [--csv FILE] [--against C ...]``."""
    import argparse

    p = argparse.ArgumentParser(prog="python -m etb_gym.rl", description="RL helpers: the RMS comparison table")
    sub = p.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("compare", help="RMS tracking error of an agent vs PID and SMC from benchmark results.csv")
    c.add_argument("results", help="results.csv of etb-gym benchmark")
    c.add_argument("--agent", required=True, help="the agent's controller spec as in results.csv, e.g. rl:DIR")
    c.add_argument("--md", default=None, help="write the Markdown table here")
    c.add_argument("--csv", default=None, help="write the table rows here")
    c.add_argument("--against", action="append", metavar="CONTROLLER",
                   help="reference controller(s) in results.csv to compare with; repeat (default: pid and smc)")
    a = p.parse_args(argv)
    from etb_gym.benchmark import read_results

    md, table = rms_comparison(read_results(a.results), a.agent, tuple(a.against or ("pid", "smc")))
    print(md)
    if a.md:
        atomic_bytes(Path(a.md), md.encode())
    if a.csv:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=list(table[0]))
        w.writeheader()
        w.writerows(table)
        atomic_bytes(Path(a.csv), buf.getvalue().encode())
    return 0

