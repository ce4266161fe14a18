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

Module layout: scenarios and variants, one run, the results file, the bounds, the sweep, the command line
(``etb-gym benchmark``); one module because they share the Job/row/bound keys (~680 lines).
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

from etb_gym.bound import settling_index
from etb_gym.variants import PlantVariant

from .io import write_atomic

HOLD_S = 0.3
TAIL_S = 0.1


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
    """A named cell of the robustness grid: a :class:`~etb_gym.variants.PlantVariant` of the env's plant."""

    name: str
    description: str
    plant: PlantVariant = field(default_factory=PlantVariant)

    def env_kwargs(self, env_id: str) -> dict:
        """params / supply_V / sensor arguments of gym.make for this variant (relative to the env's plant)."""
        from etb_gym.plant import make_plant

        kw = {"params": self.plant.overrides(make_plant(model_of(env_id)).params_dict())}
        if self.plant.supply_V is not None:
            kw["supply_V"] = self.plant.supply_V
        if self.plant.sensor_noise_std_deg is not None:
            kw["sensor"] = {"noise_std_rad": math.radians(self.plant.sensor_noise_std_deg)}
        return kw


VARIANTS: dict[str, Variant] = {v.name: v for v in [
    Variant("nominal", "the env's default plant (12 V, 20 C, nominal friction/springs/sensor)"),
    Variant("supply_9V", "battery at 9 V", PlantVariant(supply_V=9.0)),
    Variant("supply_16V", "battery at 16 V", PlantVariant(supply_V=16.0)),
    Variant("coil_-40C", "coil at -40 C: R x (1 + 0.00393 (T - 20))", PlantVariant(coil_temperature_C=-40.0)),
    Variant("coil_125C", "coil at 125 C", PlantVariant(coil_temperature_C=125.0)),
    Variant("friction_-50", "friction (T_c, T_s, sigma2) -50 %", PlantVariant(friction_scale=0.5)),
    Variant("friction_+50", "friction +50 %", PlantVariant(friction_scale=1.5)),
    Variant("springs_-20", "spring preload and rate -20 %", PlantVariant(spring_scale=0.8)),
    Variant("springs_+20", "spring preload and rate +20 %", PlantVariant(spring_scale=1.2)),
    Variant("sensor_noise_high", "angle sensor noise 0.05 deg (5x)", PlantVariant(sensor_noise_std_deg=0.05)),
]}

DEFAULT_CONTROLLERS = ("ptos", "pid", "smc", "pid-plain", "smc-plain")
DEFAULT_ENV = "ETB-3B-v0"
CSV_COLUMNS = ("env", "controller", "scenario", "variant", "seed", "stable", "rise_time_s", "settling_time_s",
               "overshoot_pct", "steady_state_error_deg", "limit_cycle_deg", "iae_deg_s", "rms_error_deg",
               "control_effort", "peak_current_A", "duty_total_variation", "step_start_deg", "bound_s",
               "settling_ratio", "signals")
TEXT_COLUMNS = ("signals",)
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


def metrics(trace: Mapping, sc: Scenario) -> dict:
    """The metrics of the module docstring for one trace."""
    t, phi, r, d, i = (np.asarray(trace[k], float) for k in ("t_s", "angle_deg", "reference_deg", "duty", "current_A"))
    dt = t[1] - t[0]
    k0 = int(round(sc.step_at_s / dt))
    w = slice(k0, None)
    e = r - phi
    tail = t >= t[-1] - TAIL_S + 1e-12
    out = {k: float("nan") for k in CSV_COLUMNS[5:] if k not in TEXT_COLUMNS}
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
        band = step_band_deg(sc)
        out["step_start_deg"] = float(phi[k0])
        k = settling_index(phi[w], b, band, int(TAIL_S / dt))
        if abs(phi[k0] - a) > band:
            # the hold left the plate away from the step's start: no step response to measure (flagged NaN,
            # counted as a miss), where the old rule could report 0 ms for a plate already in the band
            out["settling_time_s"] = float("nan")
        else:
            out["settling_time_s"] = float("nan") if k is None else float(tt[k])
        out["overshoot_pct"] = float(max(0.0, (np.max(y) - 1.0) * 100.0))
        travel = abs(step)
    else:
        travel = float(np.ptp(r))
    out["stable"] = bool(finite and out["steady_state_error_deg"] < 2.0 + 0.05 * travel)
    return out


