"""Speed of etb-gym side by side with gymnasium's Pendulum-v1 and gym-electric-motor, in one run: the one
speed harness (``etb-gym speed``, ``python -m etb_gym.speed``; scripts/bench_speed.py and
``python -m etb_gym.envs.benchmark`` are thin wrappers of it).

    etb-gym speed                                       # full run (~2 min), table + one JSON line last
    etb-gym speed --repeats 3 --seconds 0.3 --no-gem
    etb-gym speed --plant my_plant.toml                 # benchmark a plant file (e.g. with diagnosed effects)
    etb-gym speed --json-out speed.json                 # also write the JSON object to a file (atomic)
    etb-gym speed --baseline 5dc542e                    # before/after: that git revision vs this tree
    etb-gym speed --baseline 14d52f1 --baseline-substeps 5   # ... and that revision's make_vec at 5 substeps
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
                   ``vector_steps_per_s_at_equal_accuracy`` (null with --no-reference), its CPU per plant-step
                   and the rate that CPU allows on all cores (``vector_steps_per_s_bound_at_equal_accuracy``)
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
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from .speed_baseline import EQUAL_ACCURACY_DEG, ROOT, compare_with_baseline, extract_revision  # noqa: F401
from .speed_cases import (N_ACTIONS, Case, GymEnvCase, KernelBatchCase, PlantStepCase, ResetCase,  # noqa: F401
                          VectorCase, atomic_write, calibrate, log, machine_info, progress, timed)
from .speed_report import fmt_rate, print_table  # noqa: F401

TARGETS = {   # issue 7, benchmark figures (not timed tests)
    "ratio_etb_vs_gem": 15.0,
    "ratio_etb_vs_pendulum": 0.5,
    "vector_1024_steps_per_s": 1_000_000.0,
    "etb_switching_realtime_factor": 10.0,
    "reset_us_max": 50.0,
}
GEM_ID = "Cont-SC-PermExDc-v0"


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
    ap.add_argument("--baseline-substeps", type=int, default=None, metavar="N",
                    help="with --baseline: also time REV's make_vec at N substeps (REV's own fewest substeps for "
                         "the equal accuracy, e.g. 5 for the stepper of issue 12 at h_max = 200 us; REV raises N "
                         "to what its h_max allows)")
    a = ap.parse_args(argv)
    if a.threads is not None and a.threads < 1:
        ap.error(f"--threads = {a.threads}: expected an integer >= 1")
    if a.baseline_substeps is not None and (a.baseline is None or a.baseline_substeps < 1):
        ap.error(f"--baseline-substeps = {a.baseline_substeps}: expected an integer >= 1, with --baseline")
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
    med, cpu_us, spread = measure(cases, args, bar)
    exc = excitation_timings(core, args, bar)
    bar.close()
    for c in cases:
        c.close()
    res = results(args, cases, med, cpu_us, notes, exc, eq, load_start)
    print_table(cases, med, cpu_us, spread, res)
    if args.json_out:
        atomic_write(Path(args.json_out), json.dumps(res, indent=2) + "\n")
    print(json.dumps(res))
    return res


def measure(cases, args, bar):
    """Warm up every case, then ``args.repeats`` rounds over all cases (round-robin): medians of the rates, CPU
    us per unit, and each rate's (min, max)."""
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
    med = {k: statistics.median(v) for k, v in rates.items()}
    cpu_us = {k: 1e6 * statistics.median(v) for k, v in cpu.items()}
    spread = {k: (min(v), max(v)) for k, v in rates.items()}
    return med, cpu_us, spread


def results(args, cases, med, cpu_us, notes, exc, eq, load_start) -> dict:
    """The JSON object of one run (figures, ratios, targets, machine)."""
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
        "vector_cpu_us_per_plant_step_at_equal_accuracy": cpu_us.get("vector_eqacc"),
        # what that CPU per plant-step allows with every core of this machine busy (cores / CPU per plant-step)
        "vector_steps_per_s_bound_at_equal_accuracy": None if cpu_us.get("vector_eqacc") is None
        else (info.get("cpus") or 1) * 1e6 / cpu_us["vector_eqacc"],
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
    return res


def main(argv=None) -> int:
    """``etb-gym speed``: run the harness; 0 on success (argument errors exit 2 through argparse)."""
    run(argv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
