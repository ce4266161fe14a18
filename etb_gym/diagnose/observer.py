"""A residual that does not drift on closed-loop recordings: the one-step prediction error of a fixed-gain
state observer (output injection from the measured angle).

Why. In closed loop the recorded voltage is the controller's reaction to the plate: where the model places a
stick-slip event or a stop bounce slightly differently from the rig, a replay of that voltage runs away (the
model's plate is not where the controller thought it was), and the replay residual of even the right model
stays many times the noise until the next re-initialization. An observer pulls the model's angle
towards the measured angle after every control period, so such a misplaced event costs a short transient,
not the rest of the segment.

    predict    x[k+1|k] = F(x[k|k], u[k])                       the plant's own control period (compiled)
    residual   r[k+1]   = h(x[k+1|k]) - y[k+1]                  the reading predicted one period ahead
    correct    phi[k+1|k+1] = phi[k+1|k] + L (y~[k+1] - phi_h[k+1|k])     the angle only

y~ is the reading mapped back through the sensor model (offset, gain), phi_h the predicted angle at the
sensor's delay (interpolated between the stored predictions). L = 1 - exp(-omega_o dt): an angle error decays
as exp(-omega_o t), whatever the sample period. The speed, the current, the friction bristles and slow effect
states (a winding temperature) are not corrected: they follow the corrected angle through the model's own
physics (spring, back-EMF damping, friction), which is stable.

Why the angle only. A speed correction (L_omega from pole placement of the angle/speed pair) feeds the
sensor noise into the speed every sample; on LuGre friction that is a dither: the bristles of a plate that
the rig holds were shaken loose, the model crept, and the one-step error of even the truth's parameters
stood at 0.1 deg (8x the noise) on a held plate (clean stiff-PID recording, seed 2: 1.25x the noise with a
mismatch window, against 1.03x and none with the angle alone at the same angle gain).

What the bandwidth trades. A concealed effect acts persistently (a torque d over a stretch of motion): the
observer then settles at a smaller innovation than the replay's offset, and the more so the higher omega_o;
a misplaced stick-slip transient (or a creep the calibrated friction places a little differently) decays in
about 1/omega_o, so a low omega_o leaves it as a mismatch window. OMEGA_O is the measured compromise
(docs/diagnosis.md, "Closed loop: observer residual", scripts/closed_loop_residual.py). The observer is a
residual only: the exported plant is not changed.
"""
from __future__ import annotations

import math

import numpy as np

OMEGA_O = 210.0        # observer bandwidth [rad/s]: angle gain 1 - exp(-OMEGA_O dt), 0.19 at 1 kHz (measured)
GAIN_OVERRIDE = None   # a function plant -> gain vector replacing :func:`gains` (measurements only)


def gains(dt_s: float, n_states: int, omega_o: float | None = None) -> np.ndarray:
    """The correction per radian of innovation for every state: 1 - exp(-omega_o dt) on the angle, 0 elsewhere."""
    omega_o = OMEGA_O if omega_o is None else omega_o
    if not (omega_o > 0 and dt_s > 0 and math.isfinite(omega_o) and math.isfinite(dt_s)):
        raise ValueError(f"observer bandwidth {omega_o!r} rad/s and sample period {dt_s!r} s: expected positive "
                         "finite numbers")
    L = np.zeros(n_states)
    L[0] = 1.0 - math.exp(-omega_o * dt_s)
    return L


def observe(plant, sensor, rd, omega_o: float | None = None, read=None):
    """One-step predicted reading [deg] and current [A] along recording ``rd`` (model.RecData) with output
    injection; (None, reason) where the simulation fails, else ((angle, current), None). ``read``: the sensor
    that reads the observer's angles out (default ``sensor``; sensor_map.py reads the plate's own angle through
    ``sensor`` without its delay, the injection still comparing the readings at ``sensor``'s lag)."""
    r = rd.rec
    n = r.n
    y_rad = np.radians(sensor.invert(np.asarray(r.angle_deg, float)))
    R = float(getattr(plant.drive.params, "resistance_ohm", 1.0))
    if r.current_A is not None:
        i0 = float(np.mean(r.current_A[0:3]))
    else:
        i0 = float(r.voltage_V[0]) / R
    phi0 = float(np.mean(y_rad[0:3]))
    phi0 = min(max(phi0, plant.angle_min_rad), plant.angle_max_rad)
    x0 = plant.initial_state(phi0, current_A=i0)
    X = np.empty((n, plant.n_states))
    A = np.empty((n, len(plant.components)))
    lag = max(0.0, sensor.lag_periods(float(plant.control_period_s)))
    L = gains(plant.control_period_s, plant.n_states, omega_o) if GAIN_OVERRIDE is None else GAIN_OVERRIDE(plant)
    done = plant.stepper().observe(x0, rd.duty[:n - 1], rd.supply_V[:n - 1], plant.P, float(r.t_s[0]),
                                    plant.control_period_s, plant.substeps, plant.supply.switching,
                                    plant.supply.pwm_frequency_hz, y_rad, L, lag, X, A)
    if done < n - 1:
        return None, (f"the simulated state became non-finite in {r.name} at t = {float(r.t_s[done]):.3f} s "
                      "(observer residual)")
    ang = (sensor if read is None else read).apply(r.t_s, np.degrees(X[:, 0]))
    return (ang, X[:, 2].copy()), None
