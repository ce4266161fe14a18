"""Break-away self-test: the friction and spring levels at the resting plate, identified before a move.

Why: a 0.5 deg step lands in 3-5 ms on the physical bound -- full drive for two or three periods, a brake, the
holding voltage. Where to brake depends on the current at which the plate breaks away and on how hard the
springs and friction stop it, i.e. on the friction and spring levels to ~10 %. The innovation of a move
cannot tell them in time: after two or three periods the plate has moved 0.03-0.09 deg, mostly in its
presliding bristles (docs/controllers.md). A production ECU runs a self-test at key-on (Pavkovic et al.
2006: slow current ramps to break-away in both directions give the spring torque plus and minus the static
friction); this is that test, with the levels read by the plant's own compiled model.

The test, while the reference has stood still for ``settle_s`` and the plate rests on it:

    ramp up:    i_cmd = i_0 + rho t   until the plate slides (it moved more than ``slide_deg`` beyond the
                                      elastic give of its presliding bristles), or the current passed what
                                      the largest admissible levels would need (no break-away: no estimate)
    hold:       i_cmd = i_0           for ``hold_s`` (the plate stops; friction holds it)
    ramp down, hold                   the same in the other direction

i_0 is the holding current the controller had found; the coil follows i_cmd through
u = R_hat i_cmd + L di_cmd/dt + K_c (i_cmd - i_m). The plate ends a few tenths of a degree from the
reference and the controller brings it back with the levels found. A change of the reference aborts the test
(no estimate, the controller continues at once).

Identification (a bank of models, a multiple-model estimator): each candidate (friction level, spring level)
of a grid is the controller's compiled plant model (the simulator's equations, ``Plant.stepper``) with those
levels, started at the sensed rest angle with its bristles at the static balance of the holding current,
stepped every period with the duty applied and its current reset to the measured one (as the predictor's
observer does), without angle correction. Its cost is the sum of squared angle errors over the test; the
estimate is the best candidate, refined by a pattern search on the logged test (the four neighbours on
the two axes replayed on the same data, from a third of the grid's spacing down to a 27th), projected onto
the self-tuning boxes. The presliding, the limp-home spring's compliance and the Stribeck drop are all in the
model, so the break-away need not be detected exactly: the ramps only have to pass it.

Cost: one compiled control step per candidate per period of the test (~7 us each: 50 candidates ~0.35 ms);
the refinement replays at most 25 logged periods per control period;
the candidates' parameter vectors are built one per period while the controller waits for the plate to
settle (``update`` returns None then: the controller's own law acts).
"""
from __future__ import annotations

import math

import numpy as np

from etb_gym.variants import COPPER_ALPHA_PER_K, RESISTANCE_REFERENCE_C, PlantVariant

from .base import check_gain

FRICTION_GRID = (0.4, 0.55, 0.7, 0.85, 1.0, 1.15, 1.3, 1.5, 1.75, 2.0)
SPRING_GRID = (0.7, 0.85, 1.0, 1.15, 1.3)


