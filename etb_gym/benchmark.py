"""The controller benchmark: controllers x scenarios x plant variants x seeds, all through the Gymnasium env.

Every run builds ``gym.make(env_id, params=<variant>, supply_V=..., sensor=...)`` and resets it with the
scenario's reference and initial angle and the run's seed, so every controller sees exactly what the env
observes, on identical plants, references (random ones are drawn from the seed) and sensor noise.

Scenarios start with a 0.3 s hold at the initial angle (the controller brings the plate to rest under
control) before the step/ramp/profile; step metrics are measured from the step on the *true* angle:

    rise_time_s             10 % -> 90 % of the step
    settling_time_s         last exit from the band max(2 % of |step|, 0.1 deg) (0.1 deg: sensor resolution
                            floor, so for a 0.5 deg step it is the "reach +-0.1 deg and stay" time). NaN when
                            the plate never settles, and when the hold left the plate more than a band away
                            from the step's start (no step response to measure: flagged, counted as a miss)
    step_start_deg          the true angle at the step (where the step really started)
    bound_s                 the physical bound of the step on this plant variant (etb_gym.bound)
    settling_ratio          settling_time_s / bound_s
    overshoot_pct           largest excursion beyond the final reference, % of |step|
    steady_state_error_deg  mean |r - phi| over the last 0.1 s
    limit_cycle_deg         half the peak-to-peak of phi over the last 0.1 s (a sustained oscillation)
    iae_deg_s, rms_error_deg  integral / RMS of |r - phi| over the evaluated window (from the step, or all
                            of a tracking scenario after the hold)
    control_effort          RMS duty over the window;  peak_current_A  max |i|
    duty_total_variation    sum |d_k - d_{k-1}| over the window (chattering)
    stable                  finite, and |r - phi| < 2 deg + 5 % of the travel at the end
    signals                 what the controller read besides the reference: angle (+current, +supply)

Module layout: this module runs jobs (one run through the env, the sweep over a process pool or Ray);
``etb_gym.bench_scenarios`` holds the scenarios and plant variants, ``etb_gym.bench_results`` the metrics and
the results file, ``etb_gym.bench_bounds`` the physical bounds and their cache, ``etb_gym.bench_report`` the
tables and plots, ``etb_gym.benchmark_cli`` the command line (``etb-gym benchmark``). The names of the first
three are re-exported here, so ``from etb_gym.benchmark import SCENARIOS, metrics, compute_bound`` works.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from etb_gym.bench_bounds import (BoundJob, attach_bound, bound_fingerprint, bound_jobs,  # noqa: F401 (re-exported)
                                  bound_plant, compute_bound, read_bounds, write_bounds)
from etb_gym.bench_results import (CSV_COLUMNS, KEY_COLUMNS, TEXT_COLUMNS, metrics, read_results,  # noqa: F401
                                   row_key, write_results)
from etb_gym.bench_scenarios import (DEFAULT_CONTROLLERS, DEFAULT_ENV, HOLD_S, QUICK_SCENARIOS,  # noqa: F401
                                     SCENARIOS, SMALL_STEP_SCENARIOS, TAIL_S, VARIANTS, Scenario, Variant,
                                     check_names, model_of, step_band_deg)

from .io import write_atomic

# ------------------------------------------------------------------------------------------------ one run
@dataclass(frozen=True)
class Job:
    env_id: str
    controller: str
    scenario: str
    variant: str
    seed: int
    controller_kwargs: tuple = ()

    @property
    def key(self):
        return (self.env_id, self.controller, self.scenario, self.variant, str(self.seed))


def build_controller(spec: str, env_id: str, kwargs: Mapping | None = None):
    """Built-in controllers are designed on the env's nominal model; other specs get only ``kwargs``."""
    from etb_gym.controllers import CONTROLLERS, make_controller

    kw = dict(kwargs or {})
    if spec in CONTROLLERS:
        kw.setdefault("model", model_of(env_id))
    return make_controller(spec, **kw)


SIGNALS = ("angle", "current", "supply")


def controller_signals(ctrl) -> tuple:
    """What a controller reads besides the reference and its last duty (its ``reads`` attribute; default the
    sensed angle only). The benchmark builds each controller's env with exactly these sensors."""
    sig = tuple(getattr(ctrl, "reads", ("angle",)))
    bad = [x for x in sig if x not in SIGNALS]
    if bad:
        raise ValueError(f"controller {getattr(ctrl, 'name', ctrl)!r} reads {bad}: expected signals from {SIGNALS}")
    return sig


