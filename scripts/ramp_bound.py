"""The best RMS tracking error any admissible input achieves on a benchmark ramp (noise-free, same plant).

For a tracking scenario (default ``ramp_10_80``) and plant variants (default ``nominal`` and ``supply_9V``):
the plate starts at rest at the ramp's start angle at the ramp's start (what the 0.3 s hold leaves: no
pre-launch during the hold, which a causal controller cannot do), the input is the H-bridge duty per control
period, |d| <= 1 at the variant's battery voltage, and the cost is the benchmark's ``rms_error_deg`` (RMS of
r - phi over the samples from the ramp's start to the scenario's end) on the true, noise-free angle.

Method (a direct whole-horizon optimal-control solve; a bound *found by search*, so an upper bound on the
true optimum: no input outside the searched family was tried):

1. the duty is a controller's duty (default ``ptos``, run through the env with the benchmark's sensor noise,
   so it carries the fine switching structure of a real landing) plus a correction that is piecewise linear
   between knots every ``--knot-ms`` (default 5 ms), clipped to [-1, 1];
2. start: no correction (the controller's duty replayed on the noise-free plant);
3. scipy L-BFGS-B with box constraints on the knots ([-2, 2]), the gradient by forward differences (one
   compiled simulation of the whole horizon per knot), until ``--iterations``.

It also prints the steady-state voltage the ramp's speed needs at each angle on the nominal model
(u = R (T_spring + T_c + b w) / k + k w): where it exceeds the battery the plate cannot follow the ramp.

    python scripts/ramp_bound.py                                   # ramp_10_80, nominal and supply_9V
    python scripts/ramp_bound.py --variants supply_9V --knot-ms 1 --iterations 200
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from etb_gym.bench_bounds import bound_plant  # noqa: E402
from etb_gym.bench_scenarios import DEFAULT_ENV, HOLD_S, SCENARIOS, VARIANTS  # noqa: E402


def reference_deg(sc, t_s: np.ndarray) -> np.ndarray:
    """The scenario's ramp reference at times ``t_s`` (s, from the episode's start)."""
    spec = sc.reference
    a, b, t0, T = spec["start_deg"], spec["end_deg"], spec["at_s"], spec["duration_s"]
    return a + (b - a) * np.clip((t_s - t0) / T, 0.0, 1.0)


class RampProblem:
    def __init__(self, env_id: str, scenario: str, variant: str, knot_ms: float):
        from etb_gym.bound import _Problem

        self.sc = sc = SCENARIOS[scenario]
        if sc.kind != "tracking" or sc.reference.get("name") != "ramp":
            raise SystemExit(f"--scenario {scenario!r} is not a ramp: expected one of "
                             f"{[k for k, s in SCENARIOS.items() if s.reference.get('name') == 'ramp']}")
        self.plant = bound_plant(env_id, variant)
        self.dt = self.plant.control_period_s
        self.n = int(round((sc.duration_s - HOLD_S) / self.dt))
        self.r = reference_deg(sc, HOLD_S + self.dt * np.arange(self.n + 1))
        prob = _Problem(self.plant, sc.reference["start_deg"], sc.reference["end_deg"], 0.1, sc.duration_s)
        self.x0 = prob.x0(0.0)
        step = max(1, int(round(knot_ms * 1e-3 / self.dt)))
        self.knots = np.unique(np.r_[np.arange(0, self.n, step), self.n - 1])
        self.evals = 0
        self.base = np.zeros(self.n)

    def duty(self, z: np.ndarray) -> np.ndarray:
        return np.clip(self.base + np.interp(np.arange(self.n), self.knots, z), -1.0, 1.0)

    def angle(self, duty: np.ndarray) -> np.ndarray:
        self.evals += 1
        return self.plant.simulate(duty=np.clip(duty, -1.0, 1.0), x0=self.x0).angle_deg

    def rms(self, duty: np.ndarray) -> float:
        return float(np.sqrt(np.mean((self.r - self.angle(duty)) ** 2)))

    def cost(self, z: np.ndarray) -> float:
        return float(np.mean((self.r - self.angle(self.duty(z))) ** 2))


def controller_duty(env_id: str, controller: str, scenario: str, variant: str, seed: int):
    """(duty per period from the ramp's start, the run's rms_error_deg) of a controller through the env."""
    from etb_gym.benchmark import Job, metrics, simulate

    trace, _ = simulate(Job(env_id, controller, scenario, variant, seed))
    k0 = int(round(HOLD_S / (trace["t_s"][1] - trace["t_s"][0])))
    return np.asarray(trace["duty"][k0 + 1:], float), metrics(trace, SCENARIOS[scenario])["rms_error_deg"]


def headroom(env_id: str, scenario: str, variant: str):
    """Steady voltage the ramp's speed needs at its angles on the nominal model vs the battery."""
    from etb_gym.controllers.model import NominalModel

    p = bound_plant(env_id, variant)
    m = NominalModel.from_plant(p)
    spec = SCENARIOS[scenario].reference
    w = math.radians(spec["end_deg"] - spec["start_deg"]) / spec["duration_s"]
    k, R = m.torque_constant_Nm_per_A, m.resistance_ohm
    rows = []
    for deg in np.linspace(spec["start_deg"], spec["end_deg"], 8):
        t = m.spring_torque_Nm(math.radians(deg)) + math.copysign(m.coulomb_Nm, w) + m.viscous_Nm_s_per_rad * w
        rows.append((float(deg), R * t / k + k * w))
    return p.supply.voltage_V, w, rows


