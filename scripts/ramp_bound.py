"""The best RMS tracking error any admissible input achieves on a benchmark tracking scenario (noise-free, same
plant), and a lower bound on it from the start of the first move.

For a tracking scenario (``ramp_10_80``, ``ramp_80_10``, ``pedal``: the reference as the env shows it for the
seed, read from a controller's run) and plant variants (their parameters and battery; the sensor does not
matter): the plate starts at the last sample before the reference first moves, either in the controller's own
state there (its run's duty replayed on the plant from the env's initial state, which reproduces the env's
true angle exactly: checked) or at rest at the reference's first value with the coil current anywhere in the
band static friction holds (``--preloads``: fractions of the way from the spring-balancing current to the
band's edge, towards the first move -- what a controller can leave there during the hold without knowing when
the move comes). The input is the H-bridge duty per control
period, |d| <= 1 at the variant's battery voltage; the cost is the benchmark's ``rms_error_deg`` (RMS of
r - phi over the samples from the end of the 0.3 s hold to the scenario's end) on the true, noise-free angle.

**Upper estimate: a direct whole-horizon optimal-control solve**, a bound *found by search* (no input
outside the searched family was tried, so the true optimum can only be lower):

1. the duty is a start input plus a correction that is piecewise linear between knots every ``--knot-ms``
   (default 5 ms), clipped to [-1, 1]; start inputs: a controller's duty through the env with the
   benchmark's sensor noise (``--controller``, default ``ptos``; for ramps seeds 0..``--start-seeds``-1: it
   carries the fine switching structure of a real landing), once from the controller's own state and once per
   preload (from its own state the start scores the controller's RMS, so the result is never above it);
2. scipy L-BFGS-B with box constraints on the knots ([-2, 2]); the gradient by one-sided differences
   (1e-4), each knot's simulation restarted from the base trajectory's state at the knot before it (a knot
   moves the duty only from there on), until ``--iterations``;
3. the best result is refined on knots ``--refine-knot-ms`` apart (default 2 ms; several values: successive
   refinements, e.g. ``2 1``) for ``--refine-iterations`` each.

For the pedal the reference's later moves are known to the search from the start (a causal controller sees
each tip-in only when it begins), so that bound is optimistic in information and pessimistic by search.

**Lower bound** (``lower_bound_rms_deg``): from the resting start with the coil at the static-friction
edge (the most a plate at rest can be given), full drive towards the move puts the plate furthest along at
every sample of the first few milliseconds (checked: no input the search tried, from any start, got ahead of
it before it first reaches the reference); until it reaches the reference, no admissible input can have a
smaller error at a sample than r - phi_full_drive. The sum of those squares over the scored samples, over the
scored sample count, is a lower bound on any input's mean square error (everything after that first
crossing is counted as zero). It holds for any causal or non-causal controller on this plant from a plate at
rest at the move (``ahead_of_full_drive_deg`` of each start records how far its result got ahead of full
drive before the crossing: negative in every committed run, the controller's own start included).

The script also prints the steady-state voltage a ramp's speed needs at each angle on the nominal model
(u = R (T_spring + T_c + b w) / k + k w): where it exceeds the battery the plate cannot follow the ramp.

    python scripts/ramp_bound.py                                   # ramp_10_80, nominal and supply_9V
    # the committed ramp cells (one command per line):
    python scripts/ramp_bound.py --variants nominal supply_9V coil_125C --preloads --iterations 80 --refine-knot-ms 2 1 --refine-iterations 60 --json baselines/benchmark/ramp_bound.json
    python scripts/ramp_bound.py --scenario pedal --variants nominal supply_9V --preloads --iterations 60 --refine-iterations 40 --json out.json
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

from etb_gym.bench_bounds import TRACKING_BOUND_METHOD, bound_plant, tracking_fingerprint  # noqa: E402
from etb_gym.bench_scenarios import DEFAULT_ENV, HOLD_S, SCENARIOS, VARIANTS  # noqa: E402

EPS = 1e-4                       # one-sided difference of a knot (duty units)
PRELOADS = (0.0, 0.95)           # as etb_gym.bound: equilibrium, 95 % of the way to the static-friction edge


class TrackingProblem:
    """One tracking scenario on one plant variant from a resting start (module docstring)."""

    def __init__(self, env_id: str, scenario: str, variant: str, reference_deg: np.ndarray, preload: float,
                 x0: np.ndarray | None = None):
        from etb_gym.bound import _Problem

        self.sc = sc = SCENARIOS[scenario]
        if sc.kind != "tracking":
            raise SystemExit(f"--scenario {scenario!r} is not a tracking scenario: expected one of "
                             f"{[k for k, s in SCENARIOS.items() if s.kind == 'tracking']}")
        self.plant = bound_plant(env_id, variant)
        self.dt = self.plant.control_period_s
        r = np.asarray(reference_deg, float)
        moved = np.nonzero(np.abs(r - r[0]) > 1e-9)[0]
        if moved.size == 0:
            raise SystemExit(f"the reference of {scenario!r} never moves: nothing to track")
        self.k_start = int(moved[0]) - 1                   # last sample before the first move
        self.k0 = int(round(HOLD_S / self.dt))             # the benchmark scores samples k0..n
        self.n_scored = r.size - self.k0
        self.r = r[self.k_start:]                          # reference at samples k_start..n
        self.n = self.r.size - 1                           # control periods simulated
        self.w = (np.arange(self.n + 1) + self.k_start >= self.k0).astype(float)   # scored samples
        self.direction = 1.0 if r[moved[0]] > r[0] else -1.0
        prob = _Problem(self.plant, float(r[0]), float(r[0]) + self.direction, 0.1, sc.duration_s)
        self.preload = preload                             # NaN: the given state x0
        self.x0 = np.asarray(x0, float) if x0 is not None else prob.x0(preload)
        self.evals = 0
        self.base = np.zeros(self.n)
        self.set_knots(5.0)

    def set_knots(self, knot_ms: float):
        step = max(1, int(round(knot_ms * 1e-3 / self.dt)))
        self.knots = np.unique(np.r_[np.arange(0, self.n, step), self.n - 1])

    def correction(self, z):
        return np.interp(np.arange(self.n), self.knots, z)

    def duty(self, z: np.ndarray) -> np.ndarray:
        return np.clip(self.base + self.correction(z), -1.0, 1.0)

    def run(self, duty: np.ndarray, start: int = 0, x0=None):
        """States at samples start..n under duty[start:], from x0 (default the problem's start)."""
        self.evals += 1
        return self.plant.simulate(duty=np.clip(duty[start:], -1.0, 1.0),
                                   x0=self.x0 if x0 is None else x0).states

    def angle(self, duty: np.ndarray) -> np.ndarray:
        return np.degrees(self.run(duty)[:, 0])

    def sse(self, angle_deg: np.ndarray, start: int = 0) -> float:
        e = self.r[start:] - angle_deg
        return float(np.sum(self.w[start:] * e * e))

    def rms(self, duty: np.ndarray) -> float:
        return math.sqrt(self.sse(self.angle(duty)) / self.n_scored)

    def cost_grad(self, z: np.ndarray):
        """Mean square over the scored samples and its gradient in the knots (one-sided differences, each
        knot's run restarted from the base trajectory at the knot before it)."""
        d = self.duty(z)
        X = self.run(d)
        f = self.sse(np.degrees(X[:, 0]))
        g = np.empty_like(z)
        for j in range(z.size):
            a = int(self.knots[j - 1]) if j > 0 else 0
            zp = z.copy()
            zp[j] += EPS
            dp = self.duty(zp)
            ang = np.degrees(self.run(dp, a, X[a])[:, 0])
            g[j] = (self.sse(ang, a) - self.sse(np.degrees(X[a:, 0]), a)) / EPS
        return f / self.n_scored, g / self.n_scored

    def solve(self, base: np.ndarray, knot_ms: float, iterations: int):
        """L-BFGS-B on the correction to ``base``; returns the best duty found."""
        from scipy.optimize import minimize

        self.base = np.asarray(base, float)[:self.n].copy()
        self.set_knots(knot_ms)
        res = minimize(self.cost_grad, np.zeros(len(self.knots)), jac=True, method="L-BFGS-B",
                       bounds=[(-2.0, 2.0)] * len(self.knots), options={"maxiter": iterations})
        return self.duty(res.x), int(res.nit)

    def full_drive_lower_bound(self):
        """(lower bound on the RMS, the full-drive angle from the edge of the static band, the sample where it
        first reaches the reference) -- the module docstring's lower bound."""
        from etb_gym.bound import _Problem

        prob = _Problem(self.plant, float(self.r[0]), float(self.r[0]) + self.direction, 0.1, self.sc.duration_s)
        phi = np.degrees(self.plant.simulate(duty=np.full(self.n, self.direction), x0=prob.x0(1.0)).states[:, 0])
        behind = self.direction * (self.r - phi)
        ahead = np.nonzero((behind <= 0) & (np.arange(self.n + 1) > 0))[0]
        kc = int(ahead[0]) if ahead.size else self.n + 1
        e = np.clip(behind[:kc], 0.0, None)
        return math.sqrt(float(np.sum(self.w[:kc] * e * e)) / self.n_scored), phi, kc


def controller_run(env_id: str, controller: str, scenario: str, variant: str, seed: int):
    """(duty per period from sample 0, reference per sample, the run's rms_error_deg, the plant's states per
    sample: the run's duty replayed on the noise-free plant from the env's initial state, which reproduces
    the env's true angle exactly) through the env."""
    from etb_gym.benchmark import Job, metrics, simulate

    trace, _ = simulate(Job(env_id, controller, scenario, variant, seed))
    duty = np.asarray(trace["duty"][1:], float)
    p = bound_plant(env_id, variant)
    X = p.simulate(duty=duty, x0=p.initial_state(math.radians(SCENARIOS[scenario].initial_deg))).states
    if np.max(np.abs(np.degrees(X[:, 0]) - trace["angle_deg"])) > 1e-6:
        raise RuntimeError(f"{controller} {scenario} {variant} seed {seed}: the replayed duty does not reproduce "
                           "the env's angle (the env is not the bound's plant)")
    return duty, np.asarray(trace["reference_deg"], float), metrics(trace, SCENARIOS[scenario])["rms_error_deg"], X


def headroom(env_id: str, scenario: str, variant: str):
    """Steady voltage a ramp's speed needs at its angles on the nominal model vs the battery (None: no ramp)."""
    from etb_gym.controllers.model import NominalModel

    spec = SCENARIOS[scenario].reference
    if spec.get("name") != "ramp":
        return None
    p = bound_plant(env_id, variant)
    m = NominalModel.from_plant(p)
    w = math.radians(spec["end_deg"] - spec["start_deg"]) / spec["duration_s"]
    k, R = m.torque_constant_Nm_per_A, m.resistance_ohm
    rows = []
    for deg in np.linspace(spec["start_deg"], spec["end_deg"], 8):
        t = m.spring_torque_Nm(math.radians(deg)) + math.copysign(m.coulomb_Nm, w) + m.viscous_Nm_s_per_rad * w
        rows.append((float(deg), R * t / k + k * w))
    return p.supply.voltage_V, w, rows


def solve(env_id, scenario, variant, seed, args):
    """One (scenario, variant, reference seed): every start, the best refined, the lower bound."""
    t0 = time.perf_counter()
    pedal = SCENARIOS[scenario].reference.get("name") == "pedal"
    seeds = [seed] if pedal else list(range(args.start_seeds))     # the pedal is drawn from the seed
    runs = [controller_run(env_id, args.controller, scenario, variant, s) for s in seeds]
    ref = runs[0][1]
    starts, evals, best = [], 0, None
    lb = None
    todo = [(pre, s) for pre in [float("nan")] + list(args.preloads) for s in range(len(runs))]
    for pre, s in todo:
        duty, _, rms_env, X = runs[s]
        k_start = int(np.nonzero(np.abs(ref - ref[0]) > 1e-9)[0][0]) - 1
        # nan: the controller's own state where the reference starts to move
        pr = TrackingProblem(env_id, scenario, variant, ref, pre, X[k_start] if math.isnan(pre) else None)
        if lb is None:
            lb, phi_fd, kc = pr.full_drive_lower_bound()
        base = duty[pr.k_start:]
        rms_replay = pr.rms(base)
        d, nit = pr.solve(base, args.knot_ms, args.iterations)
        rms = pr.rms(d)
        ang = pr.angle(d)
        ahead = float(np.max(pr.direction * (ang[1:kc] - phi_fd[1:kc]))) if kc > 1 else float("-inf")
        starts.append({"controller_seed": seeds[s], "start": "controller state" if math.isnan(pre) else
                       f"rest, preload {pre:g}",
                       "controller_rms_deg_env": rms_env, "start_rms_deg_replayed_noise_free": rms_replay,
                       "rms_deg": rms, "iterations": nit, "ahead_of_full_drive_deg": ahead})
        print(f"    start {args.controller} seed {starts[-1]['controller_seed']}, {starts[-1]['start']}: env "
              f"{rms_env:.4f}, replayed {rms_replay:.4f} -> {rms:.4f} deg ({nit} it.)", flush=True)
        if best is None or rms < best[0]:
            best = (rms, d, pr)
        evals += pr.evals
    rms, d, pr = best
    n_it, stages = 0, []
    for knot_ms in args.refine_knot_ms:
        pr.evals = 0
        d2, nit = pr.solve(d, knot_ms, args.refine_iterations)
        n_it += nit
        evals += pr.evals
        rms2 = pr.rms(d2)
        stages.append({"knot_ms": knot_ms, "iterations": nit, "rms_deg": rms2})
        print(f"    refined on {knot_ms:g} ms knots: {rms2:.4f} deg ({nit} it.)", flush=True)
        if rms2 < rms:
            rms, d = rms2, d2
    phi = pr.angle(d)
    e = pr.w * (pr.r - phi)
    worst = int(np.argmax(np.abs(e)))
    sq = (pr.r - phi) ** 2 * pr.w
    first = np.arange(pr.n + 1) + pr.k_start < pr.k_start + 1 + int(round(0.02 / pr.dt))
    return {"env": env_id, "scenario": scenario, "variant": variant, "reference_seed": seed,
            "fingerprint": tracking_fingerprint(env_id, scenario, variant, seed), "method": TRACKING_BOUND_METHOD,
            "supply_V": pr.plant.supply.voltage_V, "controller": args.controller,
            "controller_seeds": seeds, "controller_rms_deg_env": float(np.mean([r[2] for r in runs])),
            "bound_rms_deg": rms, "lower_bound_rms_deg": lb,
            "bound_share_first_20ms": float(np.sum(sq[first]) / max(np.sum(sq), 1e-30)),
            "bound_max_abs_error_deg": float(abs(e[worst])),
            "bound_worst_at_s": (worst + pr.k_start) * pr.dt,
            "bound_start": "controller state" if math.isnan(pr.preload) else f"rest, preload {pr.preload:g}",
            "bound_saturated_fraction": float(np.mean(np.abs(d) > 0.999)),
            "starts": starts, "knot_ms": args.knot_ms, "iterations": args.iterations,
            "refine_knot_ms": args.refine_knot_ms, "refine_iterations": n_it, "refine_stages": stages,
            "simulations": evals,
            "solve_s": time.perf_counter() - t0}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--env", default=DEFAULT_ENV)
    tracking = [k for k, s in SCENARIOS.items() if s.kind == "tracking"]
    ap.add_argument("--scenario", default="ramp_10_80", choices=tracking)
    ap.add_argument("--variants", nargs="+", default=["nominal", "supply_9V"], choices=sorted(VARIANTS))
    ap.add_argument("--seed", type=int, default=0, help="the reference's seed (the pedal is drawn from it)")
    ap.add_argument("--controller", default="ptos", help="controller whose duty starts the search (default ptos)")
    ap.add_argument("--start-seeds", type=int, default=1,
                    help="ramps: the controller's runs of seeds 0..N-1 are the starts (default 1)")
    ap.add_argument("--preloads", type=float, nargs="*", default=list(PRELOADS),
                    help="start currents from rest, fractions of the static band towards the move (default 0 0.95; "
                         "none given: only the controller's own state)")
    ap.add_argument("--knot-ms", type=float, default=5.0, help="knot spacing of the correction (ms, default 5)")
    ap.add_argument("--iterations", type=int, default=30, help="L-BFGS-B iterations per start (default 30)")
    ap.add_argument("--refine-knot-ms", type=float, nargs="*", default=[2.0],
                    help="knot spacings of successive refinements of the best start (ms, default 2; none = no "
                         "refinement)")
    ap.add_argument("--refine-iterations", type=int, default=20)
    ap.add_argument("--json", type=Path, help="merge the results into this JSON file (by env, scenario, variant, "
                                              "seed)")
    args = ap.parse_args(argv)
    if args.knot_ms <= 0:
        ap.error(f"--knot-ms = {args.knot_ms}: expected a positive spacing in ms")
    if any(k <= 0 for k in args.refine_knot_ms):
        ap.error(f"--refine-knot-ms {args.refine_knot_ms}: expected positive spacings in ms")
    if args.start_seeds < 1:
        ap.error(f"--start-seeds = {args.start_seeds}: expected at least 1")
    if any(not 0.0 <= p <= 1.0 for p in args.preloads):
        ap.error(f"--preloads {args.preloads}: expected fractions in [0, 1]")
    out = []
    for v in args.variants:
        hr = headroom(args.env, args.scenario, v)
        if hr is not None:
            V, w, rows = hr
            print(f"{args.scenario} / {v}: battery {V:g} V; steady voltage for {math.degrees(w):.0f} deg/s at "
                  + ", ".join(f"{a:.0f} deg {u:.2f} V" for a, u in rows))
        else:
            print(f"{args.scenario} / {v} (reference seed {args.seed}):")
        r = solve(args.env, args.scenario, v, args.seed, args)
        out.append(r)
        print(f"  best input found: RMS {r['bound_rms_deg']:.4f} deg (lower bound {r['lower_bound_rms_deg']:.4f}), "
              f"max |e| {r['bound_max_abs_error_deg']:.3f} deg, {100 * r['bound_share_first_20ms']:.0f} % of the mean "
              f"square in the first 20 ms, saturated {100 * r['bound_saturated_fraction']:.0f} % "
              f"({r['simulations']} simulations, {r['solve_s']:.0f} s)", flush=True)
        if args.json:
            write_merged(args.json, [r])
    return out


def write_merged(path: Path, rows: list[dict]) -> None:
    """Merge rows into a JSON list keyed by (env, scenario, variant, reference_seed)."""
    from etb_gym.io import write_atomic

    def key(r):
        return (r["env"], r["scenario"], r["variant"], r.get("reference_seed", 0))

    old = json.loads(path.read_text()) if path.exists() else []
    new = {key(r): r for r in old}
    new.update({key(r): r for r in rows})
    write_atomic(path, json.dumps(sorted(new.values(), key=key), indent=2) + "\n")


if __name__ == "__main__":
    main()
