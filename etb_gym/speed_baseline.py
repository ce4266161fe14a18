"""``etb-gym speed --baseline REV``: a git revision of etb-gym measured side by side with this tree (etb_gym.speed)."""
from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

from .speed_cases import atomic_write, log, machine_info
from .speed_report import fmt_rate

ROOT = Path(__file__).resolve().parents[1]     # the source tree (for --baseline's git archive)
EQUAL_ACCURACY_DEG = 0.044   # RMS angle error of the stepper before issue 12 at 20 substeps, 3B rich excitation


def extract_revision(rev: str, into: Path) -> tuple[Path, Path]:
    """REV's source tree (git archive) and an importable package directory for it (the package layout of
    its pyproject.toml: etb_gym.envs lives in envs/, ...). Returns (source, PYTHONPATH entry)."""
    src, pkg = into / "src", into / "pkg"
    src.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    layout = tomllib.loads((src / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    shutil.copytree(src / layout.get("etb_gym", "etb_gym"), pkg / "etb_gym")
    for name, path in layout.items():
        target = pkg / name.replace(".", "/")
        if name != "etb_gym" and not target.exists():
            target.symlink_to(src / path, target_is_directory=True)
    return src, pkg


def _flatten(res: dict) -> dict:
    """The compared figures of one run: name -> value."""
    out = {k: res[k] for k in ("etb_steps_per_s", "etb_switching_steps_per_s", "reset_us", "pendulum_steps_per_s",
                               "gem_steps_per_s", "plant_step_us", "kernel_1024_steps_per_s", "ratio_etb_vs_gem",
                               "ratio_etb_vs_pendulum")}
    out.update({f"vector_{n}_steps_per_s": v for n, v in res["vector_steps_per_s"].items()})
    out.update({f"cpu_us_per_step.{k}": v for k, v in res["cpu_us_per_step"].items()})
    if res.get("vector_steps_per_s_at_equal_accuracy") is not None:
        out["vector_steps_per_s_at_equal_accuracy"] = res["vector_steps_per_s_at_equal_accuracy"]
    return out


def _medians(runs: list[dict]) -> dict:
    out = {}
    for k in runs[0]:
        values = [r.get(k) for r in runs]
        out[k] = None if None in values else statistics.median(values)
    return out


def compare_with_baseline(args, eq):
    common = ["--repeats", "1", "--seconds", str(args.seconds), "--env-id", args.env_id, "--no-reference",
              "--excitation-s", "0.1", "--seed", str(args.seed), "--num-envs", *map(str, args.num_envs)]
    common += ["--no-gem"] if args.no_gem else []
    common += ["--plant", str(Path(args.plant).resolve())] if args.plant else []
    with tempfile.TemporaryDirectory(prefix="etb_bench_baseline_") as tmp:
        src, pkg = extract_revision(args.baseline, Path(tmp))
        env_before = dict(os.environ, PYTHONPATH=str(pkg))
        extra = [] if args.equal_accuracy_substeps is None else \
            ["--equal-accuracy-substeps", str(args.equal_accuracy_substeps)]
        before_extra = [] if args.baseline_substeps is None else \
            ["--equal-accuracy-substeps", str(args.baseline_substeps)]
        runs = {"before": ([sys.executable, str(src / "scripts" / "bench_speed.py"), *common, *before_extra],
                           env_before),
                "after": ([sys.executable, "-m", "etb_gym.speed", *common, *extra], dict(os.environ))}
        results = {k: [] for k in runs}
        load_start = machine_info().get("loadavg_1min")
        for r in range(args.repeats):
            for label, (cmd, env) in runs.items():
                log(f"--baseline: round {r + 1}/{args.repeats}, {label}")
                out = subprocess.run(cmd, env=env, cwd=tmp, capture_output=True, text=True)
                if out.returncode:
                    raise SystemExit(f"speed --baseline: the {label} run failed:\n{out.stderr[-3000:]}")
                results[label].append(json.loads(out.stdout.strip().splitlines()[-1]))
                bar_note = f"{label}: vector N=1024 {results[label][-1]['vector_steps_per_s'].get('1024')}"
                log(bar_note)
    load_end = machine_info().get("loadavg_1min")
    med = {label: _medians([_flatten(r) for r in rs]) for label, rs in results.items()}
    print(f"\n{args.baseline} (before) vs this tree (after): medians of {args.repeats} alternating rounds of "
          f"~{args.seconds:g} s per case, load average {load_start} -> {load_end}\n")
    print("| figure | before | after | after / before |")
    print("|---|---|---|---|")
    for k, b in med["before"].items():
        a = med["after"].get(k)
        if a is None or b is None:
            continue
        fmt = (lambda v: f"{v:.2f}") if (k.endswith("_us") or k.startswith(("cpu", "ratio"))) else fmt_rate
        print(f"| {k} | {fmt(b)} | {fmt(a)} | {a / b:.2f} |")
    eq_after = med["after"].get("vector_steps_per_s_at_equal_accuracy")
    n_max = max(args.num_envs)
    eq_before = med["before"].get(f"vector_{n_max}_steps_per_s")
    if eq_after is not None and eq_before is not None:
        print(f"| make_vec N={n_max} at equal accuracy ({EQUAL_ACCURACY_DEG} deg RMS): before at its 20 substeps, "
              f"after at {args.equal_accuracy_substeps} | {fmt_rate(eq_before)} | {fmt_rate(eq_after)} | "
              f"{eq_after / eq_before:.2f} |")
    eq_before_own = med["before"].get("vector_steps_per_s_at_equal_accuracy")
    if eq_after is not None and eq_before_own is not None:
        print(f"| make_vec N={n_max} at equal accuracy: before at {args.baseline_substeps} substeps "
              f"(--baseline-substeps), after at {args.equal_accuracy_substeps} | {fmt_rate(eq_before_own)} | "
              f"{fmt_rate(eq_after)} | {eq_after / eq_before_own:.2f} |")
    res = dict(results["after"][-1])
    dt = res["etb_sim_s_per_wall_s"] / res["etb_steps_per_s"]      # the control period (of the last run)
    res.update({k: med["after"][k] for k in ("etb_steps_per_s", "reset_us", "pendulum_steps_per_s", "gem_steps_per_s",
                                             "ratio_etb_vs_gem", "ratio_etb_vs_pendulum")})
    res["etb_sim_s_per_wall_s"] = med["after"]["etb_steps_per_s"] * dt
    res["etb_switching_realtime_factor"] = med["after"]["etb_switching_steps_per_s"] * dt
    res["vector_steps_per_s"] = {str(n): med["after"][f"vector_{n}_steps_per_s"] for n in args.num_envs}
    res["baseline"] = {"revision": args.baseline, "medians_before": med["before"], "medians_after": med["after"],
                       "rounds": args.repeats, "loadavg_1min": [load_start, load_end]}
    res["substeps_for_0p044_deg"] = args.equal_accuracy_substeps
    res["equal_accuracy"] = eq
    res["vector_steps_per_s_at_equal_accuracy"] = eq_after
    cpu_eq = med["after"].get("cpu_us_per_step.vector_eqacc")
    res["vector_cpu_us_per_plant_step_at_equal_accuracy"] = cpu_eq
    res["vector_steps_per_s_bound_at_equal_accuracy"] = None if cpu_eq is None else \
        (res["machine"].get("cpus") or 1) * 1e6 / cpu_eq
    res["ratio_vector_at_equal_accuracy_vs_baseline"] = None if eq_after is None or eq_before is None \
        else eq_after / eq_before
    res["ratio_vector_at_equal_accuracy_vs_baseline_at_its_substeps"] = \
        None if eq_after is None or eq_before_own is None else eq_after / eq_before_own
    if args.json_out:
        atomic_write(Path(args.json_out), json.dumps(res, indent=2) + "\n")
    print(json.dumps(res))
    return res