def simulate(job: Job, controller=None):
    """Run one job through the env; returns (trace dict of arrays, controller name)."""
    import gymnasium as gym

    import etb_gym.envs  # noqa: F401  (registers the ids)

    sc = SCENARIOS[job.scenario]
    var = VARIANTS[job.variant]
    ctrl = controller if controller is not None else build_controller(job.controller, job.env_id,
                                                                       dict(job.controller_kwargs))
    sig = controller_signals(ctrl)
    env = gym.make(job.env_id, reference=dict(sc.reference), episode_s=sc.duration_s,
                   observe_current="current" in sig, observe_supply="supply" in sig, **var.env_kwargs(job.env_id))
    obs, info = env.reset(seed=job.seed, options={"angle_deg": sc.initial_deg, "reference": dict(sc.reference)})
    ctrl.reset(seed=job.seed)
    n = int(round(sc.duration_s / env.unwrapped.dt))
    t = np.empty(n + 1)
    ang = np.empty(n + 1)
    ref = np.empty(n + 1)
    duty = np.empty(n + 1)
    cur = np.empty(n + 1)
    t[0], ang[0], ref[0], duty[0], cur[0] = 0.0, info["angle_deg"], info["reference_deg"], 0.0, info["current_A"]
    act = np.zeros(1, np.float32)
    for k in range(1, n + 1):
        act[0] = ctrl.act(obs)
        obs, _, _, trunc, info = env.step(act)
        t[k], ang[k], ref[k], duty[k], cur[k] = info["t_s"], info["angle_deg"], info["reference_deg"], info["duty"], \
            info["current_A"]
    env.close()
    return {"t_s": t, "angle_deg": ang, "reference_deg": ref, "duty": duty, "current_A": cur}, ctrl.name


def run_job(job: Job, want_trace: bool = False):
    """Simulate one job; returns (CSV row, trace or None). Runs in pool workers and Ray tasks alike:
    traces travel back to the driver, which writes every file."""
    ctrl = build_controller(job.controller, job.env_id, dict(job.controller_kwargs))
    trace, _ = simulate(job, ctrl)
    row = {"env": job.env_id, "controller": job.controller, "scenario": job.scenario, "variant": job.variant,
           "seed": job.seed}
    row.update(metrics(trace, SCENARIOS[job.scenario]))
    row["signals"] = "+".join(controller_signals(ctrl))
    return row, (trace if want_trace else None)


def save_trace(trace_dir, job: Job, trace: Mapping) -> None:
    write_atomic(Path(trace_dir) / trace_name(job), lambda fh: np.savez_compressed(fh, **trace))


def load_trace(trace_dir, job: Job):
    p = Path(trace_dir) / trace_name(job)
    if not p.exists():
        return None
    with np.load(p) as z:
        return {k: z[k] for k in z.files}


def trace_name(job: Job) -> str:
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in job.controller)
    return f"{job.env_id}__{safe}__{job.scenario}__{job.variant}__{job.seed}.npz"


# ------------------------------------------------------------------------------------------------ sweep
def make_jobs(controllers: Iterable[str], scenarios: Iterable[str], variants: Iterable[str], seeds: Iterable[int],
              env_id: str = DEFAULT_ENV, controller_kwargs: Mapping | None = None) -> list[Job]:
    """The cross product, validated (unknown scenario / variant / env names list the valid ones). A name given
    twice (``--controller pid --controller pid``) is run once."""
    model_of(env_id)
    controllers, scenarios, variants = (list(dict.fromkeys(x)) for x in (controllers, scenarios, variants))
    seeds = list(dict.fromkeys(int(s) for s in seeds))
    scenarios = check_names("scenario", scenarios, SCENARIOS)
    variants = check_names("variant", variants, VARIANTS)
    ckw = tuple(sorted((controller_kwargs or {}).items()))
    return [Job(env_id, c, s, v, int(sd), ckw) for c in controllers for s in scenarios for v in variants
            for sd in seeds]


def _pool_init():
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")


