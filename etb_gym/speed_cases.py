"""What the speed harness (etb_gym.speed) measures and how: the timed cases, their timing, the machine they ran on,
and the harness's small helpers (progress, log, atomic JSON)."""
from __future__ import annotations

import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

N_ACTIONS = 4096


# ---------------------------------------------------------------------------------------------- cases
class Case:
    """One measured thing. ``run(n)`` does n iterations and returns the work units done (steps)."""

    key: str
    label: str
    unit: str = "steps/s"
    sim_dt: float | None = None      # simulated seconds per unit (for the real-time factor)
    fast: bool | None = None         # ETB cases: compiled fast path?
    n_per_iter: int = 1              # work units per iteration (vector env: N)

    def run(self, n: int) -> int:
        raise NotImplementedError

    def close(self):
        pass


class GymEnvCase(Case):
    def __init__(self, key, label, make, seed, sim_dt=None, fast=None):
        self.key, self.label, self.sim_dt, self.fast = key, label, sim_dt, fast
        self.env = make()
        self.env.action_space.seed(seed)
        self.actions = [self.env.action_space.sample() for _ in range(N_ACTIONS)]
        self.env.reset(seed=seed)
        self.k = 0

    def run(self, n):
        env, acts, k = self.env, self.actions, self.k
        step, reset = env.step, env.reset
        for _ in range(n):
            _, _, term, trunc, _ = step(acts[k])
            k = (k + 1) % N_ACTIONS
            if term or trunc:
                reset()
        self.k = k
        return n

    def close(self):
        self.env.close()


class ResetCase(Case):
    unit = "resets/s"

    def __init__(self, make, seed, fast):
        self.key, self.label, self.fast = "reset", "reset() (draws a random reference)", fast
        self.env = make()
        self.env.reset(seed=seed)

    def run(self, n):
        reset = self.env.reset
        for _ in range(n):
            reset()
        return n

    def close(self):
        self.env.close()


class VectorCase(Case):
    unit = "plant-steps/s"

    def __init__(self, env_id, N, env_kw, seed, dt, fast, key=None, label=None):
        import gymnasium as gym

        self.key, self.label, self.sim_dt, self.fast, self.n_per_iter = key or f"vector_{N}", \
            label or f"make_vec N={N}", dt, fast, N
        self.envs = gym.make_vec(env_id, num_envs=N, **env_kw)
        self.kind = type(self.envs).__name__
        threads = getattr(self.envs, "num_threads", None)
        if threads is not None:
            self.kind += f", {threads} thread(s)"
        self.envs.action_space.seed(seed)
        self.actions = [self.envs.action_space.sample() for _ in range(16)]
        self.envs.reset(seed=seed)
        self.k = 0
        self.N = N

    def run(self, n):
        step, acts, k = self.envs.step, self.actions, self.k
        for _ in range(n):
            step(acts[k])
            k = (k + 1) % 16
        self.k = k
        return n * self.N

    def close(self):
        self.envs.close()


class PlantStepCase(Case):
    unit = "steps/s"

    def __init__(self, plant, seed):
        self.key, self.label, self.sim_dt, self.fast = "plant_step", "Plant.step (3B core, from Python)", \
            plant.control_period_s, plant.fast
        self.plant = plant
        self.x0 = plant.initial_state()
        self.x = self.x0.copy()
        self.aux = np.zeros(len(plant.components))
        self.duty = np.random.default_rng(seed).uniform(-1, 1, N_ACTIONS).tolist()
        self.k = 0

    def run(self, n):
        step, x, aux, duty, k = self.plant.step, self.x, self.aux, self.duty, self.k
        for _ in range(n):
            step(x, duty[k], aux=aux)
            k += 1
            if k == N_ACTIONS:                 # a new "episode" from rest
                k = 0
                x[:] = self.x0
        self.k = k
        return n


class KernelBatchCase(Case):
    unit = "plant-steps/s"

    def __init__(self, plant, N, seed):
        self.key, self.label, self.sim_dt, self.fast, self.n_per_iter = f"kernel_{N}", \
            f"Plant.step_batch N={N} (no env)", plant.control_period_s, plant.fast, N
        self.plant, self.N = plant, N
        rng = np.random.default_rng(seed)
        self.X0 = np.tile(plant.initial_state(), (N, 1))
        self.X = self.X0.copy()
        self.P = np.tile(plant.P, (N, 1))
        self.AUX = np.zeros((N, len(plant.components)))
        self.V = np.full(N, plant.supply.voltage_V)
        self.D = rng.uniform(-1, 1, (64, N))
        self.k = 0

    def run(self, n):
        p, X, D = self.plant, self.X, self.D
        t0 = np.zeros(self.N)
        for _ in range(n):
            p.step_batch(X, D[self.k], self.V, self.P, t0, self.AUX)
            self.k += 1
            if self.k == len(D):
                self.k = 0
                X[:] = self.X0
        return n * self.N


# ---------------------------------------------------------------------------------------------- timing
def timed(case: Case, n: int):
    w0, c0 = time.perf_counter(), time.process_time()
    units = case.run(n)
    return units, time.perf_counter() - w0, time.process_time() - c0


def calibrate(case: Case, seconds: float) -> int:
    """Warm up (compiles, caches) and find the iteration count of a ~``seconds`` repeat."""
    n = 1
    case.run(1)
    while True:
        _, wall, _ = timed(case, n)
        if wall >= 0.05 * seconds or n >= 1 << 22:
            break
        n *= 4
    return max(1, int(n * seconds / max(wall, 1e-9)))


def atomic_write(path: Path, text: str):
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w") as fh:
        fh.write(text)
    os.replace(tmp, path)


def progress(total, desc):
    try:
        from tqdm import tqdm

        return tqdm(total=total, desc=desc, file=sys.stderr, leave=False)
    except ImportError:  # pragma: no cover - tqdm is a dependency
        class _P:
            def update(self, k=1):
                pass

            def set_postfix_str(self, s):
                print(s, file=sys.stderr)

            def close(self):
                pass

        return _P()


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def machine_info():
    info = {"python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count()}
    try:
        info["loadavg_1min"] = round(os.getloadavg()[0], 2)
    except OSError:
        info["loadavg_1min"] = None
    try:
        import numba

        from etb_gym.threadpool import ensure_thread_pool

        info["thread_pool"] = ensure_thread_pool()     # before get_num_threads starts the pool (else it spins)
        info["numba"] = numba.__version__
        info["numba_threads"] = numba.get_num_threads()
        try:
            info["threading_layer"] = numba.threading_layer()
        except ValueError:
            info["threading_layer"] = None
    except ImportError:
        info["numba"] = None
    return info
