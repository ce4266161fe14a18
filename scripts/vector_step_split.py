#!/usr/bin/env python
"""Where the vector env's step spends its CPU (docs/speed.md, "Round 7"): in one process, interleaved, medians of 7,
CPU ns per plant-step of

    vector_step        the compiled step of the env (plants, reward, sensing, observation, info, noise refills)
    no_refill          the same with the noise blocks never used up (so never drawn anew)
    plants_only        the same with every sub-env marked for reset (plants stepped, nothing observed)
    step_batch         Plant.step_batch on the same arrays (the bare batch step, no env)

all on one thread (num_threads=1: CPU time without thread-pool effects), and env.step() itself.

    python scripts/vector_step_split.py [--n 1024] [--substeps 3] [--model 3B]
"""
import argparse
import statistics
import time

import gymnasium as gym
import numpy as np

import etb_gym  # noqa: F401  (registers the ids)
from etb_gym import make_plant


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--substeps", type=int, default=3)
    ap.add_argument("--model", default="3B")
    ap.add_argument("--repeats", type=int, default=7)
    a = ap.parse_args()
    N = a.n
    env = gym.make_vec(f"ETB-{a.model}-v0", num_envs=N, plant=make_plant(a.model, substeps=a.substeps), num_threads=1)
    env.action_space.seed(0)
    acts = [env.action_space.sample() for _ in range(16)]
    env.reset(seed=0)
    for k in range(100):
        env.step(acts[k % 16])
    u = env.unwrapped
    d = np.random.default_rng(0).uniform(-1, 1, N)
    none, every = np.zeros(N, bool), np.ones(N, bool)
    args = list(u._step_args)
    K0 = u._K.copy()

    def call(ignored, refill=True):
        info = np.empty((len(u._info_keys), N + 8))
        args[0] = ignored
        u._step_fn(d, *args, np.empty(N), np.empty(N, bool), u._obs, info)
        u._K[:] = K0                       # stay inside the episode
        if not refill:
            u._npos[:] = 1

    t0 = np.zeros(N)
    k = [0]

    def env_step():
        env.step(acts[k[0] % 16])
        k[0] += 1

    cases = {"vector_step": lambda: call(none), "no_refill": lambda: call(none, False),
             "plants_only": lambda: call(every),
             "step_batch": lambda: u.plant.step_batch(u._X, d, u._V, u._P, t0, u._AUX, parallel=False),
             "env.step()": env_step}
    res = {c: [] for c in cases}
    for _ in range(a.repeats):
        for c, f in cases.items():
            n = max(20, 200_000 // N)
            c0 = time.process_time()
            for _ in range(n):
                f()
            res[c].append(1e9 * (time.process_time() - c0) / (n * N))
    print(f"{a.model}, {a.substeps} substeps, N = {N}, one thread: CPU ns per plant-step (median of {a.repeats})")
    for c, v in res.items():
        print(f"  {c:12s} {statistics.median(v):7.0f}   ({min(v):.0f}-{max(v):.0f})")


if __name__ == "__main__":
    main()
