"""Loop detection (etb_gym/diagnose/model.py, closed_loop_evidence) measured: a confusion table over controllers
and open-loop excitations.

Closed loops (the controller sees the sensor's readings, noise and 12-bit quantization included; the cascade
controllers also read the coil current and the battery): the voltage-mode PID with and without friction
compensation, a stiff PID, a PID with a strong roll-off (low derivative cutoff), pid-nocomp, the voltage-mode
sliding mode, the ECU cascade PID / sliding mode / PTOS, a user's own PI on a low-passed reading and a relay
(bang-bang with hysteresis), on 3B and on random nameplates (the PID designed on the user's file).
Open loops: the synthetic rig excitation (steps, ramps, stops, PRBS), a chirp, voltage steps, a PRBS, a plate
held at a stop the whole time, a sine, on 3B and random nameplates.

    .venv/bin/python scripts/loop_detection.py --seeds 3 --duration 6 --out out/loop.jsonl
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
import warnings

import numpy as np

from etb_gym.components.sensor import PositionSensor, PositionSensorParams
from etb_gym.diagnose import loop as LD
from etb_gym.diagnose import model as M
from etb_gym.diagnose.synthetic import (QUIET_S, nameplate_file_plant, open_loop_duty, random_nameplate,
                                        reference_profile)
from etb_gym.envs.observation import Measurement
from etb_gym.plant import make_plant
from etb_gym.recordings import Recording


class UserPI:
    """A user's own loop: PI on a first-order low-passed reading (cutoff ``wf`` rad/s), spring feedforward-free,
    output clamped: no derivative, no friction compensation."""
    name = "user-pi"
    reads = ("angle",)

    def __init__(self, dt, kp_per_deg=0.08, ti_s=0.05, wf=60.0):
        self.dt, self.kp, self.ti, self.a = dt, kp_per_deg, ti_s, math.exp(-wf * dt)

    def reset(self, seed=None):
        self.yf = None
        self.i = 0.0

    def act(self, m):
        self.yf = m.angle_deg if self.yf is None else self.a * self.yf + (1 - self.a) * m.angle_deg
        e = m.reference_deg - self.yf
        u = self.kp * e + self.i
        if abs(u) < 1.0:
            self.i += self.kp * e * self.dt / self.ti
        return max(-1.0, min(1.0, u))


class Relay:
    """Bang-bang with hysteresis: full duty towards the target outside +-h deg, a holding duty inside."""
    name = "relay"
    reads = ("angle",)

    def __init__(self, dt, h_deg=0.3, hold=0.35, amp=0.6):
        self.h, self.hold, self.amp = h_deg, hold, amp

    def reset(self, seed=None):
        self.s = 0.0

    def act(self, m):
        e = m.reference_deg - m.angle_deg
        if e > self.h:
            self.s = 1.0
        elif e < -self.h:
            self.s = -1.0
        return max(-1.0, min(1.0, self.hold + self.amp * self.s))


def controller(kind: str, file_plant, dt):
    from etb_gym.controllers.cascade import CascadePID, CascadeSMC
    from etb_gym.controllers.ptos import PTOSController
    from etb_gym.controllers.pid import PIDController
    from etb_gym.controllers.smc import SlidingModeController
    m = file_plant
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if kind == "pid":
            for wc in (50.0, 30.0, 15.0):
                try:
                    return PIDController(model=m, crossover_rad_s=wc)
                except ValueError:
                    pass
        if kind == "pid-nofc":
            return PIDController(model=m, friction_compensation=False, crossover_rad_s=30.0)
        if kind == "pid-stiff":
            return PIDController(model=m, crossover_rad_s=80.0, phase_margin_deg=35.0, friction_compensation=False)
        if kind == "pid-rolloff":
            return PIDController(model=m, crossover_rad_s=25.0, derivative_cutoff_rad_s=120.0,
                                 friction_compensation=False)
        if kind == "pid-nocomp":
            return PIDController(model=m, friction_compensation=False, limp_home_compensation=False,
                                 gain_scheduling=False, crossover_rad_s=30.0)
        if kind == "smc-plain":
            return SlidingModeController(model=m)
        if kind == "cascade-pid":
            return CascadePID(model=m)
        if kind == "cascade-smc":
            return CascadeSMC(model=m)
        if kind == "ptos":
            return PTOSController(model=m)
        if kind == "user-pi":
            return UserPI(dt)
        if kind == "relay":
            return Relay(dt)
    raise ValueError(kind)


CLOSED = ("pid", "pid-nofc", "pid-stiff", "pid-rolloff", "pid-nocomp", "smc-plain", "cascade-pid", "cascade-smc",
          "ptos", "user-pi", "relay")
OPEN = ("rig", "chirp", "steps", "prbs", "held-open", "held-closed", "sine", "zero")


def open_duty(kind, n, rng, dt):
    t = np.arange(n) * dt
    if kind == "rig":
        return open_loop_duty(n * dt, rng, dt)[:n]
    if kind == "chirp":
        f0, f1 = 0.5, float(rng.uniform(10, 30))
        ph = 2 * np.pi * (f0 * t + 0.5 * (f1 - f0) / t[-1] * t ** 2)
        return np.clip(float(rng.uniform(0.2, 0.4)) + float(rng.uniform(0.2, 0.5)) * np.sin(ph), -1, 1)
    if kind == "steps":
        lv = rng.uniform(0.0, 0.8, size=int(n * dt / 0.4) + 1)
        return np.repeat(lv, int(0.4 / dt))[:n]
    if kind == "prbs":
        hold = int(rng.integers(5, 40))
        b = rng.integers(0, 2, size=n // hold + 1) * 2 - 1
        return 0.4 + 0.2 * np.repeat(b, hold)[:n]
    if kind == "held-open":
        return np.full(n, 1.0)
    if kind == "held-closed":
        return np.full(n, -0.4)
    if kind == "sine":
        return 0.35 + 0.3 * np.sin(2 * np.pi * float(rng.uniform(0.5, 5)) * t)
    if kind == "zero":
        return np.zeros(n)
    raise ValueError(kind)


def record(truth, kind, rng, duration_s, noise_deg, colour, file_plant):
    dt = truth.control_period_s
    nq = int(round(QUIET_S / dt))
    n = nq + int(round((duration_s - QUIET_S) / dt))
    sensor = PositionSensor(PositionSensorParams(noise_std_rad=0.0, resolution_rad=math.radians(90.0 / 4096)))
    e = rng.normal(0.0, 1.0, n)
    if colour > 0:
        from scipy.signal import lfilter
        e = lfilter([1.0], [1.0, -colour], e) * math.sqrt(1 - colour ** 2)
    noise = math.radians(noise_deg) * e
    V = truth.supply.voltage_V
    if kind in OPEN:
        duty = np.concatenate([np.zeros(nq), open_duty(kind, n - nq, rng, dt)])[:n]
        tr = truth.simulate(duty=duty[:-1], angle_deg=math.degrees(truth.limp_home_rad))
        y = np.degrees(sensor.measure(tr.angle_rad + noise, rng))
        cur = tr.current_A
    else:
        ctrl = controller(kind, file_plant, dt)
        ctrl.reset()
        lo, hi = math.degrees(truth.angle_min_rad), math.degrees(truth.angle_max_rad)
        lh = math.degrees(truth.limp_home_rad)
        ref = np.concatenate([np.full(nq, lh), reference_profile(duration_s - QUIET_S, rng, dt, lo + 1.0,
                                                                 hi - 5.0)])[:n]
        sensor.reset(truth.limp_home_rad + noise[0])
        x = truth.initial_state(truth.limp_home_rad)
        y = np.empty(n)
        cur = np.empty(n)
        duty = np.zeros(n)
        aux = np.zeros(len(truth.components))
        last = 0.0
        for k in range(n):
            y[k] = math.degrees(sensor.read(float(x[0]) + noise[k], rng))
            cur[k] = x[2]
            if k >= nq:
                m = Measurement(y[k], float(ref[k]), float(ref[k]) - y[k], last,
                                current_A=float(x[2]) + 0.01 * float(rng.normal()),
                                supply_V=V + 0.05 * float(rng.normal()))
                last = float(np.clip(ctrl.act(m), -1.0, 1.0))
            duty[k] = last
            truth.step(x, last, supply_V=V, t0=k * dt, aux=aux)
    t = np.arange(n) * dt
    return Recording(name=f"{kind}.csv", t_s=t, voltage_V=duty * V, angle_deg=y,
                     current_A=cur + 0.01 * rng.normal(size=n), supply_V=None)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--kinds", default=",".join(CLOSED + OPEN))
    ap.add_argument("--plants", default="3B,random")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--duration", type=float, default=6.0)
    ap.add_argument("--out", default=None, help="append one JSON line per recording")
    a = ap.parse_args(argv)
    kinds = [k for k in a.kinds.split(",") if k]
    bad = [k for k in kinds if k not in CLOSED + OPEN]
    if bad:
        ap.error(f"unknown kind(s) {bad}")
    out = open(a.out, "a") if a.out else None
    conf, conf_old = {}, {}
    for kind in kinds:
        for pl in a.plants.split(","):
            for seed in range(a.first_seed, a.first_seed + a.seeds):
                rng = np.random.default_rng(7919 * seed + 31 * (CLOSED + OPEN).index(kind) + (pl == "random"))
                if pl == "random":
                    truth = random_nameplate(rng, substeps=20)
                    fp = nameplate_file_plant(truth, rng)
                else:
                    truth = make_plant("3B", substeps=20)
                    fp = make_plant("3B")
                noise = [0.01, 0.03][seed % 2]
                colour = [0.0, 0.0, 0.7][seed % 3]
                t0 = time.perf_counter()
                try:
                    rec = record(truth, kind, rng, a.duration, noise, colour, fp)
                except Exception as e:      # noqa: BLE001 (a controller that cannot be designed on this file)
                    print(f"{kind:12s} {pl:6s} s{seed}: not recorded ({type(e).__name__}: {e})", flush=True)
                    continue
                old = M.closed_loop_evidence_d2(rec)
                ev = LD.loop_evidence(rec.voltage_V, rec.angle_deg, rec.dt_s)
                truth_loop = "closed" if kind in CLOSED else "open"
                det = "closed" if ev > LD.LOOP_Z else "open"
                det_old = "closed" if old > M.LOOP_Z_D2 else "open"
                conf_old[(truth_loop, det_old)] = conf_old.get((truth_loop, det_old), 0) + 1
                conf[(truth_loop, det)] = conf.get((truth_loop, det), 0) + 1
                row = {"kind": kind, "plant": pl, "seed": seed, "noise": noise, "colour": colour,
                       "loop": truth_loop, "evidence": round(float(ev), 2), "detected": det,
                       "evidence_d2": round(float(old), 2), "detected_d2": det_old,
                       "saturated": round(float(np.mean(np.abs(rec.voltage_V) >= 0.999 * 12.0)), 3),
                       "time_s": round(time.perf_counter() - t0, 1)}
                print(f"{kind:12s} {pl:6s} s{seed} noise {noise} colour {colour}: z {ev:7.2f} -> {det} (d2 statistic {old:6.2f} -> {det_old})"
                      f"{'' if det == truth_loop else '  WRONG'}", flush=True)
                if out:
                    out.write(json.dumps(row) + "\n")
                    out.flush()
    print("confusion (truth -> detected):", {f"{k[0]}->{k[1]}": v for k, v in sorted(conf.items())})
    print("earlier d2 statistic:         ", {f"{k[0]}->{k[1]}": v for k, v in sorted(conf_old.items())})
    return 0


if __name__ == "__main__":
    sys.exit(main())
