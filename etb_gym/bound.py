"""The physical bound of a step: the shortest settling time any admissible input achieves on the plant.

For a step a -> b on a plant (a benchmark variant: its parameters and battery voltage), noise-free, from the
plate at rest at a, we search inputs d(t) with |d| <= 1 (the H-bridge duty, held per control period as the
env applies it) for the shortest settling time into the band |phi - b| <= band, measured exactly as the
benchmark measures a controller (:func:`settling_index`: last sample outside the band, plus one period;
the plate must stay in the band until the end of the scenario).

Searched family (a bound *found by search*: no input outside this family was tried)::

    d(t) =  s            0 <= t < t1                     full drive towards b       (s = sign(b - a))
            l2           t1 <= t < t1 + t2               brake (l2 = -s) or coast (l2 = 0), then free
            s            t1 + t2 <= t < t1 + t2 + t3     a last push (third switch of a 3rd-order plant)
            h            afterwards                      a constant holding duty

Switching times are continuous; a period that contains a switch gets the period's mean duty (an admissible
duty, as averaged PWM applies it). Stages:

1. ``t_reach``: the time full drive takes to reach b. Grid over (t1, t2) in [0, t_reach]^2 (about 24 x 24
   points) for l2 = -s and l2 = 0 with t3 = 0 and h = the static holding duty at b (from the plant's
   own right-hand side); each candidate is simulated on a short horizon (``2 t_reach + 60 ms``).
2. The three best grid points are refined with scipy's Nelder-Mead over (t1, t2, l2, t3, h) on a
   continuous surrogate of the settling time (the band crossing interpolated between samples).
3. The winner is re-simulated over the whole scenario; its settling time by the benchmark's rule is the
   bound. If it left the band after the short horizon, the next candidate is taken.

Cost: ~1500 short simulations, 0.2-1 s per (plant, step, variant) on one core; results are cached in
process and by the benchmark on disk (``bounds.json`` next to results.csv).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

BOUND_METHOD = ("bang-bang/bang-off-bang + third switch + hold, grid then Nelder-Mead; model-predictive landing "
                "law to the end (etb_gym.bound v3)")
GRID_POINTS = 24
REFINE_STARTS = 3
REFINE_EVALS = 400
PRELOADS = (0.0, 0.95)          # start current: equilibrium, or 95 % of the way to the static-friction edge


@dataclass(frozen=True)
class StepBound:
    """The best input found and its settling time (by the benchmark's rule, full scenario horizon)."""

    settling_time_s: float          # NaN if no searched input settles within the horizon
    duty: np.ndarray                # per control period, from the step on
    angle_deg: np.ndarray           # true angle at the samples 0..len(duty)
    params: tuple                   # (t1_s, t2_s, l2, t3_s, h, preload)
    evaluations: int
    method: str = BOUND_METHOD


def settling_index(angle_deg: np.ndarray, target_deg: float, band_deg: float, tail: int = 0) -> int | None:
    """The benchmark's settling rule on samples 0..n: index after the last sample outside the band (0 if
    none); None if the plate is outside within the last ``tail`` samples (never settled)."""
    outside = np.nonzero(np.abs(np.asarray(angle_deg) - target_deg) > band_deg)[0]
    if outside.size == 0:
        return 0
    j = int(outside[-1])
    if j + 1 >= angle_deg.size or j >= angle_deg.size - tail:
        return None
    return j + 1


def duty_profile(params, n: int, dt: float) -> np.ndarray:
    """The per-period duty of the searched family (module docstring), the mean over each period."""
    t1, t2, l2, t3, h = params
    s = 1.0
    edges = np.array([0.0, t1, t1 + t2, t1 + t2 + t3])
    levels = (s, l2, s)
    k = np.arange(n + 1) * dt
    out = np.full(n, float(h))
    covered = np.zeros(n)
    for (lo, hi), lv in zip(zip(edges[:-1], edges[1:]), levels):
        if hi <= lo:
            continue
        ov = np.clip(np.minimum(k[1:], hi) - np.maximum(k[:-1], lo), 0.0, None)
        out += (lv - h) * ov / dt
        covered += ov
    return np.clip(out, -1.0, 1.0)


class _Problem:
    """One step on one plant: simulation of a searched input and the settling surrogate."""

    def __init__(self, plant, a_deg, b_deg, band_deg, horizon_s):
        self.plant = plant
        self.dt = plant.control_period_s
        self.sign = 1.0 if b_deg >= a_deg else -1.0
        self.a, self.b, self.band = a_deg, b_deg, band_deg
        self.n_full = int(round(horizon_s / self.dt))
        self.evals = 0
        self.i_hold, self.i_band = self.holding_current(a_deg)
        self._x0 = {}

    def x0(self, preload: float):
        """Plate at rest at a with the coil current ``preload`` of the way from the equilibrium current to
        the edge of the static-friction band, towards b (a controller can leave it there during the hold)."""
        key = round(preload, 6)
        if key not in self._x0:
            i0 = self.i_hold + self.sign * preload * self.i_band
            self._x0[key] = self.plant.initial_state(math.radians(self.a), current_A=i0)
        return self._x0[key]

    def holding_current(self, angle_deg):
        """(current holding the plate at rest at ``angle_deg`` against the springs, the half-width of the
        current band static friction holds: T_s / k), from the plant's right-hand side."""
        p = self.plant
        x = p.initial_state(math.radians(angle_deg), at_rest=False)
        rhs = p.stepper().rhs
        dx = np.empty(p.n_states)
        aux = np.zeros(len(p.components))
        names = p.component_names
        fr = names.index("friction") if "friction" in names else -1
        drive = names.index("drive")

        def torques(i):
            x[2] = i
            rhs(0.0, x, 0.0, p.P, dx, aux)
            return float(np.sum(aux)) - (float(aux[fr]) if fr >= 0 else 0.0), float(aux[drive])

        t0, _ = torques(0.0)
        t1, _ = torques(1.0)
        k = t1 - t0
        i0 = -t0 / k if k != 0 else 0.0
        fp = p.friction.params if p.friction is not None else None
        ts = float(getattr(fp, "static_Nm", getattr(fp, "coulomb_Nm", 0.0))) if fp is not None else 0.0
        return i0, abs(ts / k) if k != 0 else 0.0

    def simulate(self, duty, preload=0.0):
        self.evals += 1
        tr = self.plant.simulate(duty=duty, x0=self.x0(preload))
        return tr.angle_deg

    def angle(self, params, n):
        t1, t2, l2, t3, h, pre = params
        return self.simulate(self.sign * duty_profile((t1, t2, l2, t3, h), n, self.dt), pre)

    def surrogate(self, phi) -> float:
        """Settling time with the band crossing interpolated between samples (continuous in the input);
        a response still outside at the end scores the horizon plus its distance to the band."""
        e = np.abs(phi - self.b) - self.band
        out = np.nonzero(e > 0)[0]
        if out.size == 0:
            return 0.0
        j = int(out[-1])
        if j + 1 >= phi.size:
            return (phi.size + e[-1]) * self.dt
        f = e[j] / (e[j] - e[j + 1])
        return (j + f) * self.dt

    def hold_duty(self) -> float:
        """The duty that holds the plate at rest at b against the springs: di/dt = 0 at the holding current."""
        p = self.plant
        x = p.initial_state(math.radians(self.b), at_rest=False)
        x[2] = self.holding_current(self.b)[0]
        dx = np.empty(p.n_states)
        aux = np.zeros(len(p.components))
        rhs = p.stepper().rhs
        rhs(0.0, x, 0.0, p.P, dx, aux)
        f0 = dx[2]
        rhs(0.0, x, 1.0, p.P, dx, aux)
        u0 = -f0 / (dx[2] - f0) if dx[2] != f0 else 0.0
        return float(np.clip(u0 / p.supply.voltage_V, -1.0, 1.0))


def _reach_time(prob: _Problem, n: int) -> float:
    phi = prob.simulate(np.full(n, prob.sign))
    past = np.nonzero(prob.sign * (phi - prob.b) >= 0)[0]
    return (past[0] if past.size else n) * prob.dt


def step_bound(plant, a_deg: float, b_deg: float, band_deg: float, horizon_s: float,
               tail_s: float = 0.1) -> StepBound:
    """The shortest settling time found by the search of the module docstring (see :class:`StepBound`)."""
    from scipy.optimize import minimize

    prob = _Problem(plant, float(a_deg), float(b_deg), float(band_deg), float(horizon_s))
    dt, n_full = prob.dt, prob.n_full
    t_reach = min(_reach_time(prob, min(n_full, int(round(0.2 / dt)))), horizon_s / 2)
    n_short = min(n_full, int(math.ceil((2 * t_reach + 0.06) / dt)))
    h0 = prob.sign * prob.hold_duty()        # in the step's direction (the family is mirrored by sign)
    span = max(t_reach, 2 * dt)
    grid = np.linspace(0.0, span, GRID_POINTS)
    scored = []
    for pre in PRELOADS:
        for l2 in (-1.0, 0.0):
            for t1 in grid[1:]:
                for t2 in grid:
                    if l2 == 0.0 and t2 == 0.0:
                        continue
                    th = (t1, t2, l2, 0.0, h0, pre)
                    scored.append((prob.surrogate(prob.angle(th, n_short)), th))
    scored.sort(key=lambda z: z[0])

    def clamp(v):
        t1, t2, l2, t3, h, pre = v
        return (max(t1, 0.0), max(t2, 0.0), min(1.0, max(-1.0, l2)), max(t3, 0.0), min(1.0, max(-1.0, h)),
                min(PRELOADS[-1], max(0.0, pre)))

    def f(v):
        return prob.surrogate(prob.angle(clamp(v), n_short))

    step = grid[1] - grid[0]
    results = []
    for _, th in scored[:REFINE_STARTS]:
        simplex = np.array([th] + [np.add(th, d) for d in np.diag([step, step, 0.5, step, 0.05, -0.2])])
        r = minimize(f, np.array(th), method="Nelder-Mead",
                     options={"initial_simplex": simplex, "maxfev": REFINE_EVALS, "xatol": 1e-5, "fatol": 1e-6})
        th_r = clamp(r.x)
        results.append((f(th_r), th_r))
    tail = int(round(tail_s / dt))
    best = None
    for _, th in results + scored[:5]:
        duty = prob.sign * duty_profile(th[:5], n_full, dt)
        phi = prob.simulate(duty, th[5])
        k = settling_index(phi, prob.b, prob.band, tail)
        if k is not None and (best is None or k < best[0]):
            best = (k, duty, phi, th)
    for pre in PRELOADS:
        duty = landing_input(prob, pre, n_full)
        phi = prob.simulate(duty, pre)
        k = settling_index(phi, prob.b, prob.band, tail)
        if k is not None and (best is None or k < best[0]):
            best = (k, duty, phi, (float("nan"),) * 5 + (pre,))
    if best is None:
        return StepBound(float("nan"), duty, phi, tuple(float(x) for x in th), prob.evals)
    k, duty, phi, th = best
    return StepBound(k * dt, duty, phi, tuple(float(x) for x in th), prob.evals)


def landing_input(prob: _Problem, preload: float, n: int) -> np.ndarray:
    """The input of the model-predictive landing law (``etb_gym.controllers.predictive``) run with the exact
    plant state and parameters (no sensor): each period the duty whose predicted stop lands on b, to the
    end of the scenario (after the landing it holds the plate at b). A second candidate family beside the switching-time search (it finds
    inputs whose switching period carries a fractional duty and whose hold starts at a different level)."""
    from etb_gym.controllers.model import NominalModel
    from etb_gym.controllers.predictive import StopPredictor

    plant = prob.plant
    pred = StopPredictor(NominalModel.from_plant(plant))
    V = plant.supply.voltage_V
    b = math.radians(prob.b)
    i_hold = prob.holding_current(prob.b)[0]
    hold = prob.hold_duty()
    x = prob.x0(preload).copy()
    aux = np.zeros(len(plant.components))
    step = plant.stepper().control_step
    duty = np.full(n, hold)
    s = prob.sign
    for k in range(n):
        if abs(b - x[0]) > 1e-6:
            s = 1.0 if b > x[0] else -1.0          # after landing the same law holds the plate at b
        pred._x0[:] = x
        d = pred.duty_to_land(b, s, V, i_hold, hold * V)
        duty[k] = d
        step(x, d, V, plant.P, 0.0, prob.dt, plant.substeps, plant.supply.switching, plant.supply.pwm_frequency_hz,
             aux)
        prob.evals += 1
    return duty
