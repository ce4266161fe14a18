"""The controller benchmark: controllers x scenarios x plant variants x seeds, all through the Gymnasium env.

Every run builds ``gym.make(env_id, params=<variant>, supply_V=..., sensor=...)`` and resets it with the
scenario's reference and initial angle and the run's seed, so every controller sees exactly what the env
observes, on identical plants, references (random ones are drawn from the seed) and sensor noise.

Scenarios start with a 0.3 s hold at the initial angle (the controller brings the plate to rest under
control) before the step/ramp/profile; step metrics are measured from the step on the *true* angle:

    rise_time_s             10 % -> 90 % of the step
    settling_time_s         last exit from the band max(2 % of |step|, 0.1 deg) (0.1 deg: sensor resolution
                            floor, so for a 0.5 deg step it is the "reach +-0.1 deg and stay" time)
    overshoot_pct           largest excursion beyond the final reference, % of |step|
    steady_state_error_deg  mean |r - phi| over the last 0.1 s
    limit_cycle_deg         half the peak-to-peak of phi over the last 0.1 s (a sustained oscillation)
    iae_deg_s, rms_error_deg  integral / RMS of |r - phi| over the evaluated window (from the step, or all
                            of a tracking scenario after the hold)
    control_effort          RMS duty over the window;  peak_current_A  max |i|
    duty_total_variation    sum |d_k - d_{k-1}| over the window (chattering)
    stable                  finite, and |r - phi| < 2 deg + 5 % of the travel at the end
"""
from __future__ import annotations

import csv
import io
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np

from .io import write_atomic

HOLD_S = 0.3
TAIL_S = 0.1
COPPER_ALPHA_PER_K = 0.00393


# ------------------------------------------------------------------------------------------------ scenarios
@dataclass(frozen=True)
class Scenario:
    name: str
    kind: str                      # "step" or "tracking"
    reference: Mapping             # env reference spec (dict), times include the hold
    initial_deg: float
    duration_s: float
    step_at_s: float = HOLD_S
    step_from_deg: float = float("nan")
    step_to_deg: float = float("nan")
    description: str = ""


def _step(name, a, b, after_s=0.5, desc=""):
    return Scenario(name, "step", {"name": "step", "initial_deg": a, "final_deg": b, "at_s": HOLD_S}, a,
                    HOLD_S + after_s, HOLD_S, a, b, desc or f"step {a:g} -> {b:g} deg")


SCENARIOS: dict[str, Scenario] = {s.name: s for s in [
    _step("step_10_80", 10.0, 80.0, desc="large opening step 10 -> 80 deg"),
    _step("step_80_10", 80.0, 10.0, desc="large closing step 80 -> 10 deg"),
    _step("small_step_limp_home", 3.0, 3.5, desc="+0.5 deg out of limp-home (3 deg)"),
    _step("small_step_limp_home_neg", 3.0, 2.5, desc="-0.5 deg below limp-home"),
    _step("step2_limp_home", 3.0, 5.0, desc="+2 deg out of limp-home"),
    _step("step2_limp_home_neg", 3.0, 1.0, desc="-2 deg below limp-home"),
    _step("small_step_40", 40.0, 40.5, desc="+0.5 deg at part load"),
    _step("small_step_40_neg", 40.0, 39.5, desc="-0.5 deg at part load"),
    _step("step2_40", 40.0, 42.0, desc="+2 deg at part load"),
    _step("step2_40_neg", 40.0, 38.0, desc="-2 deg at part load"),
    Scenario("ramp_10_80", "tracking", {"name": "ramp", "start_deg": 10.0, "end_deg": 80.0, "at_s": HOLD_S,
                                        "duration_s": 0.5}, 10.0, HOLD_S + 0.7,
             description="ramp 10 -> 80 deg in 0.5 s (140 deg/s), then hold"),
    Scenario("ramp_80_10", "tracking", {"name": "ramp", "start_deg": 80.0, "end_deg": 10.0, "at_s": HOLD_S,
                                        "duration_s": 0.5}, 80.0, HOLD_S + 0.7,
             description="ramp 80 -> 10 deg in 0.5 s, then hold"),
    Scenario("pedal", "tracking", {"name": "pedal", "duration_s": 2.0}, 4.0, 2.0,
             description="pedal-like driving profile drawn from the seed (idle, part load, WOT tip-in/out)"),
]}

QUICK_SCENARIOS = ("step_10_80", "step_80_10", "small_step_limp_home", "small_step_limp_home_neg",
                   "small_step_40", "small_step_40_neg", "ramp_10_80", "pedal")
SMALL_STEP_SCENARIOS = ("small_step_limp_home", "small_step_limp_home_neg", "small_step_40", "small_step_40_neg")


