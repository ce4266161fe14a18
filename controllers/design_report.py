"""``etb-gym design``: the design report (linearized plant, designed PID gains and margins per scheduling
angle, sliding-mode and cascade gains, Bode / step plots). It sits above the controllers, which import
:mod:`etb_gym.controllers.design` for their gains, so that module imports no controller."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .design import _mode_text, current_feedback_poles, describe_plant, linearize

def main(argv=None) -> int:
    """``etb-gym design``: linearized plant, designed PID gains and margins per scheduling angle, the
    sliding-mode gains, the ECU cascade's current loop, and Bode / step plots (PNG) of the designed loops."""
    import argparse

    from etb_gym.plant import MODELS

    p = argparse.ArgumentParser(prog="etb-gym design", description=main.__doc__.split("\n\n")[0].replace("``", ""))
    p.add_argument("--model", default="3B", help=f"plant model, one of {', '.join(MODELS)} (default 3B)")
    p.add_argument("--out", default="docs/figures/controllers", help="folder for the PNGs")
    p.add_argument("--no-plots", action="store_true", help="print the design only")
    a = p.parse_args(argv)
    if a.model.upper() not in MODELS:
        p.error(f"unknown model {a.model!r}: valid are {', '.join(MODELS)}")
    from .ptos import PTOSController
    from .pid import PIDController
    from .smc import SlidingModeController

    model = a.model.upper()
    pid = PIDController(model=model)
    smc = SlidingModeController(model=model)
    ptos = PTOSController(model=model)
    print(f"Nominal model {model}: {pid.model.describe()}")
    for ang in pid.schedule_rad:
        print(describe_plant(pid.model.plant, float(ang)))
    print("\npid-plain: PID designs (crossover 50 rad/s, phase margin >= 50 deg), scheduled on the reference angle:")
    for d in pid.designs:
        print("  " + d.summary())
    print(f"  friction compensator linear zone e_fc = {math.degrees(pid.friction_zone_rad):.4f} deg, "
          f"level T_s/T_c = {pid.model.static_Nm}/{pid.model.coulomb_Nm} Nm")
    print(f"\nsmc-plain: lambda = {smc.lambda_rad_s:g} rad/s, K = {smc.K_V:.3f} V, layer gain K/Phi = "
          f"{smc.layer_gain:.4f} V s/rad, Phi = {smc.phi_layer:.2f} rad/s, k0 = {smc.k0:g} rad/s")
    print(f"\nECU cascade (pid, smc, ptos): current feedback K_c = {ptos.Kc:g} V/A, friction zone "
          f"{math.degrees(ptos.friction_zone):.3f} deg")
    for ang in (13.0, 80.0):
        phi0 = math.radians(ang)
        print(f"  electro-mechanical mode at {ang:g} deg: voltage drive "
              f"{_mode_text(linearize(pid.model.plant, phi0, 'sliding').poles())}; with K_c: "
              f"{_mode_text(current_feedback_poles(pid.model.plant, phi0, ptos.Kc))}")
    if a.no_plots:
        return 0
    out = Path(a.out)
    files = _plot_pid(pid, model, out)
    print("\nwrote " + ", ".join(str(f) for f in files))
    return 0


def _plot_pid(pid, model: str, out: Path) -> list:
    """Bode plot and linear closed-loop steps of the voltage-mode PID designs (local Agg canvases)."""
    import control
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    T = pid.dt
    w = np.logspace(0, math.log10(0.99 * math.pi / T), 600)
    fig = Figure(figsize=(7, 6))
    axm, axp = fig.subplots(2, 1, sharex=True)
    fig_s = Figure(figsize=(7, 4))
    axs = fig_s.subplots()
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
    axm.set_title(f"pid-plain loop L = C(z) P(z), model {model} linearized (sliding friction)", fontsize=9)
    axm.legend(fontsize=8)
    for ax in (axm, axp):
        ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    axs.set_xlabel("time [ms]")
    axs.set_ylabel("angle / reference")
    axs.set_title(f"Linear closed-loop step responses of the pid-plain designs (model {model})", fontsize=9)
    axs.grid(alpha=0.3)
    axs.legend(fontsize=8)
    fig_s.tight_layout()
    files = [out / f"pid_bode_{model}.png", out / f"pid_step_{model}.png"]
    for f, path in zip((fig, fig_s), files):
        save_png(f, path, FigureCanvasAgg)
    return files


def save_png(fig, path: Path, canvas_cls=None) -> None:
    """Render a matplotlib Figure on its own Agg canvas and write it atomically (etb_gym.io.write_atomic)."""
    from etb_gym.io import write_atomic

    if canvas_cls is None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg as canvas_cls
    canvas_cls(fig)
    write_atomic(Path(path), lambda fh: fig.savefig(fh, dpi=90, format="png"))