def run_sweep(jobs: list[Job], out_dir, workers: int = 2, ray_address: str | None = None, resume: bool = False,
              progress: bool = True, trace_filter=None) -> list[dict]:
    """Run the jobs, writing ``results.csv`` in ``out_dir`` after every finished run (atomically).

    ``resume`` keeps the rows already in the file and runs only the missing jobs; without it an existing
    file is replaced. ``workers`` > 1 uses a local process pool; ``ray_address`` ("local" or "auto" or
    "ray://host:port") runs the same jobs as Ray tasks. ``trace_filter(job) -> bool`` selects the runs whose
    traces are saved to ``out_dir/traces`` (default: seed-0 nominal runs, for the plots).

    The physical bound of every (env, step scenario, variant) is computed alongside (the same pool) unless
    ``out_dir/bounds.json`` holds it with the same fingerprint; each row gets bound_s and settling_ratio."""
    from tqdm.auto import tqdm

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "results.csv"
    if resume:              # what a killed writer left: hidden temporaries, never a result (etb_gym.io)
        for f in [*out.glob(".*.tmp"), *(out / "traces").glob(".*.tmp")]:
            f.unlink(missing_ok=True)
    rows = read_results(csv_path) if resume else []
    done = {row_key(r) for r in rows}
    todo = [j for j in jobs if j.key not in done]
    if trace_filter is None:
        def trace_filter(j):
            return j.variant == "nominal" and j.seed == min(x.seed for x in jobs)
    trace_dir = str(out / "traces")
    # build each controller once up front: bad specs fail before any work starts
    for spec in dict.fromkeys((j.controller, j.env_id, j.controller_kwargs) for j in todo):
        build_controller(spec[0], spec[1], dict(spec[2]))
    bounds_path = out / "bounds.json"
    cached = read_bounds(bounds_path)
    bounds, bjobs = _cached_bounds(jobs, cached)
    bar = tqdm(total=len(jobs) + len(bjobs), initial=len(jobs) - len(todo), desc="benchmark", unit="run",
               disable=not progress)

    def finished(task, result):
        if isinstance(task, BoundJob):
            bounds[task.key] = result
            write_bounds(bounds_path, {**cached, **bounds})
            for r in rows:
                attach_bound(r, bounds)
        else:
            row, trace = result
            if trace is not None:
                save_trace(trace_dir, task, trace)
            rows.append(attach_bound(row, bounds))
        write_results(csv_path, rows)
        bar.update(1)

    tasks = [(compute_bound, (bj,), bj) for bj in bjobs] + \
        [(run_job, (j, trace_filter(j)), j) for j in _interleave(todo)]
    try:
        _execute(tasks, finished, workers, ray_address)
    finally:
        bar.close()
    for r in rows:
        attach_bound(r, bounds)
    write_results(csv_path, rows)
    return sorted(rows, key=row_key)


def _cached_bounds(jobs, cached: Mapping) -> tuple[dict, list]:
    """The bounds of ``cached`` (bounds.json) whose fingerprint still matches, and the bound jobs to run."""
    bounds, todo = {}, []
    for bj in bound_jobs(jobs):
        hit = cached.get(bj.key)
        if hit is not None and hit.get("fingerprint") == bound_fingerprint(bj):
            bounds[bj.key] = hit
        else:
            todo.append(bj)
    return bounds, todo


def _execute(tasks, finished, workers: int, ray_address: str | None) -> None:
    """Run ``(fn, args, task)`` tuples in process, in a local spawn pool or on Ray; ``finished(task, result)``
    is called in the driver as each completes."""
    if ray_address:
        _run_ray(tasks, ray_address, finished)
    elif workers <= 1 or len(tasks) <= 1:
        for fn, args, task in tasks:
            finished(task, fn(*args))
    else:
        from concurrent.futures import ProcessPoolExecutor, as_completed
        import multiprocessing as mp

        ctx = mp.get_context("spawn")
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_pool_init) as ex:
            futs = {ex.submit(fn, *args): task for fn, args, task in tasks}
            for f in as_completed(futs):
                finished(futs[f], f.result())


def _interleave(jobs):
    """Spread controllers over the pool so each worker designs every controller early and once."""
    by = {}
    for j in jobs:
        by.setdefault(j.controller, []).append(j)
    out = []
    lists = list(by.values())
    for k in range(max(map(len, lists)) if lists else 0):
        out.extend(lst[k] for lst in lists if k < len(lst))
    return out


def _run_ray(tasks, address, finished):
    try:
        import ray
    except ImportError:
        raise RuntimeError("--ray needs the optional dependency ray: pip install 'etb-gym[ray]'") from None
    started = False
    if not ray.is_initialized():
        if address == "local":
            ray.init(include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
        started = True
    try:
        remotes: dict = {}
        refs = {remotes.setdefault(fn, ray.remote(fn)).remote(*args): task for fn, args, task in tasks}
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for r in ready:
                finished(refs[r], ray.get(r))
    finally:
        if started:
            ray.shutdown()
