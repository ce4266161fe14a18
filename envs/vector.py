"""A native batched vector env: N throttle plants stepped together in one compiled, parallel call.

    envs = gym.make_vec("ETB-3B-v0", num_envs=1024)            # this class (the id's vector entry point)
    obs, info = envs.reset(seed=0)                               # sub-env k seeded with 0 + k
    obs, rew, term, trunc, info = envs.step(envs.action_space.sample())

It is the same MDP as N :class:`~etb_gym.envs.env.ETBEnv` in a ``SyncVectorEnv``, step for step and bit for
bit (tests/test_envs_vector.py): sub-env k owns a generator seeded like ``SyncVectorEnv`` seeds it
(``seed + k``), draws its episodes with the single env's :meth:`ETBEnv.draw_episode`, and reads its
sensor from noise blocks drawn in the same order. The plants advance together through
``Plant.step_batch``; sensing, observation, reward and info are numpy expressions over the batch.
Autoreset is Gymnasium's default ``NEXT_STEP`` mode: the step after a sub-env is truncated resets it
(its action is ignored, reward 0) and returns the reset observation and info. ``info`` is a dict of arrays
with ``_key`` masks, as ``SyncVectorEnv`` builds it. Rendering is not supported here (use
``vectorization_mode="sync"`` to render sub-envs).

``num_threads`` (keyword) sets the threads of the parallel batch step. Default: 1 below 64 sub-envs
(waking a thread pool costs more than stepping a few dozen plants), else numba's thread count. The pool
sleeps while it waits (etb_gym.integrate.configure_thread_pool), so on a shared machine it costs no
more CPU than one thread and still uses whatever the other core has left: measured on the loaded 2-core
machine of docs/speed.md, N = 1024 stepped 690k plant-steps/s with 2 threads vs 455k with 1 (N = 256:
470k vs 348k; N = 64: 233k vs 202k). Results do not depend on it.
"""
from __future__ import annotations

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from etb_gym.jit import HAVE_NUMBA

from . import observation as obsmod
from .env import NOISE_BLOCK, RAD2DEG, ETBEnv

SERIAL_UP_TO = 4      # up to this many plants: the single env's compiled control step in a loop
PARALLEL_FROM = 64    # below this many plants one thread is faster than waking numba's thread pool


def _max_threads() -> int:
    if not HAVE_NUMBA:
        return 1
    import numba

    return numba.config.NUMBA_NUM_THREADS


class _Threads:
    """Run numba parallel regions with ``n`` threads inside the block (restores the previous count)."""

    def __init__(self, n):
        self.n, self.prev = n, None

    def __enter__(self):
        if HAVE_NUMBA:
            import numba

            self.prev = numba.get_num_threads()
            if self.prev != self.n:
                numba.set_num_threads(self.n)
        return self

    def __exit__(self, *exc):
        if self.prev is not None and self.prev != self.n:
            import numba

            numba.set_num_threads(self.prev)


