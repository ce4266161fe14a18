"""Frames of the ETB env: the throttle plate in its bore beside the angle-vs-reference trace.

One matplotlib figure (Agg canvas, never pyplot) is built once per env; each frame restores the cached
static background and redraws only the moving artists (blitting), then copies the canvas buffer, so a
frame costs a few milliseconds. ``human`` mode shows the frames in a pyplot window when the backend is
interactive and silently does nothing more than produce the frame when it is not (headless tests).
"""
from __future__ import annotations

import math

import numpy as np

WIDTH_PX, HEIGHT_PX, DPI = 720, 320, 80


def _interactive_backend() -> bool:
    """True when pyplot can open a window (not Agg/pdf/svg/inline: headless runs just produce frames)."""
    import matplotlib

    try:
        from matplotlib.backends import BackendFilter, backend_registry

        interactive = backend_registry.list_builtin(BackendFilter.INTERACTIVE)
    except ImportError:  # matplotlib < 3.9
        from matplotlib import rcsetup

        interactive = rcsetup.interactive_bk
    return matplotlib.get_backend().lower() in {b.lower() for b in interactive}


class ETBRenderer:
    def __init__(self, episode_s: float, lo_deg: float, hi_deg: float, limp_home_deg: float, human: bool = False,
                 fps: float = 30):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
        from matplotlib.patches import Circle, Rectangle

        self.human, self.fps = human, fps
        self.fig = Figure(figsize=(WIDTH_PX / DPI, HEIGHT_PX / DPI), dpi=DPI)
        self.canvas = FigureCanvasAgg(self.fig)
        # --- left: the bore seen along the shaft: air flows left to right between the walls, the plate
        #     turns about the shaft from closed (0 deg, across the flow) to open (90 deg, along the flow)
        ax = self.fig.add_axes((0.01, 0.04, 0.31, 0.88))
        ax.set_xlim(-1.3, 1.3)
        ax.set_ylim(-1.3, 1.3)
        ax.set_aspect("equal")
        ax.axis("off")
        for y0 in (1.0, -1.3):
            ax.add_patch(Rectangle((-1.3, y0), 2.6, 0.3, color="#8c96a0", zorder=1))
        ax.add_patch(Rectangle((-1.3, -1.0), 2.6, 2.0, color="#eef3f8", zorder=0))
        for y in (-0.55, 0.0, 0.55):
            ax.annotate("", xy=(-0.95, y), xytext=(-1.25, y), zorder=2,
                        arrowprops=dict(arrowstyle="->", color="#b8c4d0", lw=1.2))
        lim = [(lo_deg, "#7a8590", ":"), (hi_deg, "#7a8590", ":"), (limp_home_deg, "#7a8590", "--")]
        for a, col, style in lim:
            if math.isfinite(a):
                ax.plot(*self._plate_xy(a, 1.0), style, color=col, lw=1, zorder=2)
        ax.add_patch(Circle((0, 0), 0.07, color="#222", zorder=6))
        if math.isfinite(lo_deg) and math.isfinite(hi_deg):
            # labels in the upper right quadrant, which the plate never crosses between 0 and 90 deg
            ax.text(0.1, 0.93, f"closed {lo_deg:g}\u00b0\nlimp-home {limp_home_deg:g}\u00b0", fontsize=7,
                    color="#55606a", ha="left", va="top", zorder=3)
            ax.text(0.93, 0.05, f"open {hi_deg:g}\u00b0", fontsize=7, color="#55606a", ha="right", va="bottom",
                    zorder=3)
        ax.set_title("throttle plate (side view)", fontsize=10)
        (self.ref_plate,) = ax.plot([], [], color="#e07b00", lw=2, ls="--", zorder=4, animated=True)
        (self.plate,) = ax.plot([], [], color="#1f4e99", lw=7, solid_capstyle="round", zorder=5, animated=True)
        self.text = ax.text(0, -1.27, "", ha="center", va="bottom", fontsize=9, family="monospace",
                            color="white", animated=True, zorder=7)
        self.ax_plate = ax
        # --- right: angle and reference over the episode, duty below
        tx = self.fig.add_axes((0.40, 0.38, 0.58, 0.54))
        tx.set_xlim(0, episode_s)
        tx.set_ylim((lo_deg if math.isfinite(lo_deg) else 0.0) - 5, (hi_deg if math.isfinite(hi_deg) else 90.0) + 5)
        tx.set_ylabel("angle [deg]")
        tx.axhline(limp_home_deg, color="#7a8590", lw=0.8, ls="--")
        tx.grid(alpha=0.3)
        tx.tick_params(labelbottom=False)
        (self.l_ref,) = tx.plot([], [], color="#e07b00", lw=1.5, ls="--", label="reference", animated=True)
        (self.l_ang,) = tx.plot([], [], color="#1f4e99", lw=1.5, label="angle", animated=True)
        tx.legend(loc="upper right", fontsize=8, ncols=2)
        self.title = tx.set_title("", fontsize=10)
        dx = self.fig.add_axes((0.40, 0.12, 0.58, 0.22), sharex=tx)
        dx.set_ylim(-1.1, 1.1)
        dx.set_ylabel("duty")
        dx.set_xlabel("time [s]")
        dx.axhline(0, color="#7a8590", lw=0.8)
        dx.grid(alpha=0.3)
        (self.l_duty,) = dx.plot([], [], color="#2a7d2a", lw=1.0, animated=True)
        self.axes = (ax, tx, dx)
        self._bg = None
        self._win = None
        self._model = None

    @staticmethod
    def _plate_xy(deg, r=0.97):
        """End points of the plate: 0 deg vertical (across the flow), 90 deg horizontal (along it)."""
        c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
        return [-r * s, r * s], [r * c, -r * c]

    def draw(self, t, angle, ref, duty, model: str) -> np.ndarray:
        if self._bg is None or model != self._model:
            self._model = model
            self.axes[1].set_title(f"{model}: angle and reference")
            self.canvas.draw()
            self._bg = self.canvas.copy_from_bbox(self.fig.bbox)
        self.canvas.restore_region(self._bg)
        a, r = float(angle[-1]), float(ref[-1])
        self.plate.set_data(*self._plate_xy(a))
        self.ref_plate.set_data(*self._plate_xy(r))
        self.text.set_text(f"t={t[-1]:5.3f} s  {a:5.1f} deg (ref {r:5.1f})")
        step = max(1, len(t) // 1500)        # at most ~1500 points per line
        self.l_ref.set_data(t[::step], ref[::step])
        self.l_ang.set_data(t[::step], angle[::step])
        self.l_duty.set_data(t[::step], duty[::step])
        for art, ax in ((self.ref_plate, 0), (self.plate, 0), (self.text, 0), (self.l_ref, 1), (self.l_ang, 1),
                        (self.l_duty, 2)):
            self.axes[ax].draw_artist(art)
        self.canvas.blit(self.fig.bbox)
        frame = np.asarray(self.canvas.buffer_rgba())[:, :, :3].copy()
        if self.human:
            self._show(frame)
        return frame

    def _show(self, frame):
        import matplotlib.pyplot as plt

        if _interactive_backend():
            if self._win is None or not plt.fignum_exists(self._win[0].number):
                fig = plt.figure("etb-gym", figsize=(WIDTH_PX / DPI, HEIGHT_PX / DPI), dpi=DPI)
                ax = fig.add_axes((0, 0, 1, 1))
                ax.axis("off")
                self._win = (fig, ax.imshow(frame))
                plt.show(block=False)
            self._win[1].set_data(frame)
            self._win[0].canvas.draw_idle()
            plt.pause(1.0 / self.fps)

    def close(self):
        if self._win is not None:
            import matplotlib.pyplot as plt

            plt.close(self._win[0])
            self._win = None
