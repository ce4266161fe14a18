"""The physical bound of every (env, step scenario, variant) for the benchmark: computed with etb_gym.bound,
cached in process and on disk (bounds.json) under a fingerprint of everything it depends on."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

from etb_gym.bench_scenarios import SCENARIOS, TAIL_S, VARIANTS, model_of, step_band_deg

from .io import write_atomic

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


def _fingerprint(env_id: str, variant: str, **what) -> str:
    """A bound's fingerprint: the plant a variant's env steps (its parameters, model, supply and step) and
    ``what`` else the bound depends on."""
    import hashlib
    import json

    p = bound_plant(env_id, variant)
    spec = {"plant": sorted((k, repr(v)) for k, v in p.params_dict().items()), "model": p.model,
            "supply_V": p.supply.voltage_V, "dt": p.control_period_s, "substeps": p.substeps, **what}
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


def bound_fingerprint(job: BoundJob) -> str:
    """What the bound depends on: the plant's parameters and supply, the step, the band, the horizon and the
    search method. A cached bound is reused only for the same fingerprint."""
    from etb_gym.bound import BOUND_METHOD

    sc = SCENARIOS[job.scenario]
    return _fingerprint(job.env_id, job.variant, method=BOUND_METHOD,
                        step=[sc.step_from_deg, sc.step_to_deg, step_band_deg(sc), sc.duration_s - sc.step_at_s, TAIL_S])


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


def bound_jobs(jobs: Iterable) -> list[BoundJob]:
    """The bound jobs of the step scenarios among ``jobs`` (benchmark Jobs), each (env, scenario, variant) once."""
    return list(dict.fromkeys(BoundJob(j.env_id, j.scenario, j.variant) for j in jobs
                              if SCENARIOS[j.scenario].kind == "step"))


# ------------------------------------------------------------------------------------------------ tracking bounds
# The best RMS error any admissible input achieves on a tracking scenario (noise-free, same plant) is a
# whole-horizon optimal-control solve (scripts/ramp_bound.py, minutes per cell): too slow for the benchmark's
# run, so it is computed offline and committed (baselines/benchmark/ramp_bound.json); the report uses an entry
# only while its fingerprint matches the plant, the reference and the method.
TRACKING_BOUND_METHOD = ("start input + piecewise-linear correction, L-BFGS-B, from the controller's state and "
                         "from rest with preloads (scripts/ramp_bound.py v2)")
TRACKING_BOUNDS_FILE = Path(__file__).resolve().parents[1] / "baselines" / "benchmark" / "ramp_bound.json"


def _random_reference(scenario: str) -> bool:
    from etb_gym.envs.references import RANDOM_REFERENCES

    return SCENARIOS[scenario].reference.get("name") in RANDOM_REFERENCES


def tracking_key(env_id: str, scenario: str, variant: str, seed: int) -> str:
    """A tracking bound's key; a reference that is not drawn from the seed has one bound for every seed."""
    return f"{env_id}|{scenario}|{variant}|{int(seed) if _random_reference(scenario) else '*'}"


def tracking_fingerprint(env_id: str, scenario: str, variant: str, seed: int) -> str:
    """What a tracking bound depends on: the plant's parameters and supply, the reference (and its seed when it
    is drawn from it), the horizon, the scored window and the search method."""
    from etb_gym.bench_scenarios import HOLD_S

    sc = SCENARIOS[scenario]
    return _fingerprint(env_id, variant, reference=sorted((k, repr(v)) for k, v in sc.reference.items()),
                        initial_deg=sc.initial_deg, duration_s=sc.duration_s, scored_from_s=HOLD_S,
                        seed=int(seed) if _random_reference(scenario) else None, method=TRACKING_BOUND_METHOD)


def read_tracking_bounds(path=None) -> dict:
    """{tracking_key: bound RMS [deg]} from a scripts/ramp_bound.py JSON file (default the committed one),
    keeping only entries whose fingerprint matches today's plant, reference and method (a stale entry is
    dropped, never trusted). A missing or damaged file gives {}."""
    import json

    p = Path(TRACKING_BOUNDS_FILE if path is None else path)
    try:
        rows = json.loads(p.read_text())
    except (OSError, ValueError):
        return {}
    out = {}
    for r in rows if isinstance(rows, list) else []:
        try:
            env, sc, var, seed = r["env"], r["scenario"], r["variant"], int(r.get("reference_seed", 0))
            if sc in SCENARIOS and var in VARIANTS and r.get("fingerprint") == tracking_fingerprint(env, sc, var, seed):
                out[tracking_key(env, sc, var, seed)] = float(r["bound_rms_deg"])
                # a variant on the same plant (the noisy sensor: the bound is noise-free) shares the bound
                for other in VARIANTS:
                    k = tracking_key(env, sc, other, seed)
                    if k not in out and tracking_fingerprint(env, sc, other, seed) == r["fingerprint"]:
                        out[k] = float(r["bound_rms_deg"])
        except (KeyError, TypeError, ValueError):
            continue
    return out