class BreakawaySelfTest:
    """The self-test of the module docstring for a controller built on ``model`` (a NominalModel with its
    plant), ``dt`` its control period. ``update`` is called every period; it returns the duty to apply while
    the test runs (None otherwise). ``result`` holds (friction level, spring level) once identified."""

    WAIT, RAMP, HOLD, REFINE, DONE = range(5)

    def __init__(self, model, dt: float, *, ramp_A_per_s: float = 100.0, settle_s: float = 0.03,
                 hold_s: float = 0.015, slide_deg: float = 0.1, rest_band_deg: float = 0.1,
                 max_noise_deg: float = 0.02, friction_grid=FRICTION_GRID, spring_grid=SPRING_GRID,
                 friction_bounds=(0.3, 2.0), spring_bounds=(0.6, 1.5)):
        own = "BreakawaySelfTest"
        self.m = model
        self.dt = dt
        self.rho = check_gain(own, "ramp_A_per_s", ramp_A_per_s, positive=True)
        self.settle = check_gain(own, "settle_s", settle_s, non_negative=True)
        self.hold = check_gain(own, "hold_s", hold_s, non_negative=True)
        self.slide = math.radians(check_gain(own, "slide_deg", slide_deg, positive=True))
        self.rest_band = math.radians(check_gain(own, "rest_band_deg", rest_band_deg, positive=True))
        self.max_noise = math.radians(check_gain(own, "max_noise_deg", max_noise_deg, positive=True))
        self.f_grid = tuple(float(x) for x in friction_grid)
        self.s_grid = tuple(float(x) for x in spring_grid)
        self.f_bounds, self.s_bounds = friction_bounds, spring_bounds
        plant = model.plant
        self.plant = plant
        fns = plant.stepper()
        self._step = fns.control_step
        self._nsub, self._sw, self._fpwm = plant.substeps, plant.supply.switching, plant.supply.pwm_frequency_hz
        self._aux = np.zeros(len(plant.components))
        self._nominal = plant.params_dict()
        names = plant.state_names
        self._z = names.index("friction.z_rad") if "friction.z_rad" in names else -1
        fp = plant.friction.params if plant.friction is not None else None
        self._sigma0 = float(getattr(fp, "bristle_stiffness_Nm_per_rad", 0.0)) if fp is not None else 0.0
        self.cands = [(f, s) for f in self.f_grid for s in self.s_grid]
        # the largest current step any admissible level needs to break the plate away (+ a margin): beyond it
        # the ramp stops without an estimate
        self.i_cap = (friction_bounds[1] * model.static_Nm + spring_bounds[1] * model.preload_Nm) \
            / model.torque_constant_Nm_per_A + 0.5
        self.reset()

    def reset(self) -> None:
        self.phase = self.WAIT
        self.result = None
        self.aborted = False
        self._P = []
        self._next = 0
        self._count = 0
        self._r = None
        self._ys = []
        self._is = []
        self.slid = []

    @property
    def running(self) -> bool:
        return self.phase in (self.RAMP, self.HOLD)

    def _build_one(self, R: float) -> None:
        """Build (or rebuild) one candidate's parameter vector at the present resistance estimate, in turn:
        while the controller waits, every candidate is refreshed once per len(cands) periods, so the bank
        starts with the coil resistance the self-tuning has found (it moves while the plate first settles)."""
        n = len(self.cands)
        k = self._next % n
        P = self._params(*self.cands[k], R)
        if len(self._P) < n:
            self._P.append(P)
        else:
            self._P[k] = P
        self._next += 1

    def _start(self, y0: float, i0: float) -> None:
        self.i0 = i0
        self.log = []                          # the test's data, replayed by the refinement
        x0 = np.asarray(self.plant.initial_state(y0), float)
        self.X = [x0.copy() for _ in self.cands]
        self.J = np.zeros(len(self.cands))
        self.sign = 1.0
        self._begin_ramp(y0, i0)

    def _begin_ramp(self, y0: float, i_m: float) -> None:
        """Each ramp is its own experiment: every candidate starts it at the sensed rest angle ``y0`` (a mean
        over the last periods), at rest, with the measured current and its bristles at the static balance of
        that current at its own levels (so the first ramp's slide does not carry over as an offset)."""
        self.log.append(("start", y0, i_m))
        m = self.m
        k = float(np.asarray(self.plant.drive.torque_constant(y0)))
        t_spring = m.spring_torque_Nm(y0)           # the spring level scales preload and rate alike
        for (f, s), x in zip(self.cands, self.X):
            x[0], x[1], x[2] = y0, 0.0, i_m
            if self._z >= 0 and self._sigma0 > 0:
                net = k * i_m - s * t_spring
                lim = f * m.static_Nm
                x[self._z] = max(-lim, min(lim, net)) / self._sigma0
        self.phase = self.RAMP
        self.t_phase = 0.0
        self.y_ramp = y0
        self.i_ramp = i_m
        self.k_lh = m.torque_constant_Nm_per_A
        # a ramp that starts inside the limp-home spring's compliance zone must leave it: inside, the plate
        # slides against the zone's stiff spring (preload / compliance) before it breaks out of limp-home,
        # and the break-out is what a step out of limp-home meets
        lh, c = m.limp_home_rad, m.limp_home_compliance_rad
        s_dir = getattr(self, "sign", 1.0)
        self.slide_now = self.slide + (max(0.0, s_dir * (lh + s_dir * c - y0)) if abs(y0 - lh) < c else 0.0)

    def update(self, y: float, r: float, i_m: float, d_prev: float, V: float, R_hat: float, Kc: float,
               v_hat: float, noise_ms: float, busy: bool) -> float | None:
        """One period: returns the duty while the test drives the coil, else None. ``busy``: the controller is
        in a move (no test starts); ``noise_ms``: mean square of the resting angle innovation (the test does
        not start on a sensor noisier than ``max_noise_deg``)."""
        if self.phase == self.DONE:
            return None
        if self.phase == self.REFINE:
            if self._r is not None and abs(r - self._r) > 1e-7:
                self._refine_done()            # a move begins: the best level found so far
            else:
                self._refine_one(R_hat)
            return None
        if self._r is not None and abs(r - self._r) > 1e-7:
            # the reference moved: a test under way is aborted; one not yet started is not run any more (the
            # key-on test runs before the first move, never between moves)
            self.aborted = self.running
            self.phase = self.DONE
            return None
        self._r = r
        if self.phase == self.WAIT:
            self._build_one(R_hat)
            still = abs(r - y) < self.rest_band and abs(v_hat) < 0.3 and not busy
            self._count = self._count + 1 if still else 0
            self._ys = (self._ys + [y])[-8:]
            self._is = (self._is + [i_m])[-4:]
            if still and self._count * self.dt >= self.settle and len(self._P) == len(self.cands) \
                    and noise_ms <= self.max_noise ** 2 and self.m.plant.friction is not None:
                self.slid = []
                self._start(sum(self._ys) / len(self._ys), sum(self._is) / len(self._is))
            else:
                return None
        else:
            self._advance_bank(y, i_m, d_prev, V)
            self._ys = (self._ys + [y])[-4:]
        # the test's current command this period
        self.t_phase += self.dt
        L = self.m.inductance_H
        if self.phase == self.RAMP:
            di = self.sign * self.rho * self.t_phase
            # sliding, not the presliding bristles' elastic give: the plate moved more than slide_deg beyond
            # k (i_m - i_start) / sigma0 (the bristles' deflection under the added torque; ~0.008 deg per period
            # at 100 A/s on ETB-3B, within the sensor's noise period to period, so a speed test fires on noise)
            elastic = self.k_lh * (i_m - self.i_ramp) / self._sigma0 if self._sigma0 > 0 else 0.0
            moved = self.sign * (y - self.y_ramp - elastic) > self.slide_now
            if moved or abs(di) > self.i_cap:
                self.slid.append(bool(moved))
                self.phase, self.t_phase = self.HOLD, 0.0
                i_cmd, di_dt = self.i0, 0.0
            else:
                i_cmd, di_dt = self.i0 + di, self.sign * self.rho
        else:
            i_cmd, di_dt = self.i0, 0.0
            if self.t_phase > self.hold:
                if self.sign > 0:
                    self.sign = -1.0
                    self._begin_ramp(sum(self._ys) / len(self._ys), i_m)
                    i_cmd, di_dt = self.i0 - self.rho * self.dt, -self.rho
                    self.t_phase = self.dt
                else:
                    self._finish()
                    return None
        u = R_hat * i_cmd + L * di_dt + Kc * (i_cmd - i_m)
        return max(-1.0, min(1.0, u / V))

    def _advance_bank(self, y: float, i_m: float, d_prev: float, V: float) -> None:
        self.log.append((y, i_m, d_prev, V))
        step, aux, dt = self._step, self._aux, self.dt
        for j, x in enumerate(self.X):
            step(x, d_prev, V, self._P[j], 0.0, dt, self._nsub, self._sw, self._fpwm, aux)
            e = y - x[0]
            self.J[j] += e * e
            x[2] = i_m

    def _finish(self) -> None:
        if len(self.slid) < 2 or not all(self.slid):
            self.phase = self.DONE
            self.aborted = True                 # no break-away seen in a direction: nothing identified
            return
        # the best candidate of the grid, then a local refinement on the logged data: a pattern search over
        # the four axis neighbours of the best point, from a third of the grid's spacing down (the cost is
        # steeply asymmetric about its minimum -- a level too low lets the model's plate slide far -- so a parabola through the grid points
        # is biased towards the higher level: +6 % on both levels of the nominal plant, enough for 25-40 %
        # overshoot of a 0.5 deg step at limp-home)
        nf, ns = len(self.f_grid), len(self.s_grid)
        a, b = np.unravel_index(int(np.argmin(self.J)), (nf, ns))
        self.best = (self.f_grid[a], self.s_grid[b])
        self.best_J = float(self.J.min())
        self.h = (_spacing(self.f_grid, a) / 3.0, _spacing(self.s_grid, b) / 3.0)
        self.rounds = 8
        self.h_min = self.h[0] / 4.0
        self._job = None
        self._queue_pattern()
        self.phase = self.REFINE

    def _queue_pattern(self) -> None:
        f0, s0 = self.best
        hf, hs = self.h
        self.queue = [(f0 + i * hf, s0 + j * hs) for i, j in ((-1, 0), (1, 0), (0, -1), (0, 1))]
        self.queue = [(f, s) for f, s in self.queue if f > 0.05 and s > 0.05]

    REPLAY_CHUNK = 25          # logged periods replayed per control period (~25 x 7 us)

    def _refine_one(self, R: float) -> None:
        """Advance the replay of the logged test for the next candidate of the pattern by at most
        ``REPLAY_CHUNK`` periods (a replay of a 150-period test spans six control periods)."""
        if getattr(self, "_job", None) is None:
            f, s = self.queue.pop()
            self._job = self.replay_start(f, s, R)
        if not self.replay_advance(self._job, self.REPLAY_CHUNK):
            return
        job, self._job = self._job, None
        if job["J"] < self.best_J:
            self.best_J, self.best_new = job["J"], (job["f"], job["s"])
        if not self.queue:
            # a pattern search: the pattern moves to a better neighbour at the same spacing, and shrinks to a
            # third when its centre is the best (at most ``rounds`` patterns)
            new = getattr(self, "best_new", self.best)
            moved, self.best = new != self.best, new
            self.rounds -= 1
            if self.rounds <= 0 or (not moved and self.h[0] < self.h_min):
                self._refine_done()
                return
            if not moved:
                self.h = (self.h[0] / 3.0, self.h[1] / 3.0)
            self._queue_pattern()

    def _refine_done(self) -> None:
        self.best = getattr(self, "best_new", self.best)
        f, s = self.best
        self.result = (min(max(f, self.f_bounds[0]), self.f_bounds[1]), min(max(s, self.s_bounds[0]), self.s_bounds[1]))
        self.phase = self.DONE

    def replay_cost(self, f: float, s: float, R: float) -> float:
        """Sum of squared angle errors of the candidate (f, s) over the logged test (as the bank scores)."""
        job = self.replay_start(f, s, R)
        self.replay_advance(job, len(self.log))
        return job["J"]

    def replay_start(self, f: float, s: float, R: float) -> dict:
        return {"f": f, "s": s, "P": self._params(f, s, R), "x": self.X[0].copy(), "J": 0.0, "k": 0}

    def _params(self, f: float, s: float, R: float):
        """The parameter vector of the controller's plant at friction level f, spring level s and coil
        resistance R (the self-tuned one, as a copper temperature)."""
        temp = RESISTANCE_REFERENCE_C + (R / self.m.resistance_ohm - 1.0) / COPPER_ALPHA_PER_K
        var = PlantVariant(coil_temperature_C=max(temp, -200.0), friction_scale=f, spring_scale=s)
        return self.plant.param_vector(var.overrides(self._nominal))

    def replay_advance(self, job: dict, n: int) -> bool:
        """Replay up to ``n`` more logged periods of ``job``; True when the log is done."""
        m, step, aux, dt = self.m, self._step, self._aux, self.dt
        x, P, f, s = job["x"], job["P"], job["f"], job["s"]
        log = self.log
        k, end = job["k"], min(len(log), job["k"] + n)
        J = job["J"]
        while k < end:
            rec = log[k]
            k += 1
            if rec[0] == "start":
                _, y0, i0 = rec
                x[0], x[1], x[2] = y0, 0.0, i0
                if self._z >= 0 and self._sigma0 > 0:
                    kt = float(np.asarray(self.plant.drive.torque_constant(y0)))
                    net = kt * i0 - s * m.spring_torque_Nm(y0)
                    lim = f * m.static_Nm
                    x[self._z] = max(-lim, min(lim, net)) / self._sigma0
                continue
            y, i_m, d_prev, V = rec
            step(x, d_prev, V, P, 0.0, dt, self._nsub, self._sw, self._fpwm, aux)
            e = y - x[0]
            J += e * e
            x[2] = i_m
        job["J"], job["k"] = J, k
        return k >= len(log)


def _spacing(grid, k: int) -> float:
    if len(grid) < 2:
        return 0.1
    if k == 0:
        return grid[1] - grid[0]
    if k == len(grid) - 1:
        return grid[-1] - grid[-2]
    return 0.5 * (grid[k + 1] - grid[k - 1])