class ETBVectorEnv(VectorEnv):
    """N ETB envs with shared configuration (the keyword arguments of :class:`ETBEnv`)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 1, num_threads: int | None = None, **kwargs):
        if not (isinstance(num_envs, (int, np.integer)) and num_envs >= 1):
            raise ValueError(f"num_envs = {num_envs!r}: expected an integer >= 1")
        if num_threads is None:
            num_threads = 1 if num_envs < PARALLEL_FROM else _max_threads()
        elif not (isinstance(num_threads, (int, np.integer)) and 1 <= num_threads <= _max_threads()):
            raise ValueError(f"num_threads = {num_threads!r}: expected an integer in [1, {_max_threads()}]")
        self.num_threads = int(num_threads)
        if kwargs.get("render_mode") is not None:
            raise ValueError(f"render_mode = {kwargs['render_mode']!r}: the native vector env does not render; "
                             "use gym.make_vec(..., vectorization_mode='sync') to render sub-envs")
        kwargs.pop("render_mode", None)
        self.env = env = ETBEnv(**kwargs)       # configuration and episode draws (never stepped)
        self.num_envs = N = int(num_envs)
        self.render_mode = None
        self.single_observation_space = env.observation_space
        self.single_action_space = env.action_space
        self.observation_space = batch_space(env.observation_space, N)
        self.action_space = batch_space(env.action_space, N)
        p = env.plant
        self.plant = p
        self._rngs: list = [None] * N
        self._X = np.zeros((N, p.n_states))
        self._AUX = np.zeros((N, len(p.components)))
        self._P = np.tile(env._P_nominal, (N, 1))
        self._V = np.full(N, env.supply_V)
        self._K = np.zeros(N, np.int64)
        self._duty = np.zeros(N)
        self._tab = np.zeros((N, env.max_steps + 1))
        self._noise = np.zeros((N, NOISE_BLOCK, 2))
        self._npos = np.zeros(N, np.int64)
        self._noise_std = np.zeros(N)
        self._dbuf = np.zeros((N, env._delay + 1))
        self._dpos = np.zeros(N, np.int64)
        self._episodes: list = [None] * N
        self._autoreset = np.zeros(N, bool)
        self._rows = np.arange(N)
        self._dx = np.empty(p.n_states)
        self._started = False
        self._threads = _Threads(self.num_threads)

    # ------------------------------------------------------------------------------ per-row resets
    def _reset_rows(self, rows, seeds, options):
        env = self.env
        for i, s in zip(rows, seeds):
            if s is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(s)
            rng = self._rngs[i]
            ep = env.draw_episode(rng, options)
            self._episodes[i] = ep
            self._P[i] = ep.P
            self._V[i] = ep.supply_V
            self._X[i] = ep.x0
            self._tab[i] = ep.ref_table
            self._noise_std[i] = ep.noise_std_rad
            self._K[i] = 0
            self._duty[i] = 0.0
            env._rhs(0.0, self._X[i], 0.0, self._P[i], self._dx, self._AUX[i])
            self._dbuf[i] = self._X[i, 0]
            self._dpos[i] = 0
            self._noise[i] = rng.standard_normal((NOISE_BLOCK, 2))
            self._npos[i] = 0
            self._autoreset[i] = False
        rows = np.asarray(rows, np.int64)
        return self._observe(rows, self._tab[rows, 0], np.zeros(rows.size), np.zeros(rows.size))

    # ------------------------------------------------------------------------------ sensing and outputs
    def _observe(self, rows, r, d, t):
        """Observation and info arrays for ``rows`` (an index array, or ``slice(None)`` for all sub-envs):
        the single env's ``_observe`` over a batch."""
        env = self.env
        ri = self._rows if isinstance(rows, slice) else rows
        X = self._X[rows]
        phi = X[:, 0]
        if env._delay:
            pos = self._dpos[rows]
            old = self._dbuf[ri, pos]
            self._dbuf[ri, pos] = phi
            self._dpos[rows] = (pos + 1) % self._dbuf.shape[1]
            phi_read = old
        else:
            phi_read = phi
        npos = self._npos[rows]
        full = npos == NOISE_BLOCK
        if full.any():
            for j in np.flatnonzero(full):
                i = ri[j]
                if not self._autoreset[i]:       # a row about to be reset draws its noise at the reset
                    self._noise[i] = self._rngs[i].standard_normal((NOISE_BLOCK, 2))
                    npos[j] = 0
            npos = np.minimum(npos, NOISE_BLOCK - 1)
        z = self._noise[ri, npos]
        self._npos[rows] = npos + 1
        sensed = env.sensor.transform(phi_read, self._noise_std[rows] * z[:, 0])
        s_deg = sensed * RAD2DEG
        n = len(ri)
        obs = np.empty((n, env.n_obs), np.float32)
        if env.observe_current:
            i_read = X[:, 2] + env._cur_std * z[:, 1]
            if env._cur_q > 0.0:
                i_read = env._cur_q * np.round(i_read / env._cur_q)
            obsmod.encode_into(obs, s_deg, r, d, i_read)
        else:
            obsmod.encode_into(obs, s_deg, r, d)
        if env.full_state:
            obs[:, env.n_obs - X.shape[1]:] = X * env._inv_scales
        if env._clip_obs:
            np.minimum(obs, env._obs_high, out=obs)
            np.maximum(obs, env._obs_low, out=obs)
        V = self._V[rows]
        AUX = self._AUX[rows]
        info = {"angle_deg": phi * RAD2DEG, "sensed_angle_deg": s_deg, "velocity_deg_s": X[:, 1] * RAD2DEG,
                "current_A": X[:, 2].copy(), "voltage_V": d * V, "duty": np.array(d, float), "reference_deg": r,
                "supply_V": V}
        for key, k in env._torque_index:
            info[key] = AUX[:, k].copy() if k >= 0 else np.zeros(n)
        for key, k in env._effect_torques:
            info[key] = AUX[:, k].copy()
        info["t_s"] = np.array(t, float)
        return obs, info

    def _with_masks(self, info):
        """Add SyncVectorEnv's ``_key`` masks (all True: every sub-env reports every key; one shared array)."""
        out = {}
        every = np.ones(self.num_envs, bool)
        for k, v in info.items():
            out[k] = v
            out["_" + k] = every
        return out

    # ------------------------------------------------------------------------------ VectorEnv API
    def reset(self, *, seed=None, options=None):
        N = self.num_envs
        if seed is None:
            seeds = [None] * N
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + k for k in range(N)]
        else:
            seeds = list(seed)
            if len(seeds) != N:
                raise ValueError(f"seed: a list of {len(seeds)} seeds for num_envs = {N}: expected one per sub-env")
        opts = dict(options) if options else {}
        mask = opts.pop("reset_mask", None)
        if mask is None:
            rows = self._rows
        else:
            mask = np.asarray(mask)
            if mask.shape != (N,) or mask.dtype != np.bool_ or not mask.any():
                raise ValueError(f"options['reset_mask'] must be a bool array of shape ({N},) with a True entry")
            if not self._started:
                raise ValueError("options['reset_mask'] needs a full reset first")
            rows = np.flatnonzero(mask)
        obs_r, info_r = self._reset_rows(rows, [seeds[i] for i in rows], opts or None)
        self._started = True
        if mask is None:
            self._obs = obs_r
            return obs_r.copy(), self._with_masks(info_r)
        self._obs[rows] = obs_r
        infos = {}
        for k, v in info_r.items():
            a = np.zeros(N, v.dtype)
            a[rows] = v
            m = np.zeros(N, bool)
            m[rows] = True
            infos[k], infos["_" + k] = a, m
        return self._obs.copy(), infos

    def step(self, actions):
        if not self._started:
            from gymnasium.error import ResetNeeded

            raise ResetNeeded("call reset() before step()")
        env, N = self.env, self.num_envs
        a = np.asarray(actions, dtype=float)
        if a.size != N:
            raise ValueError(f"actions have shape {a.shape}: expected ({N}, 1), one duty cycle per sub-env")
        a = a.reshape(N)
        resetting = self._autoreset.any()
        live = ~self._autoreset
        if not np.isfinite(a).all():
            bad = ~np.isfinite(a) & live
            if bad.any():
                k = int(np.argmax(bad))
                raise ValueError(f"actions[{k}] = {a[k]!r}: expected a finite duty cycle in [-1, 1]")
        d = np.minimum(np.maximum(a, -1.0), 1.0)        # np.clip, without its Python wrapper
        if resetting:
            d[~live] = 0.0
        dt = env.dt
        t0 = self._K * dt
        if self.num_envs <= SERIAL_UP_TO:     # a parallel region costs more than a few plants
            ok = np.empty(self.num_envs, bool)
            cs, X, V, P, A = env._control_step, self._X, self._V, self._P, self._AUX
            for i in range(self.num_envs):
                ok[i] = cs(X[i], d[i], V[i], P[i], t0[i], dt, env._nsub, env._sw, env._fpwm, A[i])
        elif self.num_threads == 1:
            ok = self.plant.step_batch(self._X, d, self._V, self._P, t0, self._AUX, parallel=False)
        else:
            with self._threads:
                ok = self.plant.step_batch(self._X, d, self._V, self._P, t0, self._AUX)
        if not ok.all() and not ok[live].all():
            k = int(np.argmax(~ok & live))
            raise FloatingPointError(f"sub-env {k}: ETB plant state became non-finite at t = "
                                     f"{(self._K[k] + 1) * dt:.6f} s: {dict(zip(self.plant.state_names, self._X[k]))}")
        K = self._K
        K += 1
        r = self._tab[self._rows, np.minimum(K, env.max_steps)]   # (rows past the end are reset below)
        e = r - self._X[:, 0] * RAD2DEG
        dd = d - self._duty
        reward = -(env._wt * np.abs(e) + env._we * (d * d) + env._wc * (dd * dd))
        self._duty = d
        obs, info = self._observe(slice(None), r, d, K * dt)
        trunc = K >= env.max_steps
        resets = np.flatnonzero(~live) if resetting else ()
        if resetting:
            obs_r, info_r = self._reset_rows(resets, [None] * resets.size, None)
            obs[resets] = obs_r
            reward[resets] = 0.0
            trunc[resets] = False
            for k, v in info_r.items():
                info[k][resets] = v
        self._autoreset = trunc.copy()
        self._obs = obs
        return obs.copy(), reward, np.zeros(N, bool), trunc, self._with_masks(info)

    @property
    def episodes(self) -> list:
        """The current :class:`~etb_gym.envs.env.Episode` of every sub-env (what its last reset drew)."""
        return list(self._episodes)

    def close_extras(self, **kwargs):
        self.env.close()
