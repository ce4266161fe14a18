"""Rig-like recordings from a known ("truth") plant: the proof of the diagnosis and its tests use these.

Excitation (duty at the control period): steps, ramps, a push to the open stop and a release from full
open, a push into the closed stop, and a PRBS-like random duty. Closed loop: the package's reference PID
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


def open_loop_duty(duration_s: float, rng: np.random.Generator, dt: float = 1e-3) -> np.ndarray:
    """Steps, ramps, release from full open, closed-stop push and PRBS-like duty, randomly ordered levels."""
    n = int(round(duration_s / dt))
    parts = []
    def hold(level, s):
        parts.append(np.full(int(s / dt), float(level)))
    while sum(p.size for p in parts) < n:
        kind = rng.integers(0, 5)
        if kind == 0:                                   # a few steps
            for _ in range(3):
                hold(rng.uniform(0.15, 0.75), rng.uniform(0.2, 0.5))
        elif kind == 1:                                 # ramp up and down
            top = rng.uniform(0.4, 0.9)
            m = int(rng.uniform(0.4, 0.8) / dt)
            parts.append(np.linspace(0.0, top, m))
            parts.append(np.linspace(top, 0.0, m))
        elif kind == 2:                                 # full open, then release
            hold(1.0, rng.uniform(0.2, 0.4))
            hold(0.0, rng.uniform(0.3, 0.5))
        elif kind == 3:                                 # into the closed stop
            hold(rng.uniform(-0.5, -0.25), rng.uniform(0.15, 0.3))
            hold(0.0, 0.2)
        else:                                           # PRBS-like
            m = int(rng.uniform(0.5, 1.0) / dt)
            base = rng.uniform(0.25, 0.55)
            amp = rng.uniform(0.1, 0.25)
            hold_n = int(rng.integers(15, 60))
            bits = rng.integers(0, 2, size=m // hold_n + 1) * 2 - 1
            parts.append(base + amp * np.repeat(bits, hold_n)[:m])
    return np.clip(np.concatenate(parts)[:n], -1, 1)


def reference_profile(duration_s: float, rng: np.random.Generator, dt: float = 1e-3) -> np.ndarray:
    """Reference angle [deg] for closed-loop runs: steps and ramps between 1 and 85 deg."""
    n = int(round(duration_s / dt))
    r = []
    cur = 5.0
    while sum(p.size for p in r) < n:
        tgt = float(rng.uniform(1.0, 85.0))
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
                   current_noise_A: float = 0.01, with_current: bool = True, name: str = "rec.csv") -> Recording:
    """One rig-like recording of ``plant`` (the truth). ``colour`` in [0, 1): AR(1) coefficient of the noise.
    Closed loop: the reference PID acts on these same readings (noise, quantization, offset/gain, delay)."""
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
        ref = reference_profile(duration_s - QUIET_S, rng, dt)[: n - nq]
        lh = math.degrees(plant.limp_home_rad)
        sensor.reset(plant.limp_home_rad + noise[0])

        def read(k, phi):
            return math.degrees(sensor.read(phi + noise[k], rng))

        duty, X, y = closed_loop(plant, np.concatenate([np.full(nq, lh), ref]), read, enable_k=nq)
        cur = X[:, 2]
    else:
        duty = np.concatenate([np.zeros(nq), open_loop_duty(duration_s - QUIET_S, rng, dt)])[:n]
        tr = plant.simulate(duty=duty[:-1], angle_deg=math.degrees(plant.limp_home_rad))
        y = np.degrees(sensor.measure(tr.angle_rad + noise, rng))
        cur = tr.current_A
    t = np.arange(n) * dt
    V = plant.supply.voltage_V
    return Recording(name=name, t_s=t, voltage_V=duty * V, angle_deg=y,
                     current_A=sensor.measure_current(cur, rng) if with_current else None, supply_V=None)
