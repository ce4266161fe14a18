"""Steps per second of the ETB envs (single env through gym.make, native vector env through gym.make_vec).

    python -m etb_gym.envs.benchmark                       # ETB-3B-v0, vector N = 1, 64, 1024
    python -m etb_gym.envs.benchmark --id ETB-1A-v0 --n 1 256 --seconds 3 --compare Pendulum-v1

Random actions (drawn before timing), default wrappers, episodes reset as they end. The vector figure is
plant control-steps per second (num_envs * vector steps per second). Timings on a shared machine vary by
tens of percent: compare with ``--compare Pendulum-v1`` run in the same process.
"""
from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import etb_gym  # noqa: F401  (registers the ids)


def single_env_rate(env_id: str, seconds: float = 2.0, **kwargs) -> dict:
    env = gym.make(env_id, **kwargs)
    acts = np.random.default_rng(0).uniform(-1, 1, (4096, 1)).astype(np.float32)
    if env.action_space.shape != (1,):
        acts = np.array([env.action_space.sample() for _ in range(4096)])
    env.reset(seed=0)
    env.step(acts[0])                         # compile / load the kernels outside the timing
    env.reset(seed=0)
    n, t0 = 0, time.perf_counter()
    while True:
        for k in range(4096):
            _, _, term, trunc, _ = env.step(acts[k])
            if term or trunc:
                env.reset()
        n += 4096
        if time.perf_counter() - t0 > seconds:
            break
    step_rate = n / (time.perf_counter() - t0)
    m, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < min(seconds, 1.0):
        for _ in range(200):
            env.reset()
        m += 200
    reset_us = (time.perf_counter() - t0) / m * 1e6
    env.close()
    return {"steps_per_s": step_rate, "us_per_step": 1e6 / step_rate, "us_per_reset": reset_us}


def vector_env_rate(env_id: str, num_envs: int, seconds: float = 2.0, **kwargs) -> dict:
    envs = gym.make_vec(env_id, num_envs=num_envs, **kwargs)
    envs.reset(seed=0)
    acts = np.random.default_rng(0).uniform(-1, 1, (64, num_envs, 1)).astype(np.float32)
    envs.step(acts[0])                        # compile / warm up
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for k in range(64):
            envs.step(acts[k])
        n += 64
    rate = n / (time.perf_counter() - t0)
    envs.close()
    return {"vector_steps_per_s": rate, "plant_steps_per_s": rate * num_envs}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--id", default="ETB-3B-v0", help="env id (default ETB-3B-v0)")
    ap.add_argument("--n", type=int, nargs="+", default=[1, 64, 1024], help="vector env sizes")
    ap.add_argument("--seconds", type=float, default=2.0, help="timing duration per measurement")
    ap.add_argument("--compare", default=None, help="also time this id (e.g. Pendulum-v1) as a yardstick")
    ap.add_argument("--threads", type=int, default=None, help="num_threads of the vector env (default: auto)")
    a = ap.parse_args(argv)
    if a.compare:
        r = single_env_rate(a.compare, a.seconds)
        print(f"{a.compare:12s} single env: {r['steps_per_s']:10.0f} steps/s ({r['us_per_step']:.1f} us/step)")
    r = single_env_rate(a.id, a.seconds)
    print(f"{a.id:12s} single env: {r['steps_per_s']:10.0f} steps/s ({r['us_per_step']:.1f} us/step, "
          f"reset {r['us_per_reset']:.1f} us)")
    for n in a.n:
        v = vector_env_rate(a.id, n, a.seconds, **({} if a.threads is None else {"num_threads": a.threads}))
        print(f"{a.id:12s} vector N={n:<5d}: {v['plant_steps_per_s']:10.0f} plant steps/s "
              f"({v['vector_steps_per_s']:.0f} vector steps/s)")


if __name__ == "__main__":
    main()