# ------------------------------------------------------------------------------------------------ variants
@dataclass(frozen=True)
class Variant:
    name: str
    description: str
    supply_V: float | None = None
    coil_temperature_C: float | None = None
    friction_scale: float = 1.0
    spring_scale: float = 1.0
    sensor: Mapping = field(default_factory=dict)

    def env_kwargs(self, env_id: str) -> dict:
        """params / supply_V / sensor arguments of gym.make for this variant (relative to the env's plant)."""
        from etb_gym.plant import make_plant

        nom = make_plant(model_of(env_id)).params_dict()
        params = {}
        if self.coil_temperature_C is not None and "drive.resistance_ohm" in nom:
            params["drive.resistance_ohm"] = nom["drive.resistance_ohm"] * (
                1.0 + COPPER_ALPHA_PER_K * (self.coil_temperature_C - 20.0))
        if self.friction_scale != 1.0:
            for f in ("coulomb_Nm", "static_Nm", "viscous_Nm_s_per_rad"):
                if f"friction.{f}" in nom:
                    params[f"friction.{f}"] = nom[f"friction.{f}"] * self.friction_scale
        if self.spring_scale != 1.0:
            for f in ("preload_Nm", "rate_Nm_per_rad"):
                if f"spring.{f}" in nom:
                    params[f"spring.{f}"] = nom[f"spring.{f}"] * self.spring_scale
        kw = {"params": params}
        if self.supply_V is not None:
            kw["supply_V"] = self.supply_V
        if self.sensor:
            kw["sensor"] = dict(self.sensor)
        return kw


VARIANTS: dict[str, Variant] = {v.name: v for v in [
    Variant("nominal", "the env's default plant (12 V, 20 C, nominal friction/springs/sensor)"),
    Variant("supply_9V", "battery at 9 V", supply_V=9.0),
    Variant("supply_16V", "battery at 16 V", supply_V=16.0),
    Variant("coil_-40C", "coil at -40 C: R x (1 + 0.00393 (T - 20))", coil_temperature_C=-40.0),
    Variant("coil_125C", "coil at 125 C", coil_temperature_C=125.0),
    Variant("friction_-50", "friction (T_c, T_s, sigma2) -50 %", friction_scale=0.5),
    Variant("friction_+50", "friction +50 %", friction_scale=1.5),
    Variant("springs_-20", "spring preload and rate -20 %", spring_scale=0.8),
    Variant("springs_+20", "spring preload and rate +20 %", spring_scale=1.2),
    Variant("sensor_noise_high", "angle sensor noise 0.05 deg (5x)", sensor={"noise_std_rad": math.radians(0.05)}),
]}

DEFAULT_CONTROLLERS = ("pid", "smc")
DEFAULT_ENV = "ETB-3B-v0"
CSV_COLUMNS = ("env", "controller", "scenario", "variant", "seed", "stable", "rise_time_s", "settling_time_s",
               "overshoot_pct", "steady_state_error_deg", "limit_cycle_deg", "iae_deg_s", "rms_error_deg",
               "control_effort", "peak_current_A", "duty_total_variation")
KEY_COLUMNS = ("env", "controller", "scenario", "variant", "seed")


def model_of(env_id: str) -> str:
    from etb_gym.envs import ENV_IDS

    if env_id not in ENV_IDS:
        raise ValueError(f"unknown env {env_id!r}: valid are {list(ENV_IDS)}")
    return env_id.split("-")[1]


def check_names(kind: str, names: Iterable[str], valid: Mapping) -> list[str]:
    out = list(names)
    bad = [n for n in out if n not in valid]
    if bad:
        raise ValueError(f"unknown {kind}(s) {bad}: valid are {list(valid)}")
    return out


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


def simulate(job: Job, controller=None):
    """Run one job through the env; returns (trace dict of arrays, controller name)."""
    import gymnasium as gym

    import etb_gym.envs  # noqa: F401  (registers the ids)

    sc = SCENARIOS[job.scenario]
    var = VARIANTS[job.variant]
    ctrl = controller if controller is not None else build_controller(job.controller, job.env_id,
                                                                       dict(job.controller_kwargs))
    env = gym.make(job.env_id, reference=dict(sc.reference), episode_s=sc.duration_s, **var.env_kwargs(job.env_id))
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


