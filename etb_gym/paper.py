"""Regenerate analogues of the paper's Figs. 8, 12, 13, 14 and 15 from etb-gym's models.

    etb-gym reproduce --out out/paper            # all five figures
    etb-gym reproduce --out /tmp/p --only 8 13   # a selection
    etb-gym reproduce --dpi 50                   # smaller images

Each figure is written as ``figNN_<topic>.png`` into the output folder; one line per figure on what it
shows (with the numbers measured in that run) is printed and collected in ``figures.md``.

The paper's figures compare the models with measurements from a test rig; we have no measurements, so
every figure here shows the models only. What each figure reproduces (paper sections):

    Fig. 8   sec. 4.4  electric subsystem alone, J*phi'' = T_el (eq. 15), at u = 1.5 V, drives A, B, C
    Fig. 12  sec. 5.3  LuGre presliding displacement on a slow voltage ramp, model 3B
    Fig. 13  sec. 5.4  release from 90 deg at zero voltage, friction models 1, 2, 3 (drive B)
    Fig. 14  sec. 7    voltage steps u_SP = 4, 5, 6 V, models 1A and 3B
    Fig. 15  sec. 7    voltage steps u_SP = 4, 6 V, models 2B and 3B

All simulation goes through ``etb_gym`` (``make_plant``/``Plant.simulate``); nothing here re-derives a
plant equation.
"""
from __future__ import annotations

import argparse
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from etb_gym import Plant, make_plant
from etb_gym.io import write_atomic
from etb_gym.components import EndStops, FluxDrive, LinearDrive, NonlinearInductanceDrive

DRIVE_COLORS = {"A": "tab:blue", "B": "tab:orange", "C": "tab:green"}
VOLT_COLORS = {4.0: "tab:blue", 5.0: "tab:orange", 6.0: "tab:red"}
FRICTION_NAMES = {"1": "1 viscous", "2": "2 Dahl", "3": "3 LuGre"}


@dataclass
class Settings:
    dpi: int = 100       # image resolution; the simulations are the same at any resolution


def subplots(nrows: int = 1, ncols: int = 1, **kw):
    """``plt.subplots`` on a local Agg canvas: no pyplot state, no backend switch for the caller's process."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig_kw = {k: kw.pop(k) for k in ("figsize", "constrained_layout") if k in kw}
    fig = Figure(**fig_kw)
    FigureCanvasAgg(fig)
    return fig, fig.subplots(nrows, ncols, **kw)


def panel(ax, ylabel: str, *, xlabel: str | None = None, ylim=None, legend: dict | None = None) -> None:
    """One panel of a paper figure, after its curves are drawn: axis labels, limits, legend (``ax.legend``
    keywords) and the figures' light grid."""
    ax.set_ylabel(ylabel)
    if xlabel is not None:
        ax.set_xlabel(xlabel)
    if ylim is not None:
        ax.set_ylim(*ylim)
    if legend is not None:
        ax.legend(**legend)
    ax.grid(alpha=0.3)


def save_png(fig, path: Path, dpi: int) -> None:
    """Write a figure atomically (one helper: etb_gym.io.write_atomic)."""
    write_atomic(path, lambda fh: fig.savefig(fh, format="png", dpi=dpi))


def write_text(path: Path, text: str) -> None:
    write_atomic(path, text)


def first_time(t, mask):
    """First time at which ``mask`` holds, or nan."""
    k = np.flatnonzero(mask)
    return float(t[k[0]]) if k.size else math.nan


def previous_entries(md_path: Path) -> dict:
    """{figure: (png name, line)} from an earlier figures.md, for figures whose PNG still exists
    (so that ``--only`` updates its figures' lines and keeps the others)."""
    entries = {}
    if not md_path.exists():
        return entries
    lines = md_path.read_text(encoding="utf-8").splitlines()
    for k, text in enumerate(lines[:-1]):
        m = re.match(r"- Fig\. (\d+) \((fig\w+\.png)", text)
        if m and m.group(1) in FIGURES and (md_path.parent / m.group(2)).exists():
            entries[m.group(1)] = (m.group(2), text[2:])
    return entries