def step_band_deg(sc: Scenario) -> float:
    """The settling band of a step scenario: max(2 % of the step, 0.1 deg)."""
    return max(0.02 * abs(sc.step_to_deg - sc.step_from_deg), 0.1)


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
        if c in TEXT_COLUMNS:
            out[c] = r.get(c) or ""
        elif c == "stable":
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


# ------------------------------------------------------------------------------------------------ bounds
@dataclass(frozen=True)
class BoundJob:
    """The physical bound of one step scenario on one plant variant (etb_gym.bound)."""

    env_id: str
    scenario: str
    variant: str

    @property
    def key(self) -> str:
        return f"{self.env_id}|{self.scenario}|{self.variant}"


def bound_plant(env_id: str, variant: str):
    """The plant a variant's env steps (parameters and battery; the sensor does not matter to the bound)."""
    from etb_gym.plant import make_plant

    return VARIANTS[variant].plant.apply(make_plant(model_of(env_id)))


def bound_fingerprint(job: BoundJob) -> str:
    """What the bound depends on: the plant's parameters and supply, the step, the band, the horizon and the
    search method. A cached bound is reused only for the same fingerprint."""
    import hashlib
    import json

    from etb_gym.bound import BOUND_METHOD

    p = bound_plant(job.env_id, job.variant)
    sc = SCENARIOS[job.scenario]
    spec = {"plant": sorted((k, repr(v)) for k, v in p.params_dict().items()), "model": p.model,
            "supply_V": p.supply.voltage_V, "dt": p.control_period_s, "substeps": p.substeps,
            "step": [sc.step_from_deg, sc.step_to_deg, step_band_deg(sc), sc.duration_s - sc.step_at_s, TAIL_S],
            "method": BOUND_METHOD}
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


_BOUNDS: dict = {}


def compute_bound(job: BoundJob) -> dict:
    """The bound of one (env, step scenario, variant), cached in process by fingerprint. Returns a JSON-ready
    dict: bound_s (NaN if the search found no settling input), the duty and true angle from the step on."""
    from etb_gym.bound import step_bound

    fp = bound_fingerprint(job)
    hit = _BOUNDS.get(fp)
    if hit is not None:
        return hit
    sc = SCENARIOS[job.scenario]
    b = step_bound(bound_plant(job.env_id, job.variant), sc.step_from_deg, sc.step_to_deg, step_band_deg(sc),
                   sc.duration_s - sc.step_at_s, TAIL_S)
    out = {"fingerprint": fp, "bound_s": b.settling_time_s, "method": b.method, "params": list(b.params),
           "evaluations": b.evaluations, "duty": [round(float(x), 6) for x in b.duty],
           "angle_deg": [round(float(x), 5) for x in b.angle_deg]}
    _BOUNDS[fp] = out
    return out


def read_bounds(path) -> dict:
    import json

    p = Path(path)
    if not p.exists():
        return {}
    try:
        d = json.loads(p.read_text())
    except ValueError:
        return {}              # a damaged cache is recomputed, never trusted
    return d if isinstance(d, dict) else {}


def write_bounds(path, bounds: Mapping) -> None:
    import json

    write_atomic(Path(path), json.dumps(bounds, allow_nan=True))


def attach_bound(row: dict, bounds: Mapping) -> dict:
    """Fill a row's bound_s and settling_ratio (= settling_time_s / bound_s) from the bounds."""
    b = bounds.get(BoundJob(row["env"], row["scenario"], row["variant"]).key)
    bs = float(b["bound_s"]) if b is not None and b.get("bound_s") is not None else float("nan")
    row["bound_s"] = bs
    st = row.get("settling_time_s", float("nan"))
    row["settling_ratio"] = st / bs if bs > 0 and not math.isnan(st) else float("nan")
    return row


def bound_jobs(jobs: Iterable[Job]) -> list[BoundJob]:
    return list(dict.fromkeys(BoundJob(j.env_id, j.scenario, j.variant) for j in jobs
                              if SCENARIOS[j.scenario].kind == "step"))


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
    bounds = {}
    bjobs = []
    for bj in bound_jobs(jobs):
        hit = cached.get(bj.key)
        if hit is not None and hit.get("fingerprint") == bound_fingerprint(bj):
            bounds[bj.key] = hit
        else:
            bjobs.append(bj)
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
    finally:
        bar.close()
    for r in rows:
        attach_bound(r, bounds)
    write_results(csv_path, rows)
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
