"""The speed harness's table (etb_gym.speed): rates formatted, one row per case, the ratios and targets."""
from __future__ import annotations

import sys


def fmt_rate(v):
    if v is None:
        return "n/a"
    return f"{v / 1e6:.3f} M" if v >= 1e6 else f"{v:,.0f}"


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
