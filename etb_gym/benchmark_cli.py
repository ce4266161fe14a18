"""``etb-gym benchmark``: the command line of the controller benchmark (etb_gym.benchmark runs the sweep,
etb_gym.bench_report writes the table and plots; this module sits above both)."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from etb_gym import bench_report
from etb_gym.benchmark import (DEFAULT_CONTROLLERS, DEFAULT_ENV, QUICK_SCENARIOS, SCENARIOS, VARIANTS, make_jobs,
                               run_sweep)

# ------------------------------------------------------------------------------------------------ command line
CLI_DOC = """Controller benchmark on the ETB envs: controllers x scenarios x plant variants x seeds.

With no arguments: the quick benchmark of the five reference controllers on ETB-3B-v0 (nominal plant and the
robustness grid, one seed) next to the physical bound of every step, printed as a Markdown table with the
issue's targets marked pass/FAIL.

    etb-gym benchmark                                  # quick (about a minute on 2 cores)
    etb-gym benchmark --full --workers 2               # all scenarios, 3 seeds
    etb-gym benchmark --controller pid --controller my_pkg.ctrl:MyController --env ETB-1A-v0
    etb-gym benchmark --controller rl:baselines/rl/ppo.zip     # once the RL prefix is registered
    etb-gym benchmark --ray local                      # same sweep as Ray tasks
    etb-gym benchmark --resume                         # complete an interrupted sweep

