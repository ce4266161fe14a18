"""The learning curve of a run (``learning_curve.png``), drawn on a local Agg canvas: no pyplot, no backend
switch, so an interactive session's ``render_mode="human"`` keeps working."""
from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from .files import atomic_bytes


def curve_title(cfg) -> str:
    task = cfg.task_config
    res = f" (residual on {task.residual}, scale {task.residual_scale:g})" if task.residual else ""
    return f"{cfg.algo.upper()}{res} on {cfg.env_id}"


def plot_learning_curve(rows: list[dict], path: Path, title: str = "") -> None:
    """Evaluation score (geometric-mean RMS ratio to the better classical controller) and training return."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    x = np.array([r["timesteps"] for r in rows])
    fig = Figure(figsize=(7, 5.5), constrained_layout=True)
    FigureCanvasAgg(fig)
    a1, a2 = fig.subplots(2, 1, sharex=True)
    keys = sorted({k for r in rows for k in r if k.startswith("rms/")})
    a1.plot(x, [r["score"] for r in rows], "k-o", ms=3, lw=2, label="score (geometric mean)")
    a1.plot(x, [r["worst_ratio"] for r in rows], "-", color="tab:red", lw=1, label="worst scenario")
    a1.axhline(1.0, color="tab:green", ls="--", lw=1, label="better of PID / SMC")
    a1.axhline(1.2, color="tab:orange", ls=":", lw=1, label="target 1.2x")
    a1.set_yscale("log")
    a1.set_ylabel("RMS error / best classical")
    a1.legend(fontsize=7, loc="upper right")
    a1.set_title((title + "\n" if title else "") + f"{len(keys)} benchmark runs per evaluation", fontsize=10)
    a1.grid(alpha=0.3, which="both")
    a2.plot(x, [r["train_return"] for r in rows], "-", color="tab:blue")
    a2.set_ylabel("training episode return\n(mean of last 20)")
    a2.set_xlabel("timesteps (policy decisions)")
    a2.grid(alpha=0.3)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    atomic_bytes(Path(path), buf.getvalue())
