"""Digests of env trajectories: a behaviour lock for refactoring the env, the vector env and the plant.

Every case steps an env (single or native vector) with fixed seeds and fixed actions and hashes the
observations, rewards, episode ends and every info value, bit for bit. ``tests/test_env_digests.py`` compares
them with ``tests/data/env_digests.json``; a change that alters a trajectory on purpose (a new stepper, a
changed default) rewrites that file with

    python tests/env_digests.py --write          # (ETB_GYM_DISABLE_JIT=1 checks the plain path: same digests)

and says so in its commit message.
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import etb_gym  # noqa: F401  (registers the ids)
from etb_gym.jit import HAVE_NUMBA
from etb_gym.plant import MODELS, Plant, make_plant

DATA = Path(__file__).resolve().parent / "data" / "env_digests.json"

# option sets exercised on the single and the vector env (every observation / sensing / randomization path)
OPTIONS = {
    "plain": {},
    "randomized": dict(randomize=True),
    "current_supply": dict(observe_current=True, observe_supply=True, randomize=True),
    "delay_full_state": dict(full_state=True, observe_current=True, reference="pedal",
                             sensor={"delay_steps": 2, "current_resolution_A": 0.01, "noise_std_rad": 1e-3}),
    "supply_only_delay1": dict(observe_supply=True, sensor={"delay_steps": 1}, reference="chirp"),
    "switching": dict(pwm_mode="switching", reference="sine", observe_current=True),
    "weights_params": dict(reward_weights={"effort": 0.1}, params={"friction.coulomb_Nm": 0.2},
                           reference={"name": "steps", "values_deg": [10.0, 60.0, 30.0], "dwell_s": 0.01}),
    "period_2ms": dict(control_period_s=2e-3, randomize={"coil_temperature_C": (-40.0, 125.0),
                                                         "sensor_noise_std_deg": (0.0, 0.2)}),
}
RESET_OPTIONS = {"angle_deg": 20.0, "params": {"friction.coulomb_Nm": 0.15}, "supply_V": 13.5}


class Digest:
    def __init__(self):
        self.h = hashlib.sha256()

    def add(self, *arrays):
        for a in arrays:
            a = np.ascontiguousarray(a)
            self.h.update(str((a.dtype.str, a.shape)).encode())
            self.h.update(a.tobytes())

    def info(self, info):
        for k in sorted(info):
            self.h.update(k.encode())
            self.add(np.asarray(info[k]))

    def hex(self):
        return self.h.hexdigest()[:24]


def single(env_id, kw, n_steps, seed, options=None):
    env = gym.make(env_id, disable_env_checker=True, **kw)
    dg = Digest()
    rng = np.random.default_rng(seed + 1000)
    obs, info = env.reset(seed=seed, options=options)
    dg.add(obs)
    dg.info(info)
    for _ in range(n_steps):
        obs, r, term, trunc, info = env.step(rng.uniform(-1.3, 1.3, (1,)).astype(np.float32))
        dg.add(obs, np.float64(r), np.bool_(term), np.bool_(trunc))
        dg.info(info)
        if term or trunc:
            obs, info = env.reset()
            dg.add(obs)
            dg.info(info)
    env.close()
    return dg.hex()


def vector(env_id, kw, n_envs, n_steps, seed, options=None, num_threads=None):
    env = gym.make_vec(env_id, num_envs=n_envs, num_threads=num_threads, **kw)
    dg = Digest()
    rng = np.random.default_rng(seed + 2000)
    obs, info = env.reset(seed=seed, options=options)
    dg.add(obs)
    dg.info(info)
    for t in range(n_steps):
        obs, r, term, trunc, info = env.step(rng.uniform(-1.3, 1.3, (n_envs, 1)).astype(np.float32))
        dg.add(obs, r, term, trunc)
        dg.info(info)
        if t == n_steps // 2:
            mask = np.zeros(n_envs, bool)
            mask[0] = True
            obs, info = env.reset(options={"reset_mask": mask})
            dg.add(obs)
            dg.info(info)
    env.close()
    return dg.hex()


def plant_digests():
    out = {}
    duty = np.sin(np.linspace(0.0, 40.0, 300)) * 0.8
    for m in MODELS:
        p = make_plant(m)
        tf = p.simulate(duty, angle_deg=10.0, path="fast")
        tp = p.simulate(duty, angle_deg=10.0, path="plain")
        dg = Digest()
        dg.add(tf.states, *[tf.torques_Nm[k] for k in sorted(tf.torques_Nm)])
        out[f"plant {m} simulate"] = dg.hex()
        same = np.array_equal(tf.states, tp.states)
        out[f"plant {m} fast == plain"] = bool(same)
        d = p.to_dict()
        out[f"plant {m} to_dict"] = hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:24]
        q = Plant.from_dict(d)
        out[f"plant {m} from_dict round trip"] = bool(np.array_equal(q.P, p.P) and q.to_dict() == d)
    return out


# every effect component with a visible size (zero defaults switch most of them off)
EFFECTS = {
    "effect.airflow_torque": {"quadratic_Nm": 0.02, "cubic_Nm": -0.01},
    "effect.angle_dependent_friction": {"slope_Nm": 0.05, "curvature_Nm": 0.03},
    "effect.angle_friction_map": {"angle_rad": (0.0, 0.4, 0.9, 1.5), "level_Nm": (0.02, -0.01, 0.05, 0.03)},
    "effect.angle_torque_map": {"angle_rad": (0.0, 0.3, 0.8, 1.5), "torque_Nm": (0.01, -0.02, 0.03, 0.0)},
    "effect.backlash": {"play_rad": 0.004},
    "effect.coil_heating": {},
    "effect.current_inductance_map": {"current_A": (-3.0, 0.0, 3.0), "delta_H": (-4e-4, 0.0, -2e-4)},
    "effect.current_torque_constant_map": {"current_A": (-3.0, 0.0, 3.0), "delta_Nm_per_A": (-0.003, 0.0, 0.004)},
    "effect.current_torque_map": {"current_A": (-3.0, 0.0, 3.0), "delta_Nm_per_A": (0.001, 0.0, 0.004)},
    "effect.current_voltage_map": {"current_A": (-3.0, -0.5, 0.5, 3.0), "drop_V": (-0.4, -0.1, 0.15, 0.3)},
    "effect.end_stop_compliance": {"stiffness_Nm_per_rad": 700.0},
    "effect.inductance_saturation": {"inductance_drop_H": 5e-4},
    "effect.shaft_flux_loss": {"loss_at_open_Nm_per_A": 0.01},
    "effect.periodic_angle_torque": {"period_rad": 0.26, "cos_Nm": (0.01, 0.004), "sin_Nm": (-0.006, 0.002),
                                     "cos_Nm_per_A": (0.002, 0.0), "sin_Nm_per_A": (0.0, -0.001)},
    "effect.speed_friction_map": {"speed_rad_s": (0.0, 0.5, 2.0, 8.0), "opening_Nm": (0.03, 0.01, 0.02, 0.04),
                                  "closing_Nm": (0.02, 0.02, 0.0, 0.05)},
    "effect.spring_asymmetry": {"closing_preload_delta_Nm": 0.02, "closing_rate_delta_Nm_per_rad": 0.05},
    "effect.stribeck_friction": {"stiction_Nm": 0.04},
    "effect.supply_drop": {"series_resistance_ohm": 0.2, "forward_drop_V": 0.3},
    "effect.thermal_network": {"time_constant_s": (0.01, 0.05, 1.0), "thermal_resistance_K_per_W": (1.0, 4.0, 8.0),
                               "voltage_rise_K_per_V2": (0.0, 0.05, 0.1)},
    "effect.torque_constant_error": {"delta_Nm_per_A": 0.005},
    "effect.torque_constant_map": {"angle_rad": (0.0, 0.5, 1.5), "delta_Nm_per_A": (0.0, -0.004, 0.006)},
}


def table_drive_digest():
    """Drive B with a measured inductance table (components/drive.table_inductance), fast and plain."""
    from etb_gym.components.drive import InductanceTable

    tab = InductanceTable(current_A=(0.0, 0.5, 1.5, 3.0, 6.0), angle_rad=(0.0, 0.4, 0.9, 1.6),
                          inductance_H=tuple(tuple(3e-3 * (1.0 - 0.08 * a) / (1.0 + 0.2 * c) for a in range(4))
                                             for c in range(5)))
    p = make_plant("3B").with_params({"drive.inductance_table": tab})
    duty = np.sin(np.linspace(0.0, 25.0, 300))
    tf = p.simulate(duty, angle_deg=10.0, path="fast")
    tp = p.simulate(duty, angle_deg=10.0, path="plain")
    dg = Digest()
    dg.add(tf.states, tf.torques_Nm["drive"])
    return {"plant 3B inductance table simulate": dg.hex(),
            "plant 3B inductance table fast == plain": bool(np.array_equal(tf.states, tp.states))}


def effect_digests():
    """Each effect component in a 2A and a 3B plant, simulated on the fast and the plain path."""
    from etb_gym.components.base import REGISTRY

    out = {}
    duty = np.sin(np.linspace(0.0, 30.0, 250)) * 0.9
    assert set(EFFECTS) == {k for k in REGISTRY if k.startswith("effect.")}, "add the new effect to EFFECTS"
    for kind, params in EFFECTS.items():
        C = REGISTRY[kind]
        for model in ("2A", "3B"):
            p = make_plant(model, effects=[C(C.Params(**params))])
            dg = Digest()
            tf = p.simulate(duty, angle_deg=20.0, path="fast")
            dg.add(tf.states, *[tf.torques_Nm[k] for k in sorted(tf.torques_Nm)])
            out[f"plant {model} + {kind} simulate"] = dg.hex()
            tp = p.simulate(duty, angle_deg=20.0, path="plain")
            out[f"plant {model} + {kind} fast == plain"] = bool(np.array_equal(tf.states, tp.states))
    return out


def task_digests():
    """The RL task's wrappers (etb_gym.rl.wrappers) around the native vector env: direct and residual."""
    from etb_gym.rl.task import TaskConfig
    from etb_gym.rl.wrappers import make_task_vec_env

    out = {}
    for name, task in (("direct", TaskConfig(episode_s=0.05)),
                       ("residual smc-plain", TaskConfig(residual="smc-plain", episode_s=0.05))):
        env = make_task_vec_env("ETB-3B-v0", 3, task, seed=4, randomize=True)
        dg = Digest()
        obs, _ = env.reset()
        dg.add(obs)
        rng = np.random.default_rng(0)
        for _ in range(70):
            obs, r, term, trunc, info = env.step(rng.uniform(-1.2, 1.2, 3))
            dg.add(obs, r, term, trunc)
            if "final_obs" in info:
                dg.add(info["final_obs"], info["_final_obs"])
        out[f"rl task {name} N=3"] = dg.hex()
    return out