Outputs in --out: results.csv (one row per run, rewritten atomically after every run), results.md (the
table), response_<env>_<scenario>.png (nominal plant, first seed, with the bound's trajectory), traces/*.npz
(those runs' traces), bounds.json (the physical bounds, reused when their fingerprint matches). The tracking
cells are also reported against their own noise-free bound from --tracking-bounds (scripts/ramp_bound.py's
JSON; default the committed baselines/benchmark/ramp_bound.json), for the entries whose fingerprint matches.
"""


def parse_args(argv=None):
    from etb_gym.envs import ENV_IDS

    p = argparse.ArgumentParser(prog="etb-gym benchmark", description=CLI_DOC.split("\n\n")[0],
                                epilog=CLI_DOC.split("\n\n", 1)[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--controller", action="append", metavar="SPEC",
                   help="built-in name (ptos, pid, smc, pid-plain, smc-plain, pid-nocomp), module:Class or "
                        "prefix:ARG (e.g. rl:PATH); repeat "
                        f"for several (default: {' '.join(DEFAULT_CONTROLLERS)})")
    p.add_argument("--env", default=DEFAULT_ENV, help=f"env id, one of {', '.join(ENV_IDS)} (default {DEFAULT_ENV})")
    p.add_argument("--scenario", action="append", metavar="NAME",
                   help=f"scenario(s) (default: quick set; --full: all): {', '.join(SCENARIOS)}")
    p.add_argument("--variant", action="append", metavar="NAME",
                   help=f"plant variant(s) (default: all): {', '.join(VARIANTS)}")
    p.add_argument("--seeds", type=int, default=None, help="number of seeds 0..N-1 (default 1; --full: 3)")
    p.add_argument("--full", action="store_true", help="all scenarios and 3 seeds")
    p.add_argument("--out", default=None,
                   help="output folder (default out/benchmark, gitignored; when it already holds results and neither "
                        "--resume nor --force is given, the next free out/benchmark-N)")
    p.add_argument("--workers", type=int, default=2, help="local worker processes (default 2; 1 = in-process)")
    p.add_argument("--ray", metavar="ADDRESS", default=None,
                   help="run on Ray: 'local' starts a local instance, 'auto' or 'ray://host:port' joins a cluster")
    p.add_argument("--resume", action="store_true", help="keep the rows in OUT/results.csv and run only the missing ones")
    p.add_argument("--force", action="store_true",
                   help="replace an existing OUT/results.csv (default: refuse unless --resume, so no result is lost)")
    p.add_argument("--tracking-bounds", metavar="JSON", default=None,
                   help="tracking bounds of scripts/ramp_bound.py (default: the committed "
                        "baselines/benchmark/ramp_bound.json when present; 'none' = leave them out)")
    p.add_argument("--no-plots", action="store_true", help="skip the PNG response plots")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no table on stdout")
    a = p.parse_args(argv)
    if a.env not in ENV_IDS:
        p.error(f"unknown env {a.env!r}: valid are {', '.join(ENV_IDS)}")
    for kind, names, valid in (("scenario", a.scenario, SCENARIOS), ("variant", a.variant, VARIANTS)):
        bad = [n for n in names or [] if n not in valid]
        if bad:
            p.error(f"unknown {kind}(s) {bad}: valid are {', '.join(valid)}")
    if a.tracking_bounds not in (None, "none") and not Path(a.tracking_bounds).is_file():
        p.error(f"--tracking-bounds {a.tracking_bounds}: no such file: expected the JSON of scripts/ramp_bound.py "
                "or 'none'")
    if a.workers < 1:
        p.error(f"--workers {a.workers}: expected at least 1")
    if a.seeds is not None and a.seeds < 1:
        p.error(f"--seeds {a.seeds}: expected at least 1")
    return a


DEFAULT_OUT = Path("out/benchmark")


def _output_folder(a) -> Path | None:
    """Where this run writes; None (after one sentence on stderr) when that would replace earlier results.

    An --out the user named is refused if it is a file or holds results.csv (unless --resume or --force); the
    default folder moves on to out/benchmark-2, -3, ... instead, so the README's command can be run again."""
    prog = "etb-gym benchmark"
    if a.out is None:
        out = DEFAULT_OUT
        n = 1
        while (out / "results.csv").exists() and not (a.resume or a.force):
            n += 1
            out = DEFAULT_OUT.with_name(f"{DEFAULT_OUT.name}-{n}")
        if n > 1:
            print(f"{prog}: {DEFAULT_OUT} already holds results; writing to {out} (--resume completes the "
                  f"earlier sweep, --force replaces it)", file=sys.stderr)
        return out
    out = Path(a.out)
    if out.exists() and not out.is_dir():
        print(f"{prog}: error: --out {out}: is an existing file: expected a folder", file=sys.stderr)
        return None
    if (out / "results.csv").exists() and not (a.resume or a.force):
        print(f"{prog}: error: --out {out}: already holds results.csv: add --resume to complete it, --force "
              f"to replace it, or choose another folder", file=sys.stderr)
        return None
    return out


def main(argv=None) -> int:
    a = parse_args(argv)
    controllers = a.controller or list(DEFAULT_CONTROLLERS)
    scenarios = a.scenario or (list(SCENARIOS) if a.full else list(QUICK_SCENARIOS))
    variants = a.variant or list(VARIANTS)
    seeds = range(a.seeds if a.seeds is not None else (3 if a.full else 1))
    try:
        jobs = make_jobs(controllers, scenarios, variants, seeds, env_id=a.env)
    except ValueError as exc:
        print(f"etb-gym benchmark: error: {exc}", file=sys.stderr)
        return 2
    out = _output_folder(a)
    if out is None:
        return 2
    t0 = time.perf_counter()
    try:
        rows = run_sweep(jobs, out, workers=a.workers, ray_address=a.ray, resume=a.resume, progress=not a.quiet)
    except (ValueError, RuntimeError) as exc:
        print(f"etb-gym benchmark: error: {exc}", file=sys.stderr)
        return 2
    keys = {j.key for j in jobs}
    rows = [r for r in rows if (r["env"], r["controller"], r["scenario"], r["variant"], str(r["seed"])) in keys]
    from etb_gym.bench_bounds import read_tracking_bounds

    tb = {} if a.tracking_bounds == "none" else read_tracking_bounds(a.tracking_bounds)
    md = bench_report.markdown(rows, title=f"Controller benchmark: {', '.join(controllers)} on {a.env}",
                               tracking_bounds=tb)
    bench_report.write_text(out / "results.md", md)
    if not a.no_plots:
        bench_report.plot_scenarios(out, rows)
    if not a.quiet:
        print(md)
        print(f"{len(rows)} runs in {time.perf_counter() - t0:.1f} s -> {out}/results.csv, results.md, response_*.png")
    return 0