# ------------------------------------------------------------------------------------------- Fig. 8
def fig08(out: Path, s: Settings):
    """Electric subsystem alone (eq. 15) at 1.5 V: no spring, no friction, only the end stops."""
    n = 300
    u = 1.5
    drives = {"A": LinearDrive(), "B": NonlinearInductanceDrive(), "C": FluxDrive()}
    tr = {k: Plant(drive=d, stops=EndStops()).simulate(voltage=np.full(n, u), angle_deg=0.0)
          for k, d in drives.items()}
    fig, ax = subplots(3, 1, figsize=(8, 7.5), sharex=True, constrained_layout=True)
    for k, r in tr.items():
        t_ms = r.t_s * 1e3
        lbl = {"A": "A linear", "B": "B nonlinear L(i, phi)", "C": "C flux model"}[k]
        ax[0].plot(t_ms, r.angle_deg, color=DRIVE_COLORS[k], ls="--" if k == "B" else "-", label=lbl)
        ax[1].plot(t_ms, r.current_A, color=DRIVE_COLORS[k], ls="--" if k == "B" else "-", label=lbl)
        ax[2].plot(t_ms, r.torques_Nm["drive"] * 1e3, color=DRIVE_COLORS[k], ls="--" if k == "B" else "-",
                   label=lbl)
    ax[0].axhline(30, color="0.6", lw=0.8, ls=":")
    ax[0].text(t_ms[0] + 1, 31, "30 deg", ha="left", va="bottom", color="0.4", fontsize=8)
    panel(ax[0], "angle phi [deg]", ylim=(-3, 95), legend=dict(loc="lower right"))
    panel(ax[1], "coil current i [A]")
    panel(ax[2], "electric torque T_el [mNm]", xlabel="time [ms]")
    ax[0].set_title(f"Paper Fig. 8 analogue: electric subsystem alone, J*phi'' = T_el (eq. 15), u = {u} V\n"
                    "no spring, no friction; end stops at 0 and 90 deg")
    path = out / "fig08_electric_drive.png"
    save_png(fig, path, s.dpi)

    a, b, c = (tr[k] for k in "ABC")
    rms_ab = float(np.sqrt(np.mean((a.angle_deg - b.angle_deg) ** 2)))
    t30 = {k: first_time(r.t_s, r.angle_deg >= 30) * 1e3 for k, r in tr.items()}
    t60 = {k: first_time(r.t_s, r.angle_deg >= 60) * 1e3 for k, r in tr.items()}
    t89 = {k: first_time(r.t_s, r.angle_deg >= 89.5) * 1e3 for k, r in tr.items()}
    dt_a, dt_c = t60["A"] - t30["A"], t60["C"] - t30["C"]
    line = (f"Fig. 8 ({path.name}): drives A/B/C alone (eq. 15) at {u} V: RMS angle difference A-B "
            f"{rms_ab:.2f} deg; from 30 to 60 deg C (torque k_C*cos(phi)*i) takes {dt_c:.0f} ms vs {dt_a:.0f} ms "
            f"for A ({'faster' if dt_c < dt_a else 'not faster'}); time to the 90 deg stop: "
            + ", ".join(f"{k} {t89[k]:.0f} ms" for k in "ABC") + ".")
    return path, line


