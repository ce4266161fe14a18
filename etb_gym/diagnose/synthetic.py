"""Rig-like recordings from a known ("truth") plant: the proof of the diagnosis and its tests use these.

Excitation (duty at the control period): steps, ramps, a push to the open stop and a release from full
open, a push into the closed stop, and a PRBS-like random duty; its levels are written for 3B and moved to the
plant between its break-away duty at limp-home and its holding duty at the open stop (:class:`DutyMap`: the
plant's spring, friction, R, c_M and supply), so a strong motor is not driven into its open stop and a weak one still travels. Closed
loop: the package's reference PID
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


def holding_duties(plant: Plant) -> tuple[float, float, float]:
    """Three duties of ``plant`` through a quasi-static coil u = R T / c_M (the reference PID's feed-forward,
    ``controllers.model.NominalModel``; the spring's torque from its own kernel, T_c its Coulomb level): the
    break-away from limp-home towards open (spring just above limp-home + T_c), the hold at the open stop
    arriving from below (spring there + T_c), and the push from limp-home into the closed stop (spring there
    - T_c, negative). Not clipped (above 1 the motor cannot open fully). Without stops the travel is 3B's."""
    from etb_gym.controllers.model import NominalModel
    nom = NominalModel.from_plant(plant)
    lh = nom.limp_home_rad
    hi = plant.angle_max_rad if math.isfinite(plant.angle_max_rad) else lh + math.radians(87.0)
    lo = plant.angle_min_rad if math.isfinite(plant.angle_min_rad) else lh - math.radians(3.0)
    u = lambda T: nom.volts_per_Nm * T / nom.supply_V   # noqa: E731
    return (u(nom.spring_torque_Nm(lh + 1e-6) + nom.coulomb_Nm), u(nom.spring_torque_Nm(hi) + nom.coulomb_Nm),
            u(nom.spring_torque_Nm(lo) - nom.coulomb_Nm))


MIN_RATIO = 0.05        # a plant without spring and friction still gets an excitation


class DutyMap:
    """The excitation's duties, written for 3B, moved to ``plant``: a positive level d goes to the same place
    between break-away from limp-home (b) and the hold at the open stop (o) as on 3B,
    d' = b' + (d - b) (o' - b') / (o - b); an amplitude scales with (o' - b') / (o - b); a push into the closed
    stop with the closed-side duty ratio. For 3B (or a plant with 3B's spring, friction, R, c_M and supply)
    every duty is returned unchanged."""

    def __init__(self, plant: Plant | None):
        from ..plant import make_plant
        ref = holding_duties(make_plant("3B"))
        own = holding_duties(plant) if plant is not None else ref
        self.b_ref, self.b = ref[0], own[0]
        self.ratio = max((own[1] - own[0]) / (ref[1] - ref[0]), MIN_RATIO)
        self.closed_ratio = max(own[2] / ref[2], MIN_RATIO)

    def level(self, d: float) -> float:
        return d + (self.b - self.b_ref) + (d - self.b_ref) * (self.ratio - 1.0)

    def amplitude(self, a: float) -> float:
        return a * self.ratio

    def closed(self, d: float) -> float:
        return d * self.closed_ratio


def open_loop_duty(duration_s: float, rng: np.random.Generator, dt: float = 1e-3, plant: Plant | None = None
                   ) -> np.ndarray:
    """Steps, ramps, release from full open, closed-stop push and PRBS-like duty, randomly ordered levels.
    The levels are written for 3B (steps 0.15-0.75, ramps to 0.4-0.9, full open 1.0, closed push -0.5..-0.25,
    PRBS around 0.25-0.55) and moved to ``plant`` by :class:`DutyMap` (default: 3B, unchanged), so a strong
    motor is not driven into its open stop and a weak one still travels."""
    dm = DutyMap(plant)
    n = int(round(duration_s / dt))
    parts = []

    def hold(level, s):
        parts.append(np.full(int(s / dt), float(level)))
    while sum(p.size for p in parts) < n:
        kind = rng.integers(0, 5)
        if kind == 0:                                   # a few steps
            for _ in range(3):
                hold(dm.level(rng.uniform(0.15, 0.75)), rng.uniform(0.2, 0.5))
        elif kind == 1:                                 # ramp up and down
            top = dm.level(rng.uniform(0.4, 0.9))
            m = int(rng.uniform(0.4, 0.8) / dt)
            parts.append(np.linspace(0.0, top, m))
            parts.append(np.linspace(top, 0.0, m))
        elif kind == 2:                                 # full open, then release
            hold(dm.level(1.0), rng.uniform(0.2, 0.4))
            hold(0.0, rng.uniform(0.3, 0.5))
        elif kind == 3:                                 # into the closed stop
            hold(dm.closed(rng.uniform(-0.5, -0.25)), rng.uniform(0.15, 0.3))
            hold(0.0, 0.2)
        else:                                           # PRBS-like
            m = int(rng.uniform(0.5, 1.0) / dt)
            base = dm.level(rng.uniform(0.25, 0.55))
            amp = dm.amplitude(rng.uniform(0.1, 0.25))
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
                   controller=None, reading=None, nameplate: Plant | None = None) -> Recording:
    """One rig-like recording of ``plant`` (the truth). ``colour`` in [0, 1): AR(1) coefficient of the noise.
    Closed loop: ``controller`` (default: the reference PID designed on the nominal 3B plant; for another
    nameplate pass one designed on that nameplate) acts on these same readings (noise, quantization,
    offset/gain, delay). ``reading``: a truth shape of the reading (``proof``'s truth_shapes.SensorShape: its
    ``stream(phi, noise)`` gives, sample by sample, what the sensor then reads), or None. ``nameplate``: the
    plant the open-loop excitation is scaled to (:class:`DutyMap`; what the rig's operator knows, e.g. the
    user's plant file, or ``plant`` itself); default None: 3B's duties unscaled, as before the scaling (the
    tests' recordings keep their excitation)."""
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
        duty = np.concatenate([np.zeros(nq), open_loop_duty(duration_s - QUIET_S, rng, dt, nameplate)])[:n]
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
