"""Rig-like recordings from a known ("truth") plant: the proof of the diagnosis and its tests use these.

Excitation (duty at the control period): steps, ramps, a push to the open stop and a release from full
open, a push into the closed stop, and a PRBS-like random duty, its levels drawn as target angles over the
recorded plant's travel and turned into duties with that plant's R, c_M, supply, spring and friction
(:class:`TravelDuty`), so a strong motor is not driven into its open stop and a weak one still travels. Closed loop: the package's reference PID
(limp-home and friction compensation, designed on the nominal plant, not on the truth) tracks steps and
ramps of the reference from the sensor's readings; the recorded voltage is what it commanded (so input and
output are correlated, as on a real rig).

The reading goes through ``PositionSensor`` (noise, quantization, offset/gain, whole-sample delay), and
optionally coloured noise: AR(1) noise n[k] = a n[k-1] + e[k] scaled to the requested standard deviation.
"""
from __future__ import annotations

import math

import numpy as np

from ..components.sensor import PositionSensor, PositionSensorParams
from ..plant import Plant
from ..recordings import Recording

QUIET_S = 0.2


# Travel fractions f of the open-loop excitation (f = 0 at limp-home, 1 at the open stop; above 1 the duty
# the spring would need beyond the stop, i.e. a push into it). Chosen so that on the default 3B plant the
# levels span what the earlier raw duties did (docs/diagnosis.md, "An excitation scaled to the nameplate").
STEP_TRAVEL = (0.05, 1.1)          # step targets, reached from either side (friction direction-aware)
RAMP_TOP_TRAVEL = (0.5, 1.4)       # ramp tops, reached from below
PRBS_BASE_TRAVEL = (0.3, 1.0)      # PRBS centre: the spring's holding duty there
PRBS_STICK = (0.6, 1.6)            # PRBS amplitude in units of the friction level (below 1 it sticks)
CLOSED_STICK = (0.75, 2.3)         # push into the closed stop: the spring there plus this x the friction
OPEN_PUSH = 1.4                    # push to the open stop: (spring there + friction) x this, at most duty 1


class TravelDuty:
    """The duties of an open-loop excitation in angle terms for ``plant`` (its own R, c_M, supply, spring,
    friction and stops). The coil is taken quasi-static, u = R T / c_M (the reference PID's feed-forward,
    ``controllers.model.NominalModel``), T the spring's torque at the target angle (its own kernel) plus the
    friction level in the direction of the move. A plant without Coulomb friction (viscous models 1x) uses a
    quarter of the spring's torque over the travel as its "friction level"; without stops the travel is
    3B's (3 deg below limp-home to 87 deg above)."""

    def __init__(self, plant: Plant):
        from etb_gym.controllers.model import NominalModel
        self.nom = nom = NominalModel.from_plant(plant)
        lh = nom.limp_home_rad
        self.open_rad = plant.angle_max_rad if math.isfinite(plant.angle_max_rad) else lh + math.radians(87.0)
        self.closed_rad = plant.angle_min_rad if math.isfinite(plant.angle_min_rad) else lh - math.radians(3.0)
        span = nom.spring_torque_Nm(self.open_rad) - nom.spring_torque_Nm(lh + 1e-6)
        full = nom.supply_V / nom.volts_per_Nm                  # the torque of duty 1 at rest
        self.stick_Nm = max(nom.coulomb_Nm if nom.coulomb_Nm > 0 else 0.25 * span, 0.02 * full)

    def angle_rad(self, f: float) -> float:
        return self.nom.limp_home_rad + f * (self.open_rad - self.nom.limp_home_rad)

    def duty(self, torque_Nm: float) -> float:
        """The duty whose quasi-static coil current gives ``torque_Nm`` (not clipped)."""
        return self.nom.volts_per_Nm * torque_Nm / self.nom.supply_V

    def level(self, f: float, direction: float = 0.0) -> float:
        """The duty that holds the plate at travel fraction ``f``, arriving from ``direction`` (+1 from
        below: spring plus friction; -1 from above; 0 the middle of the friction band)."""
        return self.duty(self.nom.spring_torque_Nm(self.angle_rad(f)) + direction * self.stick_Nm)

    def closed_push(self, stick: float) -> float:
        return self.duty(self.nom.spring_torque_Nm(self.closed_rad) - stick * self.stick_Nm)

    def open_push(self) -> float:
        return min(1.0, OPEN_PUSH * self.duty(self.nom.spring_torque_Nm(self.open_rad) + self.stick_Nm))