def digests(quick: bool = False) -> dict:
    """{case: digest}. ``quick``: the subset the test suite runs (a few seconds)."""
    out = {}
    models = ("1A", "3B") if quick else MODELS
    for m in models:
        out[f"single {m} randomized"] = single(f"ETB-{m}-v0", dict(episode_s=0.04, randomize=True), 90, seed=3)
    for name, kw in OPTIONS.items():
        kw = dict(kw, episode_s=0.03)
        out[f"single 3B {name}"] = single("ETB-3B-v0", kw, 70, seed=7)
        out[f"single 3B {name} reset options"] = single("ETB-3B-v0", kw, 20, seed=8, options=RESET_OPTIONS)
        n_sets = ((3, None), (6, 1)) if quick or not HAVE_NUMBA else ((3, None), (6, 1), (6, 2))
        for n, th in n_sets:
            out[f"vector 3B {name} N={n} threads={th}"] = vector("ETB-3B-v0", kw, n, 70, seed=9, num_threads=th)
        if not quick:
            out[f"vector 3B {name} N=5 reset options"] = vector("ETB-3B-v0", kw, 5, 20, seed=10,
                                                                 options=RESET_OPTIONS)
    if not quick:
        for m in MODELS:
            out[f"vector {m} randomized N=8"] = vector(f"ETB-{m}-v0", dict(episode_s=0.04, randomize=True), 8, 90,
                                                       seed=4, num_threads=1)
        out.update(plant_digests())
        out.update(effect_digests())
        out.update(table_drive_digest())
        out.update(task_digests())
    return out


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    full = digests(quick=False)
    quick = digests(quick=True)
    record = {"quick": quick, "full": full}
    if "--write" in argv:
        DATA.parent.mkdir(exist_ok=True)
        DATA.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")
        print(f"wrote {DATA}: {len(full)} + {len(quick)} cases")
        return 0
    ref = json.loads(DATA.read_text())
    bad = [(part, k) for part in ("quick", "full") for k in record[part] if ref[part].get(k) != record[part][k]]
    missing = [(part, k) for part in ("quick", "full") for k in ref[part] if k not in record[part]]
    for part, k in bad + missing:
        print(f"DIFFERS {part}: {k}: {ref[part].get(k)} -> {record[part].get(k)}")
    print(f"{len(full) + len(quick) - len(bad)} of {len(full) + len(quick)} cases identical"
          + (f", {len(missing)} missing" if missing else ""))
    return 1 if bad or missing else 0


if __name__ == "__main__":
    sys.exit(main())