def metrics(trace: Mapping, sc: Scenario) -> dict:
    """The metrics of the module docstring for one trace."""
    t, phi, r, d, i = (np.asarray(trace[k], float) for k in ("t_s", "angle_deg", "reference_deg", "duty", "current_A"))
    dt = t[1] - t[0]
    k0 = int(round(sc.step_at_s / dt))
    w = slice(k0, None)
    e = r - phi
    tail = t >= t[-1] - TAIL_S + 1e-12
    out = {k: float("nan") for k in CSV_COLUMNS[5:]}
    finite = bool(np.all(np.isfinite(phi)))
    out["iae_deg_s"] = float(np.sum(np.abs(e[w])) * dt)
    out["rms_error_deg"] = float(np.sqrt(np.mean(e[w] ** 2)))
    out["control_effort"] = float(np.sqrt(np.mean(d[w] ** 2)))
    out["peak_current_A"] = float(np.max(np.abs(i[w])))
    out["duty_total_variation"] = float(np.sum(np.abs(np.diff(d[k0:]))))
    out["steady_state_error_deg"] = float(np.mean(np.abs(e[tail])))
    out["limit_cycle_deg"] = float(0.5 * np.ptp(phi[tail]))
    if sc.kind == "step":
        a, b = sc.step_from_deg, sc.step_to_deg
        step = b - a
        y = (phi[w] - a) / step                              # normalized response, 0 -> 1
        tt = t[w] - t[k0]
        k10 = np.nonzero(y >= 0.1)[0]
        k90 = np.nonzero(y >= 0.9)[0]
        out["rise_time_s"] = float(tt[k90[0]] - tt[k10[0]]) if k10.size and k90.size else float("nan")
        band = max(0.02 * abs(step), 0.1)
        outside = np.nonzero(np.abs(phi[w] - b) > band)[0]
        if outside.size == 0:
            out["settling_time_s"] = 0.0
        elif outside[-1] + 1 < tt.size and outside[-1] < tt.size - int(TAIL_S / dt):
            out["settling_time_s"] = float(tt[outside[-1] + 1])
        else:
            out["settling_time_s"] = float("nan")           # never settled within the scenario
        out["overshoot_pct"] = float(max(0.0, (np.max(y) - 1.0) * 100.0))
        travel = abs(step)
    else:
        travel = float(np.ptp(r))
    out["stable"] = bool(finite and out["steady_state_error_deg"] < 2.0 + 0.05 * travel)
    return out


def run_job(job: Job, want_trace: bool = False):
    """Simulate one job; returns (CSV row, trace or None). Runs in pool workers and Ray tasks alike:
    traces travel back to the driver, which writes every file."""
    trace, _ = simulate(job)
    row = {"env": job.env_id, "controller": job.controller, "scenario": job.scenario, "variant": job.variant,
           "seed": job.seed}
    row.update(metrics(trace, SCENARIOS[job.scenario]))
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


# ------------------------------------------------------------------------------------------------ results file
def read_results(path) -> list[dict]:
    p = Path(path)
    if not p.exists():
        return []
    with open(p, newline="") as fh:
        rows = list(csv.DictReader(fh))
    missing = [c for c in KEY_COLUMNS if rows and c not in rows[0]]
    if missing:
        raise ValueError(f"{p}: not a benchmark results file (missing columns {missing})")
    return [_parse_row(r) for r in rows]


def _parse_row(r):
    out = dict(r)
    out["seed"] = int(r["seed"])
    for c in CSV_COLUMNS[5:]:
        if c == "stable":
            out[c] = str(r[c]).lower() == "true"
        else:
            out[c] = float(r[c]) if r.get(c, "") not in ("", None) else float("nan")
    return out


def write_results(path, rows: list[dict]) -> None:
    """Write all rows atomically (tmp file + os.replace), sorted by key for a stable file."""
    rows = sorted(rows, key=lambda r: (r["env"], r["controller"], r["scenario"], r["variant"], int(r["seed"])))
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, fieldnames=CSV_COLUMNS)
    w.writeheader()
    for r in rows:
        w.writerow({c: _fmt(r[c]) for c in CSV_COLUMNS})
    write_atomic(path, buf.getvalue())


def _fmt(v):
    if isinstance(v, bool):
        return str(v)
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return v


def row_key(r) -> tuple:
    return (r["env"], r["controller"], r["scenario"], r["variant"], str(r["seed"]))


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
    traces are saved to ``out_dir/traces`` (default: seed-0 nominal runs, for the plots)."""
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
    bar = tqdm(total=len(jobs), initial=len(jobs) - len(todo), desc="benchmark", unit="run", disable=not progress)

    def done_row(job, result):
        row, trace = result
        if trace is not None:
            save_trace(trace_dir, job, trace)
        rows.append(row)
        write_results(csv_path, rows)
        bar.update(1)

    try:
        if ray_address:
            _run_ray(todo, trace_filter, ray_address, done_row)
        elif workers <= 1 or len(todo) <= 1:
            for j in todo:
                done_row(j, run_job(j, trace_filter(j)))
        else:
            from concurrent.futures import ProcessPoolExecutor, as_completed
            import multiprocessing as mp

            ctx = mp.get_context("spawn")
            with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_pool_init) as ex:
                futs = {ex.submit(run_job, j, trace_filter(j)): j for j in _interleave(todo)}
                for f in as_completed(futs):
                    done_row(futs[f], f.result())
    finally:
        bar.close()
    return sorted(rows, key=row_key)


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


def _run_ray(jobs, trace_filter, address, done_row):
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
        remote = ray.remote(run_job)
        refs = {remote.remote(j, trace_filter(j)): j for j in _interleave(jobs)}
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for r in ready:
                done_row(refs[r], ray.get(r))
    finally:
        if started:
            ray.shutdown()