def open_loop_duty(duration_s: float, rng: np.random.Generator, dt: float = 1e-3, plant: Plant | None = None
                   ) -> np.ndarray:
    """Steps, ramps, release from the open stop, closed-stop push and PRBS-like duty, randomly ordered, with
    levels drawn as target angles over ``plant``'s travel (:class:`TravelDuty`; default plant: 3B)."""
    if plant is None:
        from ..plant import make_plant
        plant = make_plant("3B")
    tv = TravelDuty(plant)
    n = int(round(duration_s / dt))
    parts = []
    at = 0.0                                            # travel fraction the plate was sent to last

    def hold(level, s):
        parts.append(np.full(int(s / dt), float(level)))
    while sum(p.size for p in parts) < n:
        kind = rng.integers(0, 5)
        if kind == 0:                                   # a few steps to target angles
            for _ in range(3):
                f = rng.uniform(*STEP_TRAVEL)
                hold(tv.level(f, 1.0 if f >= at else -1.0), rng.uniform(0.2, 0.5))
                at = f
        elif kind == 1:                                 # ramp up and down
            top = tv.level(rng.uniform(*RAMP_TOP_TRAVEL), 1.0)
            m = int(rng.uniform(0.4, 0.8) / dt)
            parts.append(np.linspace(0.0, top, m))
            parts.append(np.linspace(top, 0.0, m))
            at = 0.0
        elif kind == 2:                                 # to the open stop, then release
            hold(tv.open_push(), rng.uniform(0.2, 0.4))
            hold(0.0, rng.uniform(0.3, 0.5))
            at = 0.0
        elif kind == 3:                                 # into the closed stop
            hold(tv.closed_push(rng.uniform(*CLOSED_STICK)), rng.uniform(0.15, 0.3))
            hold(0.0, 0.2)
            at = 0.0
        else:                                           # PRBS-like around a target angle
            m = int(rng.uniform(0.5, 1.0) / dt)
            at = rng.uniform(*PRBS_BASE_TRAVEL)
            base = tv.level(at)
            amp = tv.duty(rng.uniform(*PRBS_STICK) * tv.stick_Nm)
            hold_n = int(rng.integers(15, 60))
            bits = rng.integers(0, 2, size=m // hold_n + 1) * 2 - 1
            parts.append(base + amp * np.repeat(bits, hold_n)[:m])
    return np.clip(np.concatenate(parts)[:n], -1, 1)


def reference_profile(duration_s: float, rng: np.random.Generator, dt: float = 1e-3, lo_deg: float = 1.0,
                      hi_deg: float = 85.0) -> np.ndarray:
    """Reference angle [deg] for closed-loop runs: steps and ramps between ``lo_deg`` and ``hi_deg``."""
    n = int(round(duration_s / dt))
    r = []
    cur = lo_deg + 4.0
    while sum(p.size for p in r) < n:
        tgt = float(rng.uniform(lo_deg, hi_deg))
        if rng.random() < 0.3:
            m = int(rng.uniform(0.3, 0.8) / dt)
            r.append(np.linspace(cur, tgt, m))
        r.append(np.full(int(rng.uniform(0.25, 0.6) / dt), tgt))
        cur = tgt
    return np.concatenate(r)[:n]


def closed_loop(plant: Plant, ref_deg: np.ndarray, read, controller=None, enable_k: int = 0):
    """The reference PID (``etb_gym.controllers.PIDController``, designed on the nominal 3B plant, with
    limp-home and friction compensation) positions the truth plant, seeing only the sensor's readings.
    ``read(k, phi_rad) -> deg`` is the sensor reading of sample k. Returns (duty per period, true states per
    sample, readings per sample)."""
    from etb_gym.controllers.pid import PIDController
    from etb_gym.envs.observation import encode

    ctrl = controller if controller is not None else PIDController(dt=plant.control_period_s)
    ctrl.reset()
    V = plant.supply.voltage_V
    x = plant.initial_state(math.radians(float(ref_deg[0])) if 0.5 < ref_deg[0] < 89.5 else None)
    n = ref_deg.size
    X = np.empty((n, plant.n_states))
    Y = np.empty(n)
    duty = np.zeros(n)
    aux = np.zeros(len(plant.components))
    last = 0.0
    for k in range(n):
        X[k] = x
        Y[k] = read(k, float(x[0]))
        if k >= enable_k:
            last = float(np.clip(ctrl.act(encode(Y[k], float(ref_deg[k]), last)), -1.0, 1.0))
        duty[k] = last
        plant.step(x, last, supply_V=V, t0=k * plant.control_period_s, aux=aux)
    return duty, X, Y


def make_recording(plant: Plant, rng: np.random.Generator, *, duration_s: float = 10.0, closed: bool = False,
                   noise_deg: float = 0.01, resolution_deg: float = 90.0 / 4096, colour: float = 0.0,
                   offset_deg: float = 0.0, gain: float = 1.0, delay_steps: int = 0,
                   current_noise_A: float = 0.01, with_current: bool = True, name: str = "rec.csv",
                   controller=None, reading=None) -> Recording:
    """One rig-like recording of ``plant`` (the truth). ``colour`` in [0, 1): AR(1) coefficient of the noise.
    Closed loop: ``controller`` (default: the reference PID designed on the nominal 3B plant; for another
    nameplate pass one designed on that nameplate) acts on these same readings (noise, quantization,
    offset/gain, delay). ``reading``: a truth shape of the reading (``proof``'s truth_shapes.SensorShape: its
    ``stream(phi, noise)`` gives, sample by sample, what the sensor then reads), or None."""
    dt = plant.control_period_s
    nq = int(round(QUIET_S / dt))                    # the rig idles (duty 0) before the run starts
    n = nq + int(round((duration_s - QUIET_S) / dt))
    sensor = PositionSensor(PositionSensorParams(noise_std_rad=0.0, resolution_rad=math.radians(resolution_deg),
                                                 offset_rad=math.radians(offset_deg), gain=gain,
                                                 delay_steps=int(delay_steps), current_noise_std_A=current_noise_A))
    e = rng.normal(0.0, 1.0, n)
    if colour > 0:
        from scipy.signal import lfilter
        e = lfilter([1.0], [1.0, -colour], e) * math.sqrt(1 - colour ** 2)
    noise = math.radians(noise_deg) * e / gain
    if closed:
        lo, hi = math.degrees(plant.angle_min_rad), math.degrees(plant.angle_max_rad)
        ref = reference_profile(duration_s - QUIET_S, rng, dt, lo + 1.0, hi - 5.0)[: n - nq]
        lh = math.degrees(plant.limp_home_rad)
        sensor.reset(plant.limp_home_rad + noise[0])

        if reading is not None:
            reading.reset()

        def read(k, phi):
            v = phi + noise[k] if reading is None else reading.stream(phi, noise[k])
            return math.degrees(sensor.read(v, rng))

        duty, X, y = closed_loop(plant, np.concatenate([np.full(nq, lh), ref]), read, controller=controller,
                                 enable_k=nq)
        cur = X[:, 2]
    else:
        duty = np.concatenate([np.zeros(nq), open_loop_duty(duration_s - QUIET_S, rng, dt, plant)])[:n]
        tr = plant.simulate(duty=duty[:-1], angle_deg=math.degrees(plant.limp_home_rad))
        v = tr.angle_rad + noise if reading is None else reading.apply(tr.angle_rad, noise)
        y = np.degrees(sensor.measure(v, rng))
        cur = tr.current_A
    t = np.arange(n) * dt
    V = plant.supply.voltage_V
    return Recording(name=name, t_s=t, voltage_V=duty * V, angle_deg=y,
                     current_A=sensor.measure_current(cur, rng) if with_current else None, supply_V=None)


# ------------------------------------------------------------------------------------------ other nameplates
NAMEPLATE_RANGES = {                      # what random_nameplate draws from (uniform; log-uniform for L, J)
    "drive.resistance_ohm": (0.8, 3.0),
    "drive.inductance_H": (1e-3, 30e-3),
    "drive.torque_constant_Nm_per_A": (0.06, 0.25),
    "rotor.inertia_kg_m2": (12e-6, 80e-6),
    "spring.limp_home_deg": (2.0, 8.0),
    "stops.closed_deg": (-1.0, 1.0),
    "stops.open_deg": (80.0, 95.0),
    "friction.coulomb_Nm": (0.08, 0.35),
    "spring.preload_Nm": (0.07, 0.3),
    "spring.rate_Nm_per_rad": (0.12, 0.8),
}
LOG_RANGES = ("drive.inductance_H", "rotor.inertia_kg_m2")


def random_nameplate(rng: np.random.Generator, model: str = "3B", *, fixed: dict | None = None,
                     **plant_kw) -> Plant:
    """A throttle of another size: R, L, c_M, J, limp-home, stops, friction and spring levels drawn from
    NAMEPLATE_RANGES (L and J log-uniform), redrawn until the motor's stall torque beats the spring and the
    friction at the open stop by 1.8x or more (a throttle that can open fully). ``fixed``: values (keys of
    NAMEPLATE_RANGES, e.g. an extreme ``{"drive.inductance_H": 1e-3}``) taken as given instead of drawn."""
    from ..plant import make_plant
    fixed = dict(fixed or {})
    unknown = set(fixed) - set(NAMEPLATE_RANGES)
    if unknown:
        raise ValueError(f"random_nameplate: fixed {sorted(unknown)} unknown; expected keys of NAMEPLATE_RANGES: "
                         f"{', '.join(NAMEPLATE_RANGES)}")
    for _ in range(200):
        v = {}
        for k, (lo, hi) in NAMEPLATE_RANGES.items():
            v[k] = math.exp(rng.uniform(math.log(lo), math.log(hi))) if k in LOG_RANGES else float(rng.uniform(lo, hi))
        v.update(fixed)
        stall = v["drive.torque_constant_Nm_per_A"] * 12.0 / v["drive.resistance_ohm"]
        span = math.radians(v["stops.open_deg"] - v["spring.limp_home_deg"])
        need = v["spring.preload_Nm"] + v["spring.rate_Nm_per_rad"] * span + 1.1 * v["friction.coulomb_Nm"]
        if stall >= 1.8 * need:
            break
    over = {"drive.resistance_ohm": v["drive.resistance_ohm"], "drive.inductance_H": v["drive.inductance_H"],
            "drive.torque_constant_Nm_per_A": v["drive.torque_constant_Nm_per_A"],
            "rotor.inertia_kg_m2": v["rotor.inertia_kg_m2"],
            "spring.limp_home_rad": math.radians(v["spring.limp_home_deg"]),
            "stops.closed_rad": math.radians(v["stops.closed_deg"]), "stops.open_rad": math.radians(v["stops.open_deg"]),
            "spring.preload_Nm": v["spring.preload_Nm"], "spring.rate_Nm_per_rad": v["spring.rate_Nm_per_rad"]}
    p = make_plant(model, **plant_kw)
    pd = p.params_dict()
    if "drive.torque_constant_Nm_per_A" not in pd:      # drive C: k_C = N psi_hat, scaled through the turns N
        k_c = over.pop("drive.torque_constant_Nm_per_A")
        over["drive.ampere_turns"] = pd["drive.ampere_turns"] * k_c / p.drive.params.torque_constant_Nm_per_A
    if "drive.saturation_current_A" in pd:              # saturation at the same fraction of the stall current
        over["drive.saturation_current_A"] = pd["drive.saturation_current_A"] * (12.0 / v["drive.resistance_ohm"]) / 9.6
    f = p.friction.params.to_dict() if p.friction is not None else {}
    if "coulomb_Nm" in f:
        over["friction.coulomb_Nm"] = v["friction.coulomb_Nm"]
        if "static_Nm" in f:
            over["friction.static_Nm"] = v["friction.coulomb_Nm"] * f["static_Nm"] / f["coulomb_Nm"]
    if p.friction is not None and "bristle_damping_Nm_s_per_rad" in f:     # keep the bristle critically damped
        over["friction.bristle_damping_Nm_s_per_rad"] = 2.0 * math.sqrt(f["bristle_stiffness_Nm_per_rad"]
                                                                        * v["rotor.inertia_kg_m2"])
    return p.with_params(over)


def nameplate_file_plant(truth: Plant, rng: np.random.Generator, low: float = 0.10, high: float = 0.20) -> Plant:
    """What a user's plant file says about ``truth``: the same nameplate and geometry, no concealed effects,
    but the friction level and the spring preload and rate each off by a random 10-20 % (either sign)."""
    over = {}
    pd = truth.params_dict()
    for k in ("friction.coulomb_Nm", "spring.preload_Nm", "spring.rate_Nm_per_rad"):
        if k in pd:
            over[k] = pd[k] * (1.0 + float(rng.uniform(low, high)) * (1.0 if rng.random() < 0.5 else -1.0))
    if "friction.static_Nm" in pd and "friction.coulomb_Nm" in over:
        over["friction.static_Nm"] = pd["friction.static_Nm"] * over["friction.coulomb_Nm"] / pd["friction.coulomb_Nm"]
    return truth.replace(effects=()).with_params(over)