# ------------------------------------------------------------------------------------------- Fig. 12
def fig12(out: Path, s: Settings):
    """LuGre presliding: model 3B at rest at 10 deg, slow voltage ramp 0 -> 6 V."""
    p = make_plant("3B")
    start_deg = 10.0
    n = 4000
    u_end = 6.0
    volt = np.linspace(0.0, u_end, n)
    x0 = p.initial_state(math.radians(start_deg))          # resting, held by static friction
    r = p.simulate(voltage=volt, x0=x0)
    fr = p.friction.params
    omega_s = fr.stribeck_velocity_rad_s
    k_brk = int(np.argmax(r.velocity_rad_s > omega_s))       # breakaway: sliding faster than omega_s
    if r.velocity_rad_s[k_brk] <= omega_s:
        raise RuntimeError("Fig. 12: the plate never broke away on the ramp; extend the ramp")
    t_brk = r.t_s[k_brk]
    applied = r.torques_Nm["drive"] + r.torques_Nm["spring"]  # net torque the friction has to hold
    friction = -r.torques_Nm["friction"]                       # T_f (opposes the motion)
    pre_deg = float(r.angle_deg[k_brk] - start_deg)

    # show the ramp up to a little after breakaway
    k_end = min(len(r.t_s) - 1, k_brk + int(0.15 * (k_brk + 1)))
    sl = slice(1, k_end + 1)
    t = r.t_s[sl]
    fig, ax = subplots(3, 1, figsize=(8, 7.5), sharex=True, constrained_layout=True)
    ax[0].plot(t, r.voltage_V[sl], color="tab:purple")
    panel(ax[0], "input voltage u_SP [V]")
    ax[1].plot(t, r.angle_deg[sl], color="tab:blue", label="angle phi")
    ax[1].axhline(start_deg, color="0.5", lw=0.8, ls=":", label=f"start {start_deg:g} deg")
    panel(ax[1], "angle phi [deg] (zoomed)", ylim=(start_deg - 0.1, start_deg + max(3 * pre_deg, 0.4)),
          legend=dict(loc="upper left"))
    ax[2].plot(t, applied[sl], color="tab:orange", label="applied T_el - T_sp")
    ax[2].plot(t, friction[sl], color="tab:blue", ls="--", label="friction T_f (LuGre)")
    ax[2].axhline(fr.static_Nm, color="tab:red", lw=0.8, ls=":", label=f"T_s = {fr.static_Nm:g} Nm")
    ax[2].axhline(fr.coulomb_Nm, color="0.4", lw=0.8, ls="-.", label=f"T_c = {fr.coulomb_Nm:g} Nm")
    panel(ax[2], "torque [Nm]", xlabel="time [s]",
          ylim=(min(applied[sl].min(), friction[sl].min()) - 0.02, fr.static_Nm + 0.04),
          legend=dict(loc="upper left", ncol=2, fontsize=8))
    for a in ax:
        a.axvline(t_brk, color="tab:red", lw=1.0)
    ax[1].annotate(f"breakaway t = {t_brk:.2f} s\npresliding {pre_deg:.2f} deg",
                   xy=(t_brk, r.angle_deg[k_brk]), xytext=(-12, 0), textcoords="offset points",
                   ha="right", va="center", color="tab:red", fontsize=9)
    ax[0].set_title("Paper Fig. 12 analogue: presliding displacement before breakaway (model 3B, LuGre)\n"
                    f"at rest at {start_deg:g} deg, voltage ramp 0 -> {u_end:g} V over {n * p.control_period_s:g} s "
                    "(shown until shortly after breakaway)")
    path = out / "fig12_presliding.png"
    save_png(fig, path, s.dpi)
    line = (f"Fig. 12 ({path.name}): 3B at rest at {start_deg:g} deg on a 0->{u_end:g} V ramp: presliding "
            f"displacement {pre_deg:.2f} deg before breakaway at t = {t_brk:.2f} s (u = {r.voltage_V[k_brk]:.2f} V, "
            f"peak friction torque {friction[: k_end + 1].max():.3f} Nm; T_s = {fr.static_Nm:g} Nm, "
            f"T_c = {fr.coulomb_Nm:g} Nm).")
    return path, line


# ------------------------------------------------------------------------------------------- Fig. 13
def dead_band_rad(plant) -> float:
    """Half-width of the band around limp-home where the spring cannot break static friction:
    |phi - phi_LH| <= (T_s - T_SP0)/R_F (zero for viscous friction; T_s = T_c for Dahl)."""
    fp, sp = plant.friction.params, plant.spring.params
    ts = getattr(fp, "static_Nm", getattr(fp, "coulomb_Nm", 0.0))
    return max(ts - sp.preload_Nm, 0.0) / sp.rate_Nm_per_rad


