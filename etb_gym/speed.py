"""Speed of etb-gym side by side with gymnasium's Pendulum-v1 and gym-electric-motor, in one run: the one
speed harness (``etb-gym speed``, ``python -m etb_gym.speed``; scripts/bench_speed.py and
``python -m etb_gym.envs.benchmark`` are thin wrappers of it).

    etb-gym speed                                       # full run (~2 min), table + one JSON line last
    etb-gym speed --repeats 3 --seconds 0.3 --no-gem
    etb-gym speed --plant my_plant.toml                 # benchmark a plant file (e.g. with diagnosed effects)
    etb-gym speed --json-out speed.json                 # also write the JSON object to a file (atomic)
    etb-gym speed --baseline 5dc542e                    # before/after: that git revision vs this tree
    etb-gym speed --env-id ETB-1A-v0 --num-envs 1 256 --compare CartPole-v1

What is measured (every case with gymnasium's default wrappers of ``gym.make`` and random actions drawn
from the seeded action space before timing; episodes are reset when they end, inside the timed loop):

    etb            gym.make("ETB-3B-v0")                          env steps/s, simulated s per wall s
    etb_switching  gym.make("ETB-3B-v0", pwm_mode="switching")    the same, PWM edges resolved (5 kHz)
    vector N       gym.make_vec("ETB-3B-v0", num_envs=N)          plant control-steps/s (N * vector steps/s)
    pendulum       gym.make("Pendulum-v1")                        steps/s: the floor of pure-Python env cost
    gem            gym.make("Cont-SC-PermExDc-v0")                steps/s (gym-electric-motor, optional)
    reset          ETB-3B-v0 reset() incl. drawing a random reference       us per reset
    plant_step     Plant.step of 3B from Python                             us per control step
    kernel 1024    Plant.step_batch of 1024 3B plants (no env around it)    plant control-steps/s
    excitation     3B, 2 s of rich_excitation: Plant.simulate (fast path) vs Plant.reference (solve_ivp)
    equal accuracy the fewest substeps at which the stepper's angle error on that excitation is within
                   0.044 deg RMS of solve_ivp (the stepper before issue 12 at its default 20 substeps):
                   ``substeps_for_0p044_deg``, and make_vec at the largest N with those substeps:
                   ``vector_steps_per_s_at_equal_accuracy`` (null with --no-reference)
    compare ID     any other gymnasium id given with --compare, as a further yardstick

Every case runs ``--repeats`` times, the cases interleaved round-robin so that a change of machine load
hits all of them alike; the table gives medians (and the CPU time per step, which a shared machine
distorts less than wall time). The ratios compare figures of the same run. Whether each ETB plant runs
on the compiled fast path or fell back to the plain Python path (a component without a compiled
kernel: FastPathUnavailableWarning) is printed and recorded (``fast_path``).

Output: progress on stderr, the table on stdout, and, as the very last stdout line, one JSON object with
at least etb_steps_per_s, etb_switching_realtime_factor, vector_steps_per_s (keyed by N),
pendulum_steps_per_s, gem_steps_per_s (null without gym-electric-motor), reset_us, the ratios and the
excitation timings.

``--baseline REV`` measures a git revision of etb-gym side by side with this tree: it extracts REV
(``git archive``) to a temporary directory and runs REV's scripts/bench_speed.py and this harness
alternately, in fresh processes, ``--repeats`` rounds of one repeat each (no solve_ivp; the equal-accuracy
substeps are found once, up front), then prints medians before -> after per figure and, last, this tree's
medians as the JSON object with a ``baseline`` entry.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
import warnings
from pathlib import Path

import numpy as np

TARGETS = {   # issue 7, benchmark figures (not timed tests)
    "ratio_etb_vs_gem": 15.0,
    "ratio_etb_vs_pendulum": 0.5,
    "vector_1024_steps_per_s": 1_000_000.0,
    "etb_switching_realtime_factor": 10.0,
    "reset_us_max": 50.0,
}
GEM_ID = "Cont-SC-PermExDc-v0"
ROOT = Path(__file__).resolve().parents[1]     # the source tree (for --baseline's git archive)
N_ACTIONS = 4096
EQUAL_ACCURACY_DEG = 0.044   # RMS angle error of the stepper before issue 12 at 20 substeps, 3B rich excitation


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--repeats", type=int, default=5, help="timed repeats per case (median reported; default 5)")
    ap.add_argument("--seconds", type=float, default=1.0,
                    help="target wall time of one timed repeat of one case (default 1.0 s)")
    ap.add_argument("--env-id", "--id", default="ETB-3B-v0", help="the ETB env id (default ETB-3B-v0)")
    ap.add_argument("--plant", default=None, help="a plant file (.toml/.json) passed to the ETB envs as plant=")
    ap.add_argument("--num-envs", "--n", type=int, nargs="+", default=[1, 64, 1024],
                    help="vector env sizes N (default 1 64 1024)")
    ap.add_argument("--threads", type=int, default=None, help="num_threads of the vector env (default: automatic)")
    ap.add_argument("--compare", nargs="+", default=[], metavar="ID",
                    help="further gymnasium env ids to time as yardsticks (Pendulum-v1 is always timed)")
    ap.add_argument("--equal-accuracy-substeps", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--no-gem", action="store_true", help="skip gym-electric-motor (reported as null)")
    ap.add_argument("--excitation-s", type=float, default=2.0,
                    help="length of the rich excitation for fast path vs solve_ivp (default 2 s)")
    ap.add_argument("--no-reference", action="store_true", help="skip the solve_ivp and plain-path timings")
    ap.add_argument("--json-out", default=None, help="also write the JSON object to this file (atomically)")
    ap.add_argument("--seed", type=int, default=0, help="seed of envs and actions (default 0)")
    ap.add_argument("--baseline", metavar="REV", default=None,
                    help="a git revision to measure side by side with this tree (before -> after medians)")
    a = ap.parse_args(argv)
    if a.threads is not None and a.threads < 1:
        ap.error(f"--threads = {a.threads}: expected an integer >= 1")
    if a.repeats < 1:
        ap.error(f"--repeats = {a.repeats}: expected an integer >= 1")
    if not (math.isfinite(a.seconds) and a.seconds > 0):
        ap.error(f"--seconds = {a.seconds}: expected a duration > 0 s")
    if any(n < 1 for n in a.num_envs):
        ap.error(f"--num-envs = {a.num_envs}: expected integers >= 1")
    if not (math.isfinite(a.excitation_s) and a.excitation_s >= 0.01):
        ap.error(f"--excitation-s = {a.excitation_s}: expected a duration >= 0.01 s")
    if a.plant is not None and not Path(a.plant).is_file():
        ap.error(f"--plant = {a.plant!r}: no such file (expected a plant file .toml or .json)")
    return a


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


def fmt_rate(v):
    if v is None:
        return "n/a"
    return f"{v / 1e6:.3f} M" if v >= 1e6 else f"{v:,.0f}"


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


# ---------------------------------------------------------------------------------------------- main
def build_cases(args):
    import gymnasium as gym

    import etb_gym  # noqa: F401  (registers the ids)
    from etb_gym import make_plant

    env_kw = {} if args.plant is None else {"plant": args.plant}
    cases, notes = [], []

    def make_etb(**kw):
        return lambda: gym.make(args.env_id, **env_kw, **kw)

    vec_kw = dict(env_kw) if args.threads is None else dict(env_kw, num_threads=args.threads)
    probe = gym.make(args.env_id, **env_kw)
    plant = probe.unwrapped.plant
    dt = probe.unwrapped.dt
    fast = bool(plant.fast)
    probe.close()
    sw_probe = gym.make(args.env_id, pwm_mode="switching", **env_kw)
    fast_sw = bool(sw_probe.unwrapped.plant.fast)
    sw_probe.close()
    if not (fast and fast_sw):
        notes.append("PLAIN PATH: a component of this plant has no compiled kernel "
                     "(FastPathUnavailableWarning); the ETB figures are of the slow plain Python path")
    cases.append(GymEnvCase("etb", f'gym.make("{args.env_id}")', make_etb(), args.seed, dt, fast))
    cases.append(GymEnvCase("etb_switching", f'gym.make("{args.env_id}", pwm_mode="switching")',
                            make_etb(pwm_mode="switching"), args.seed, dt, fast_sw))
    cases.append(ResetCase(make_etb(), args.seed, fast))
    for N in args.num_envs:
        vc = VectorCase(args.env_id, N, vec_kw, args.seed, dt, fast)
        notes.append(f"make_vec N={N}: {vc.kind}")
        cases.append(vc)
    if args.equal_accuracy_substeps is not None:
        N = max(args.num_envs)
        eq_plant = plant.replace(substeps=args.equal_accuracy_substeps)
        cases.append(VectorCase(args.env_id, N, dict(vec_kw, plant=eq_plant), args.seed, dt, fast, key="vector_eqacc",
                                label=f"make_vec N={N}, {eq_plant.substeps} substeps (equal accuracy)"))
    for other in args.compare:
        cases.append(GymEnvCase(f"compare:{other}", f'gym.make("{other}")', lambda other=other: gym.make(other),
                                args.seed))
    cases.append(GymEnvCase("pendulum", 'gym.make("Pendulum-v1")', lambda: gym.make("Pendulum-v1"), args.seed,
                            0.05))
    gem_note = None
    if args.no_gem:
        gem_note = "gym-electric-motor: skipped (--no-gem)"
    else:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                import gym_electric_motor  # noqa: F401  (registers its ids with gymnasium)

                gem_env = gym.make(GEM_ID)
                tau = float(gem_env.unwrapped.physical_system.tau)
                gem_env.close()
            from importlib.metadata import version

            cases.append(GymEnvCase("gem", f'gym.make("{GEM_ID}") (gym-electric-motor {version("gym-electric-motor")})',
                                    lambda: gym.make(GEM_ID), args.seed, tau))
        except Exception as e:  # not installed, or its API does not fit the installed gymnasium
            gem_note = f"gym-electric-motor: not measured ({type(e).__name__}: {e})"
    if gem_note:
        notes.append(gem_note)
    core = plant if args.plant is not None else make_plant("3B")
    cases.append(PlantStepCase(core, args.seed))
    cases.append(KernelBatchCase(core, 1024, args.seed))
    return cases, notes, core


def excitation_timings(plant, args, bar):
    from etb_gym.excitation import rich_excitation

    d = rich_excitation(duration_s=args.excitation_s, dt=plant.control_period_s)
    plant.simulate(d)                                   # compile / load
    fast = []
    for _ in range(args.repeats):
        t = time.perf_counter()
        plant.simulate(d)
        fast.append(time.perf_counter() - t)
    out = {"excitation_s": args.excitation_s, "excitation_fast_s": statistics.median(fast)}
    bar.update(1)
    if args.no_reference:
        out.update(excitation_solve_ivp_s=None, excitation_plain_s=None, excitation_speedup_vs_solve_ivp=None)
        return out
    bar.set_postfix_str("solve_ivp reference")
    t = time.perf_counter()
    plant.reference(d)
    out["excitation_solve_ivp_s"] = time.perf_counter() - t
    bar.update(1)
    bar.set_postfix_str("plain path")
    t = time.perf_counter()
    plant.simulate(d, path="plain")
    out["excitation_plain_s"] = time.perf_counter() - t
    out["excitation_speedup_vs_solve_ivp"] = out["excitation_solve_ivp_s"] / out["excitation_fast_s"]
    bar.update(1)
    return out


def find_equal_accuracy(args, target_deg: float = EQUAL_ACCURACY_DEG) -> dict:
    """The fewest substeps (as the stepper uses them, see integrate.substeps_used) at which the benchmark plant's
    angle on 2 s of rich_excitation is within ``target_deg`` RMS of solve_ivp."""
    import gymnasium as gym

    import etb_gym  # noqa: F401
    from etb_gym.excitation import rich_excitation
    from etb_gym.integrate import substeps_used

    env = gym.make(args.env_id, **({} if args.plant is None else {"plant": args.plant}))
    plant = env.unwrapped.plant
    env.close()
    d = rich_excitation(duration_s=2.0, dt=plant.control_period_s)
    ref = plant.reference(d).angle_deg
    tried = {}
    for n in range(1, 201):
        used = substeps_used(plant.control_period_s, n)
        if used in tried:
            continue
        err = plant.replace(substeps=n).simulate(d).angle_deg - ref
        tried[used] = rms = float(np.sqrt(np.mean(err ** 2)))
        if rms <= target_deg:
            return {"substeps": used, "rms_deg": rms, "target_deg": target_deg, "tried": tried}
    return {"substeps": None, "rms_deg": None, "target_deg": target_deg, "tried": tried}


def machine_info():
    info = {"python": platform.python_version(), "machine": platform.machine(), "cpus": os.cpu_count()}
    try:
        info["loadavg_1min"] = round(os.getloadavg()[0], 2)
    except OSError:
        info["loadavg_1min"] = None
    try:
        import numba

        from etb_gym.integrate import ensure_thread_pool

        info["numba"] = numba.__version__
        info["numba_threads"] = numba.get_num_threads()
        info["thread_pool"] = ensure_thread_pool()
        try:
            info["threading_layer"] = numba.threading_layer()
        except ValueError:
            info["threading_layer"] = None
    except ImportError:
        info["numba"] = None
    return info


# ---------------------------------------------------------------------------------------------- --baseline
def extract_revision(rev: str, into: Path) -> tuple[Path, Path]:
    """REV's source tree (git archive) and an importable package directory for it (the package layout of
    its pyproject.toml: etb_gym.envs lives in envs/, ...). Returns (source, PYTHONPATH entry)."""
    src, pkg = into / "src", into / "pkg"
    src.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(src)], input=archive, check=True)
    layout = tomllib.loads((src / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    shutil.copytree(src / layout.get("etb_gym", "etb_gym"), pkg / "etb_gym")
    for name, path in layout.items():
        target = pkg / name.replace(".", "/")
        if name != "etb_gym" and not target.exists():
            target.symlink_to(src / path, target_is_directory=True)
    return src, pkg


def _flatten(res: dict) -> dict:
    """The compared figures of one run: name -> value."""
    out = {k: res[k] for k in ("etb_steps_per_s", "etb_switching_steps_per_s", "reset_us", "pendulum_steps_per_s",
                               "gem_steps_per_s", "plant_step_us", "kernel_1024_steps_per_s", "ratio_etb_vs_gem",
                               "ratio_etb_vs_pendulum")}
    out.update({f"vector_{n}_steps_per_s": v for n, v in res["vector_steps_per_s"].items()})
    out.update({f"cpu_us_per_step.{k}": v for k, v in res["cpu_us_per_step"].items()})
    if res.get("vector_steps_per_s_at_equal_accuracy") is not None:
        out["vector_steps_per_s_at_equal_accuracy"] = res["vector_steps_per_s_at_equal_accuracy"]
    return out


def _medians(runs: list[dict]) -> dict:
    out = {}
    for k in runs[0]:
        values = [r.get(k) for r in runs]
        out[k] = None if None in values else statistics.median(values)
    return out


def compare_with_baseline(args, eq):
    common = ["--repeats", "1", "--seconds", str(args.seconds), "--env-id", args.env_id, "--no-reference",
              "--excitation-s", "0.1", "--seed", str(args.seed), "--num-envs", *map(str, args.num_envs)]
    common += ["--no-gem"] if args.no_gem else []
    common += ["--plant", str(Path(args.plant).resolve())] if args.plant else []
    with tempfile.TemporaryDirectory(prefix="etb_bench_baseline_") as tmp:
        src, pkg = extract_revision(args.baseline, Path(tmp))
        env_before = dict(os.environ, PYTHONPATH=str(pkg))
        extra = [] if args.equal_accuracy_substeps is None else \
            ["--equal-accuracy-substeps", str(args.equal_accuracy_substeps)]
        runs = {"before": ([sys.executable, str(src / "scripts" / "bench_speed.py"), *common], env_before),
                "after": ([sys.executable, "-m", "etb_gym.speed", *common, *extra], dict(os.environ))}
        results = {k: [] for k in runs}
        load_start = machine_info().get("loadavg_1min")
        for r in range(args.repeats):
            for label, (cmd, env) in runs.items():
                log(f"--baseline: round {r + 1}/{args.repeats}, {label}")
                out = subprocess.run(cmd, env=env, cwd=tmp, capture_output=True, text=True)
                if out.returncode:
                    raise SystemExit(f"speed --baseline: the {label} run failed:\n{out.stderr[-3000:]}")
                results[label].append(json.loads(out.stdout.strip().splitlines()[-1]))
                bar_note = f"{label}: vector N=1024 {results[label][-1]['vector_steps_per_s'].get('1024')}"
                log(bar_note)
    load_end = machine_info().get("loadavg_1min")
    med = {label: _medians([_flatten(r) for r in rs]) for label, rs in results.items()}
    print(f"\n{args.baseline} (before) vs this tree (after): medians of {args.repeats} alternating rounds of "
          f"~{args.seconds:g} s per case, load average {load_start} -> {load_end}\n")
    print("| figure | before | after | after / before |")
    print("|---|---|---|---|")
    for k, b in med["before"].items():
        a = med["after"].get(k)
        if a is None or b is None:
            continue
        fmt = (lambda v: f"{v:.2f}") if (k.endswith("_us") or k.startswith(("cpu", "ratio"))) else fmt_rate
        print(f"| {k} | {fmt(b)} | {fmt(a)} | {a / b:.2f} |")
    eq_after = med["after"].get("vector_steps_per_s_at_equal_accuracy")
    n_max = max(args.num_envs)
    eq_before = med["before"].get(f"vector_{n_max}_steps_per_s")
    if eq_after is not None and eq_before is not None:
        print(f"| make_vec N={n_max} at equal accuracy ({EQUAL_ACCURACY_DEG} deg RMS): before at its 20 substeps, "
              f"after at {args.equal_accuracy_substeps} | {fmt_rate(eq_before)} | {fmt_rate(eq_after)} | "
              f"{eq_after / eq_before:.2f} |")
    res = dict(results["after"][-1])
    dt = res["etb_sim_s_per_wall_s"] / res["etb_steps_per_s"]      # the control period (of the last run)
    res.update({k: med["after"][k] for k in ("etb_steps_per_s", "reset_us", "pendulum_steps_per_s", "gem_steps_per_s",
                                             "ratio_etb_vs_gem", "ratio_etb_vs_pendulum")})
    res["etb_sim_s_per_wall_s"] = med["after"]["etb_steps_per_s"] * dt
    res["etb_switching_realtime_factor"] = med["after"]["etb_switching_steps_per_s"] * dt
    res["vector_steps_per_s"] = {str(n): med["after"][f"vector_{n}_steps_per_s"] for n in args.num_envs}
    res["baseline"] = {"revision": args.baseline, "medians_before": med["before"], "medians_after": med["after"],
                       "rounds": args.repeats, "loadavg_1min": [load_start, load_end]}
    res["substeps_for_0p044_deg"] = args.equal_accuracy_substeps
    res["equal_accuracy"] = eq
    res["vector_steps_per_s_at_equal_accuracy"] = eq_after
    res["ratio_vector_at_equal_accuracy_vs_baseline"] = None if eq_after is None or eq_before is None \
        else eq_after / eq_before
    if args.json_out:
        atomic_write(Path(args.json_out), json.dumps(res, indent=2) + "\n")
    print(json.dumps(res))
    return res


def run(argv=None) -> dict:
    """The whole measurement; returns the JSON object (also printed as the last line of stdout)."""
    args = parse_args(argv)
    eq = None
    if args.equal_accuracy_substeps is None and not args.no_reference:
        log(f"speed: the substeps that reach {EQUAL_ACCURACY_DEG} deg RMS against solve_ivp (2 s rich excitation)")
        eq = find_equal_accuracy(args)
        args.equal_accuracy_substeps = eq["substeps"]
    if args.baseline:
        return compare_with_baseline(args, eq)
    log("speed: building envs (first run compiles the numba kernels, ~1 min; cached afterwards)")
    load_start = machine_info().get("loadavg_1min")
    cases, notes, core = build_cases(args)
    bar = progress(len(cases) * (args.repeats + 1) + 3, "etb-gym speed")
    iters = {}
    for c in cases:
        bar.set_postfix_str(f"warm-up {c.key}")
        iters[c.key] = calibrate(c, args.seconds)
        bar.update(1)
    rates = {c.key: [] for c in cases}
    cpu = {c.key: [] for c in cases}
    for r in range(args.repeats):
        for c in cases:
            bar.set_postfix_str(f"repeat {r + 1}/{args.repeats} {c.key}")
            units, wall, cpu_s = timed(c, iters[c.key])
            rates[c.key].append(units / wall)
            cpu[c.key].append(cpu_s / units)
            bar.update(1)
    exc = excitation_timings(core, args, bar)
    bar.close()
    for c in cases:
        c.close()
    med = {k: statistics.median(v) for k, v in rates.items()}
    cpu_us = {k: 1e6 * statistics.median(v) for k, v in cpu.items()}
    spread = {k: (min(v), max(v)) for k, v in rates.items()}
    info = machine_info()
    info["loadavg_1min_start"] = load_start

    etb, sw = med["etb"], med["etb_switching"]
    dt = next(c.sim_dt for c in cases if c.key == "etb")
    gem = med.get("gem")
    res = {
        "env_id": args.env_id,
        "plant_file": args.plant,
        "fast_path": bool(all(c.fast for c in cases if c.fast is not None)),
        "etb_steps_per_s": etb,
        "etb_sim_s_per_wall_s": etb * dt,
        "etb_switching_steps_per_s": sw,
        "etb_switching_realtime_factor": sw * dt,
        "vector_steps_per_s": {str(N): med[f"vector_{N}"] for N in args.num_envs},
        "pendulum_steps_per_s": med["pendulum"],
        "gem_steps_per_s": gem,
        "gem_sim_s_per_wall_s": None if gem is None else gem * next(c.sim_dt for c in cases if c.key == "gem"),
        "reset_us": 1e6 / med["reset"],
        "substeps_for_0p044_deg": args.equal_accuracy_substeps,
        "equal_accuracy": eq,
        "vector_steps_per_s_at_equal_accuracy": med.get("vector_eqacc"),
        "compare_steps_per_s": {c.key.split(":", 1)[1]: med[c.key] for c in cases if c.key.startswith("compare:")},
        "plant_step_us": 1e6 / med["plant_step"],
        "kernel_1024_steps_per_s": med["kernel_1024"],
        "ratio_etb_vs_gem": None if gem is None else etb / gem,
        "ratio_etb_vs_pendulum": etb / med["pendulum"],
        "cpu_us_per_step": cpu_us,
        **exc,
        "repeats": args.repeats,
        "seconds_per_repeat": args.seconds,
        "machine": info,
        "notes": notes,
    }
    v1024 = res["vector_steps_per_s"].get("1024")
    res["targets"] = {
        "etb >= 15x gem": None if gem is None else res["ratio_etb_vs_gem"] >= TARGETS["ratio_etb_vs_gem"],
        "etb >= 0.5x pendulum": res["ratio_etb_vs_pendulum"] >= TARGETS["ratio_etb_vs_pendulum"],
        "vector N=1024 >= 1e6 plant-steps/s": None if v1024 is None else v1024 >= TARGETS["vector_1024_steps_per_s"],
        "switching >= 10x real time": res["etb_switching_realtime_factor"] >= TARGETS["etb_switching_realtime_factor"],
        "reset < 50 us": res["reset_us"] < TARGETS["reset_us_max"],
    }
    print_table(cases, med, cpu_us, spread, res)
    if args.json_out:
        atomic_write(Path(args.json_out), json.dumps(res, indent=2) + "\n")
    print(json.dumps(res))
    return res


def main(argv=None) -> int:
    """``etb-gym speed``: run the harness; 0 on success (argument errors exit 2 through argparse)."""
    run(argv)
    return 0


def print_table(cases, med, cpu_us, spread, res):
    m = res["machine"]
    print(f"\netb-gym speed, {res['repeats']} repeats of ~{res['seconds_per_repeat']:g} s per case, medians; "
          f"{m['cpus']} CPUs, load average {m['loadavg_1min_start']} -> {m['loadavg_1min']}, "
          f"numba {m.get('numba')} threads {m.get('numba_threads')} layer {m.get('threading_layer')} "
          f"({m.get('thread_pool')})")
    print("\n| case | path | rate | min..max | CPU us/step | sim s / wall s |")
    print("|---|---|---|---|---|---|")
    for c in cases:
        path = "" if c.fast is None else ("fast (numba)" if c.fast else "**PLAIN (no compiled kernel)**")
        lo, hi = spread[c.key]
        real = "" if c.sim_dt is None else f"{med[c.key] * c.sim_dt:,.1f}"   # vector: summed over plants
        print(f"| {c.label} | {path} | {fmt_rate(med[c.key])} {c.unit} | {fmt_rate(lo)}..{fmt_rate(hi)} | "
              f"{cpu_us[c.key]:.2f} | {real} |")
    print(f"\nreset: {res['reset_us']:.1f} us;  Plant.step: {res['plant_step_us']:.2f} us")
    e = res
    if e.get("excitation_solve_ivp_s") is not None:
        print(f"3B rich excitation ({e['excitation_s']:g} s): fast path {e['excitation_fast_s'] * 1e3:.2f} ms, "
              f"solve_ivp {e['excitation_solve_ivp_s']:.2f} s ({e['excitation_speedup_vs_solve_ivp']:,.0f}x), "
              f"plain path {e['excitation_plain_s']:.2f} s")
    else:
        print(f"3B rich excitation ({e['excitation_s']:g} s): fast path {e['excitation_fast_s'] * 1e3:.2f} ms")
    g = res["ratio_etb_vs_gem"]
    print(f"ratios (same run): ETB / gym-electric-motor = {'n/a' if g is None else f'{g:.1f}x'}, "
          f"ETB / Pendulum-v1 = {res['ratio_etb_vs_pendulum']:.2f}x")
    print("targets: " + ", ".join(f"{k}: {'n/a' if v is None else ('met' if v else 'NOT met')}"
                                  for k, v in res["targets"].items()))
    for n in res["notes"]:
        print(f"note: {n}")
    sys.stdout.flush()


if __name__ == "__main__":
    sys.exit(main())