def solve(env_id, scenario, variant, args):
    from scipy.optimize import minimize

    pr = RampProblem(env_id, scenario, variant, args.knot_ms)
    d_ctrl, rms_env = controller_duty(env_id, args.controller, scenario, variant, args.seed)
    d_ctrl = d_ctrl[:pr.n]
    rms_replay = pr.rms(d_ctrl)
    pr.base = d_ctrl
    z0 = np.zeros(len(pr.knots))
    t0 = time.perf_counter()
    res = minimize(pr.cost, z0, method="L-BFGS-B", bounds=[(-2.0, 2.0)] * len(z0),
                   options={"maxiter": args.iterations, "eps": 1e-4})
    d_best = pr.duty(res.x)
    phi = pr.angle(d_best)
    e = pr.r - phi
    worst = int(np.argmax(np.abs(e)))
    return {"env": env_id, "scenario": scenario, "variant": variant, "supply_V": pr.plant.supply.voltage_V,
            "controller": args.controller, "controller_rms_deg_env": rms_env,
            "controller_rms_deg_replayed_noise_free": rms_replay, "bound_rms_deg": float(np.sqrt(np.mean(e ** 2))),
            "bound_max_abs_error_deg": float(abs(e[worst])), "bound_worst_at_s_after_start": worst * pr.dt,
            "bound_saturated_fraction": float(np.mean(np.abs(d_best) > 0.999)),
            "knots": len(pr.knots), "iterations": int(res.nit), "simulations": pr.evals,
            "solve_s": time.perf_counter() - t0}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--env", default=DEFAULT_ENV)
    ap.add_argument("--scenario", default="ramp_10_80")
    ap.add_argument("--variants", nargs="+", default=["nominal", "supply_9V"], choices=sorted(VARIANTS))
    ap.add_argument("--controller", default="ptos", help="controller whose duty starts the search (default ptos)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--knot-ms", type=float, default=5.0, help="knot spacing of the correction (ms, default 5)")
    ap.add_argument("--iterations", type=int, default=60, help="L-BFGS-B iterations (default 60)")
    ap.add_argument("--json", type=Path, help="also write the results to this JSON file")
    args = ap.parse_args(argv)
    if args.knot_ms <= 0:
        ap.error(f"--knot-ms = {args.knot_ms}: expected a positive spacing in ms")
    out = []
    for v in args.variants:
        V, w, rows = headroom(args.env, args.scenario, v)
        print(f"{args.scenario} / {v}: battery {V:g} V; steady voltage for {math.degrees(w):.0f} deg/s at "
              + ", ".join(f"{a:.0f} deg {u:.2f} V" for a, u in rows))
        r = solve(args.env, args.scenario, v, args)
        out.append(r)
        print(f"  {args.controller}: RMS {r['controller_rms_deg_env']:.3f} deg (env, seed {args.seed}), "
              f"{r['controller_rms_deg_replayed_noise_free']:.3f} deg (its duty replayed noise-free); "
              f"best input found: RMS {r['bound_rms_deg']:.4f} deg, max |e| {r['bound_max_abs_error_deg']:.3f} deg "
              f"at {1000 * r['bound_worst_at_s_after_start']:.0f} ms, saturated {100 * r['bound_saturated_fraction']:.0f} %"
              f" ({r['knots']} knots, {r['iterations']} iterations, {r['simulations']} simulations, "
              f"{r['solve_s']:.0f} s)")
    if args.json:
        from etb_gym.io import write_atomic

        write_atomic(args.json, json.dumps(out, indent=2) + "\n")
    return out


if __name__ == "__main__":
    main()