def fig13(out: Path, s: Settings):
    """Release from 90 deg at zero duty (coil freewheels through the bridge), friction 1/2/3, drive B."""
    n = 600
    fig, ax = subplots(figsize=(8, 5.2), constrained_layout=True)
    finals, bands = {}, {}
    colors = {"1": "tab:gray", "2": "tab:orange", "3": "tab:blue"}
    for f in "123":
        p = make_plant(f + "B")
        x0 = p.initial_state(math.radians(90.0), at_rest=False)
        r = p.simulate(np.zeros(n), x0=x0)
        finals[f] = float(r.angle_deg[-1])
        bands[f] = dead_band_rad(p)
        ax.plot(r.t_s, r.angle_deg, color=colors[f], lw=1.8, label=f"{f}B: friction {FRICTION_NAMES[f]}")
    lh = math.degrees(p.limp_home_rad)
    eps = math.degrees(p.spring.params.limp_home_compliance_rad)   # width of the limp-home contact
    inside = {f: abs(finals[f] - lh) <= math.degrees(bands[f]) + eps + 1e-6 for f in "123"}
    b3, b2 = math.degrees(bands["3"]), math.degrees(bands["2"])
    ax.axhspan(max(lh - b3, 0.0), lh + b3, color="tab:blue", alpha=0.12,
               label=f"LuGre dead band |phi - phi_LH| <= (T_s - T_SP0)/R_F = {b3:.1f} deg")
    ax.axhline(lh + b2, color="tab:orange", lw=1.0, ls="--",
               label=f"Dahl band edge phi_LH + (T_c - T_SP0)/R_F = {lh + b2:.1f} deg")
    ax.axhline(lh, color="k", lw=0.8, ls=":", label=f"limp-home phi_LH = {lh:g} deg")
    panel(ax, "angle phi [deg]", xlabel="time [s]", ylim=(-2, 92), legend=dict(loc="upper right", fontsize=9))
    ax.set_title("Paper Fig. 13 analogue: release from 90 deg at zero voltage (duty 0), drive B\n"
                 "spring closes the plate, friction stops it in the limp-home dead band (models only)")
    path = out / "fig13_release.png"
    save_png(fig, path, s.dpi)
    line = (f"Fig. 13 ({path.name}): released at 90 deg with duty 0 (drive B): 1B settles at {finals['1']:.1f} deg "
            f"(limp-home {lh:g} deg), 2B (Dahl) at {finals['2']:.1f} deg, 3B (LuGre) at {finals['3']:.1f} deg; "
            f"dead bands where the spring cannot break static friction: phi_LH + {b2:.1f} deg (Dahl), "
            f"+ {b3:.1f} deg (LuGre): " + ("all inside" if all(inside.values()) else
                                           "OUTSIDE for " + ", ".join(f + "B" for f, ok in inside.items() if not ok))
            + ".")
    return path, line


# ------------------------------------------------------------------------------------------ Figs. 14, 15
def voltage_steps(models, volts, pre_s=0.05, dur_s=0.5):
    """Responses to u_SP steps from rest at limp-home: {(model, V): Trajectory}."""
    res = {}
    for m in models:
        p = make_plant(m)
        n_pre = int(round(pre_s / p.control_period_s))
        n = n_pre + int(round(dur_s / p.control_period_s))
        for v in volts:
            u = np.zeros(n)
            u[n_pre:] = v
            res[m, v] = p.simulate(voltage=u)
    return res


def step_figure(models, volts, s: Settings, title: str):
    res = voltage_steps(models, volts)
    fig, ax = subplots(2, 1, figsize=(8, 6.2), sharex=True, constrained_layout=True,
                           gridspec_kw={"height_ratios": [4, 1]})
    styles = {models[0]: "--", models[1]: "-"}
    for (m, v), r in res.items():
        ax[0].plot(r.t_s, r.angle_deg, color=VOLT_COLORS[v], ls=styles[m], lw=1.8 if styles[m] == "-" else 1.5,
                   label=f"{m}, u_SP = {v:g} V")
        if m == models[0]:
            ax[1].plot(r.t_s[1:], r.voltage_V[1:], color=VOLT_COLORS[v], label=f"{v:g} V")
    panel(ax[0], "angle phi [deg]", ylim=(0, 92), legend=dict(loc="upper left", ncol=2, fontsize=9))
    ax[0].set_title(title)
    panel(ax[1], "u_SP [V]", xlabel="time [s]", ylim=(-0.5, max(volts) + 1))
    return fig, res


def joined(values, fmt=".1f") -> str:
    """'a/b/c' of formatted numbers, for the one-line captions."""
    return "/".join(format(v, fmt) for v in values)


