"""Convergence of the fixed-rate stepper against solve_ivp: the accuracy table and plot of docs/model.md.

    python -m etb_gym.accuracy                                   # all nine models, both PWM modes (~30 min)
    python -m etb_gym.accuracy --models 3B 2C --modes averaged --substeps 5 10 20 40 80
    python -m etb_gym.accuracy --json-out docs/figures/convergence.json --plot docs/figures/convergence.png

Two cases per model and PWM mode, each compared with ``Plant.reference`` (solve_ivp, LSODA, rtol 1e-9):

    rich     2 s of ``etb_gym.excitation.rich_excitation()`` from rest at limp-home (steps, both stops, a
             release from full open, a chirp across limp-home)
    release  observation (a): the plate let go at 90 deg (``initial_state(pi/2, at_rest=False)``), duty 0 for
             1.5 s: a hard impact on the closed stop and the bounces after it

For each substep count the RMS and the maximum angle error [deg]; the observed order between neighbouring
counts is log2(e(n) / e(2n)). Prints a markdown table; ``--json-out`` writes all numbers, ``--plot`` the
log-log convergence plot (both atomically). References are the slow part (switching mode: one solve_ivp
call per PWM interval); they are computed once per model and mode.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from .excitation import rich_excitation
from .plant import MODELS, make_plant

CASES = ("rich", "release")
MODES = ("averaged", "switching")
SUBSTEPS = (5, 10, 20, 40, 80)
RELEASE_S = 1.5


def case_inputs(plant, case: str):
    """(duty sequence, initial state) of a case."""
    if case == "rich":
        return rich_excitation(dt=plant.control_period_s), plant.initial_state()
    if case == "release":
        n = int(round(RELEASE_S / plant.control_period_s))
        return np.zeros(n), plant.initial_state(math.pi / 2, at_rest=False)
    raise ValueError(f"case = {case!r}: expected one of {CASES}")


def errors(model: str, mode: str, case: str, substeps=SUBSTEPS, reference=None, effects=(),
           duration_s: float | None = None) -> dict:
    """RMS and max angle error [deg] of the stepper at each substep count against solve_ivp (``effects``:
    diagnosis effect components added to the model; ``duration_s``: only the first seconds of the case)."""
    base = make_plant(model, pwm_mode=mode, effects=effects)
    duty, x0 = case_inputs(base, case)
    if duration_s is not None:
        duty = duty[:max(1, int(round(duration_s / base.control_period_s)))]
    ref = base.reference(duty, x0=x0).angle_deg if reference is None else reference
    out = {"model": model, "mode": mode, "case": case, "substeps": list(substeps), "rms_deg": [], "max_deg": []}
    for n in substeps:
        e = base.replace(substeps=n).simulate(duty, x0=x0).angle_deg - ref
        out["rms_deg"].append(float(np.sqrt(np.mean(e ** 2))))
        out["max_deg"].append(float(np.abs(e).max()))
    out["order"] = observed_order(out["substeps"], out["rms_deg"])
    return out


def observed_order(substeps, err) -> list:
    """log(e_k / e_k+1) / log(n_k+1 / n_k) between neighbouring substep counts."""
    return [math.log(err[k] / err[k + 1]) / math.log(substeps[k + 1] / substeps[k])
            if err[k] > 0 and err[k + 1] > 0 else None for k in range(len(err) - 1)]


def monotone(err) -> bool:
    return all(b < a for a, b in zip(err, err[1:]))


def markdown(rows) -> str:
    ns = rows[0]["substeps"]
    head = "| model | PWM | case | " + " | ".join(f"{n} substeps: RMS / max [deg]" for n in ns) + \
        " | order (last pair) | monotone |"
    lines = [head, "|" + "---|" * (len(ns) + 5)]
    for r in rows:
        cells = " | ".join(f"{a:.2g} / {b:.2g}" for a, b in zip(r["rms_deg"], r["max_deg"]))
        o = r["order"][-1]
        lines.append(f"| {r['model']} | {r['mode']} | {r['case']} | {cells} | "
                     f"{'n/a' if o is None else f'{o:.2f}'} | {'yes' if monotone(r['rms_deg']) else 'NO'} |")
    return "\n".join(lines)


def plot(rows, path: Path) -> None:
    """Log-log RMS error vs substeps, one panel per (case, mode); an Agg canvas (no global backend switch)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    panels = sorted({(r["case"], r["mode"]) for r in rows})
    ncol = min(2, len(panels))
    nrow = (len(panels) + ncol - 1) // ncol
    fig = Figure(figsize=(5.5 * ncol, 4.2 * nrow))
    FigureCanvasAgg(fig)
    for k, (case, mode) in enumerate(panels):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        mine = [r for r in rows if (r["case"], r["mode"]) == (case, mode)]
        for r in mine:
            ax.loglog(r["substeps"], r["rms_deg"], "o-", lw=1, ms=3, label=r["model"])
        n = np.array(mine[0]["substeps"], float)
        ax.loglog(n, 2.0 * max(r["rms_deg"][0] for r in mine) * (n[0] / n) ** 2, "k--", lw=0.8, label="order 2")
        ax.axhline(0.005, color="grey", lw=0.6, ls=":")
        ax.set_xticks(n, [str(int(v)) for v in n])
        ax.minorticks_off()
        ax.set_title(f"{case}, {mode} PWM")
        ax.set_xlabel("substeps per 1 ms control period")
        ax.set_ylabel("RMS angle error vs solve_ivp [deg]")
        ax.grid(True, which="major", lw=0.3)
        ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    _atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=110), binary=True)


def _atomic_write(path: Path, write, binary=False) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb" if binary else "w") as fh:
            write(fh)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument("--models", nargs="+", default=list(MODELS), help="models (default: all nine)")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES, help="PWM modes (default: both)")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES, help="cases (default: both)")
    ap.add_argument("--substeps", type=int, nargs="+", default=list(SUBSTEPS), help="substep counts (default 5 .. 80)")
    ap.add_argument("--json-out", default=None, help="write all numbers to this JSON file")
    ap.add_argument("--plot", default=None, help="write the convergence plot (PNG) to this file")
    a = ap.parse_args(argv)
    bad = [m for m in a.models if m.upper() not in MODELS]
    if bad:
        ap.error(f"--models {bad}: expected models among {list(MODELS)}")
    if any(n < 1 for n in a.substeps) or sorted(set(a.substeps)) != a.substeps:
        ap.error(f"--substeps {a.substeps}: expected increasing integers >= 1")
    from .integrate import substeps_used

    low = substeps_used(1e-3, 1)
    if a.substeps[0] < low:
        ap.error(f"--substeps {a.substeps}: the stepper takes at least {low} substeps per 1 ms control period "
                 f"(h_max = integrate.H_MAX_S, docs/model.md sec. 9): expected counts >= {low}")
    from tqdm import tqdm

    jobs = [(m.upper(), mode, case) for mode in a.modes for case in a.cases for m in a.models]
    rows = []
    for m, mode, case in tqdm(jobs, desc="accuracy", file=sys.stderr):
        rows.append(errors(m, mode, case, a.substeps))
    print(markdown(rows))
    if a.json_out:
        _atomic_write(Path(a.json_out), lambda fh: fh.write(json.dumps(rows, indent=1) + "\n"))
    if a.plot:
        plot(rows, Path(a.plot))
    return 0


if __name__ == "__main__":
    sys.exit(main())
