#!/usr/bin/env python
"""Show the controller design: linearized plant, designed PID gains and margins per scheduling angle, the
sliding-mode gains, and Bode / step plots (PNG) of the designed loops.

    python scripts/design_controllers.py                      # ETB-3B plant, figures in docs/figures/controllers
    python scripts/design_controllers.py --model 1A --out out/design
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np


def _save(fig, path: Path):
    from etb_gym.io import write_atomic
    write_atomic(path, lambda fh: fig.savefig(fh, dpi=90, format="png"))


def main(argv=None) -> int:
    from etb_gym.plant import MODELS

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--model", default="3B", help=f"plant model, one of {', '.join(MODELS)} (default 3B)")
    p.add_argument("--out", default="docs/figures/controllers", help="folder for the PNGs")
    p.add_argument("--no-plots", action="store_true")
    a = p.parse_args(argv)
    if a.model.upper() not in MODELS:
        p.error(f"unknown model {a.model!r}: valid are {', '.join(MODELS)}")

    import matplotlib

    matplotlib.use("Agg")
    import control
    import matplotlib.pyplot as plt

    from etb_gym.controllers.design import describe_plant, linearize
    from etb_gym.controllers.pid import PIDController
    from etb_gym.controllers.smc import SlidingModeController

    model = a.model.upper()
    pid = PIDController(model=model)
    smc = SlidingModeController(model=model)
    print(f"Nominal model {model}: {pid.model.describe()}")
    for ang in pid.schedule_rad:
        print(describe_plant(pid.model.plant, float(ang)))
    print("\nPID designs (crossover 50 rad/s, phase margin >= 50 deg), scheduled on the reference angle:")
    for d in pid.designs:
        print("  " + d.summary())
    print(f"  friction compensator linear zone e_fc = {math.degrees(pid.friction_zone_rad):.4f} deg, "
          f"level T_s/T_c = {pid.model.static_Nm}/{pid.model.coulomb_Nm} Nm")
    print(f"\nSliding mode: lambda = {smc.lambda_rad_s:g} rad/s, K = {smc.K_V:.3f} V, layer gain K/Phi = "
          f"{smc.layer_gain:.4f} V s/rad, Phi = {smc.phi_layer:.2f} rad/s, k0 = {smc.k0:g} rad/s")
    if a.no_plots:
        return 0
    out = Path(a.out)
    T = pid.dt
    w = np.logspace(0, math.log10(0.99 * math.pi / T), 600)
    fig, (axm, axp) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    fig_s, axs = plt.subplots(figsize=(7, 4))
    for d in pid.designs:
        Pd = linearize(pid.model.plant, d.phi0_rad, "sliding").discrete(T)
        L = d.controller_tf() * Pd
        resp = np.array([complex(np.asarray(L(np.exp(1j * x * T))).ravel()[0]) for x in w])
        lab = f"{math.degrees(d.phi0_rad):.1f} deg: PM {d.phase_margin_deg:.0f} deg, GM {20 * math.log10(d.gain_margin):.1f} dB"
        axm.semilogx(w, 20 * np.log10(np.abs(resp)), label=lab)
        axp.semilogx(w, np.degrees(np.unwrap(np.angle(resp))) - 360 * (np.degrees(np.angle(resp[0])) > 0))
        cl = control.feedback(L, 1)
        t, y = control.step_response(cl, T=np.arange(0, 0.3, T))
        axs.plot(t * 1e3, np.squeeze(y), label=f"{math.degrees(d.phi0_rad):.1f} deg")
    axm.axhline(0, color="k", lw=0.6)
    axp.axhline(-180, color="k", lw=0.6)
    axm.set_ylabel("|L| [dB]")
    axp.set_ylabel("arg L [deg]")
    axp.set_xlabel("frequency [rad/s]")
    axm.set_title(f"Designed PID loop L = C(z) P(z), model {model} linearized (sliding friction)", fontsize=9)
    axm.legend(fontsize=8)
    for ax in (axm, axp):
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    _save(fig, out / f"pid_bode_{model}.png")
    axs.set_xlabel("time [ms]")
    axs.set_ylabel("angle / reference")
    axs.set_title(f"Linear closed-loop step responses of the PID designs (model {model})", fontsize=9)
    axs.grid(alpha=0.3)
    axs.legend(fontsize=8)
    fig_s.tight_layout()
    _save(fig_s, out / f"pid_step_{model}.png")
    print(f"\nwrote {out}/pid_bode_{model}.png, {out}/pid_step_{model}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