def rel_rms(a, ref, base):
    """RMS difference of a and ref, relative to the RMS excursion of ref from ``base``."""
    return float(np.sqrt(np.mean((a - ref) ** 2)) / np.sqrt(np.mean((ref - base) ** 2)))


def fig14(out: Path, s: Settings):
    volts = (4.0, 5.0, 6.0)
    fig, res = step_figure(("1A", "3B"), volts, s,
                           "Paper Fig. 14 analogue: steps u_SP = 4, 5, 6 V, models 1A (dashed) and 3B (solid)\n"
                           "no measurement data: the two models are compared with each other")
    path = out / "fig14_steps_1A_3B.png"
    save_png(fig, path, s.dpi)
    lh = math.degrees(make_plant("3B").limp_home_rad)
    fin = {k: float(r.angle_deg[-1]) for k, r in res.items()}
    rel = {v: rel_rms(res["1A", v].angle_deg, res["3B", v].angle_deg, lh) for v in volts}
    line = (f"Fig. 14 ({path.name}, models only, no measurements): steps to 4/5/6 V; final "
            f"angles 1A {joined(fin['1A', v] for v in volts)} deg vs 3B {joined(fin['3B', v] for v in volts)} deg; "
            f"the 1A-3B difference relative to the 3B excursion is "
            f"{joined((100 * rel[v] for v in volts), '.0f')} % at 4/5/6 V.")
    return path, line


def fig15(out: Path, s: Settings):
    volts = (4.0, 6.0)
    fig, res = step_figure(("2B", "3B"), volts, s,
                           "Paper Fig. 15 analogue: steps u_SP = 4, 6 V, models 2B (dashed) and 3B (solid)\n"
                           "no measurement data: Dahl vs LuGre friction with the same drive B")
    path = out / "fig15_steps_2B_3B.png"
    save_png(fig, path, s.dpi)
    fin = {k: float(r.angle_deg[-1]) for k, r in res.items()}
    diff = {v: float(np.max(np.abs(res["2B", v].angle_deg - res["3B", v].angle_deg))) for v in volts}
    line = (f"Fig. 15 ({path.name}, models only, no measurements): final angles 2B "
            f"{joined(fin['2B', v] for v in volts)} deg vs 3B {joined(fin['3B', v] for v in volts)} deg at 4/6 V "
            f"(max difference {joined(diff[v] for v in volts)} deg).")
    return path, line


FIGURES = {"8": fig08, "12": fig12, "13": fig13, "14": fig14, "15": fig15}


def main(argv=None, prog: str = "etb-gym reproduce") -> int:
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0],
                                 epilog="Figures: " + ", ".join(FIGURES) + ". Writes <out>/figNN_*.png and "
                                        "<out>/figures.md (one line per figure).")
    ap.add_argument("--out", type=Path, default=Path("out/paper"), help="output folder (default: out/paper)")
    ap.add_argument("--only", nargs="+", choices=list(FIGURES), metavar="FIG",
                    help=f"regenerate only these paper figures (choices: {', '.join(FIGURES)})")
    ap.add_argument("--dpi", type=int, default=100, help="image resolution in dots per inch (default 100)")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    if not 20 <= args.dpi <= 600:
        ap.error(f"--dpi {args.dpi}: expected a resolution between 20 and 600")
    s = Settings(dpi=args.dpi)
    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    names = args.only or list(FIGURES)
    try:
        from tqdm import tqdm
        it = tqdm(names, desc="paper figures", unit="fig", disable=args.no_progress, file=sys.stderr)
    except ImportError:  # tqdm is a core dependency; keep the script usable without it anyway
        it = names
    entries = previous_entries(out / "figures.md") if args.only else {}
    for name in it:
        path, line = FIGURES[name](out, s)
        entries[name] = (path.name, line)
        (it.write if hasattr(it, "write") else print)(line)
    md = ["# Paper figure analogues (etb-gym models)", "",
          f"Regenerated by `etb-gym reproduce --out {out}`. The paper's figures include measurements from a test rig; "
          "these show the models only.", ""]
    for name in FIGURES:
        if name in entries:
            png, line = entries[name]
            md += [f"- {line}", f"  ![{Path(png).stem}]({png})", ""]
    write_text(out / "figures.md", "\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
