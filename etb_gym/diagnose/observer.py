"""A residual that does not drift on closed-loop recordings: the one-step prediction error of a fixed-gain
state observer (output injection from the measured angle).

Why. In closed loop the recorded voltage is the controller's reaction to the plate: where the model places a
stick-slip event or a stop bounce slightly differently from the rig, a replay of that voltage runs away (the
model's plate is not where the controller thought it was), and the replay residual of even the right model
stays many times the noise until the next re-initialization. An observer pulls the model's angle and speed
towards the measured angle after every control period, so such a misplaced event costs a short transient,
not the rest of the segment.

    predict    x[k+1|k] = F(x[k|k], u[k])                       the plant's own control period (compiled)
    residual   r[k+1]   = h(x[k+1|k]) - y[k+1]                  the reading predicted one period ahead
    correct    x[k+1|k+1] = x[k+1|k] + L (y[k+1] - h(x[k+1|k]))   L on angle and speed only

h is the sensor model (offset, gain, delay interpolated between the stored predictions). The gains place the
error dynamics of the angle/speed pair of a double integrator at s = omega_o (-zeta +- j sqrt(1 - zeta^2)),
mapped to z = exp(s dt): with p1, p2 those poles,

    L_phi = 1 - p1 p2,      L_omega = (1 - p1)(1 - p2) / dt

(the characteristic polynomial of (I - L C) A for A = [[1, dt], [0, 1]], C = [1, 0]). The plant's own
spring, back-EMF damping and friction come on top, so the true error dynamics are faster and better
damped; the current, the friction bristles and slow effect states (a winding temperature) are not
corrected: they follow the corrected angle and speed through the model.

What the bandwidth trades. A concealed effect acts persistently (a torque d over a stretch of motion): the
observer then settles at an innovation of about d / (J omega_o^2 + k_spring) instead of the replay's
d / k_spring, so a low omega_o keeps effects visible; a misplaced stick-slip transient decays in about
1/(zeta omega_o), so a high omega_o hides it. OMEGA_O is the measured compromise (docs/diagnosis.md,
"Closed loop: observer residual"). The observer is a residual only: the exported plant is not changed.
"""
from __future__ import annotations

import math

import numpy as np

OMEGA_O = 150.0        # observer bandwidth [rad/s] (docs/diagnosis.md: measured compromise)
ZETA_O = 0.7           # observer damping ratio
GAIN_OVERRIDE = None


def gains(dt_s: float, n_states: int, omega_o: float | None = None, zeta: float | None = None) -> np.ndarray:
    """The correction per radian of innovation for every state (angle and speed; others 0)."""
    omega_o = OMEGA_O if omega_o is None else omega_o
    zeta = ZETA_O if zeta is None else zeta
    if not (omega_o > 0 and 0 < zeta <= 1 and dt_s > 0):
        raise ValueError(f"observer bandwidth {omega_o!r} rad/s, damping {zeta!r} and period {dt_s!r} s: "
                         "expected a positive bandwidth and period and a damping in (0, 1]")
    s = omega_o * complex(-zeta, math.sqrt(max(1.0 - zeta * zeta, 0.0)))
    p1 = np.exp(s * dt_s)
    p2 = np.conj(p1)
    L = np.zeros(n_states)
    L[0] = float((1.0 - p1 * p2).real)
    L[1] = float(((1.0 - p1) * (1.0 - p2)).real / dt_s)
    return L


def observe(plant, sensor, rd, omega_o: float | None = None, zeta: float | None = None):
    """One-step predicted reading [deg] and current [A] along recording ``rd`` (model.RecData) with output
    injection; (None, reason) where the simulation fails, else ((angle, current), None)."""
    r = rd.rec
    n = r.n
    y_rad = np.radians((np.asarray(r.angle_deg, float) - sensor.offset_deg) / sensor.gain)
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
    lag = max(0.0, float(sensor.delay_s) / float(plant.control_period_s))
    L = gains(plant.control_period_s, plant.n_states, omega_o, zeta) if GAIN_OVERRIDE is None else GAIN_OVERRIDE(plant)
    done = plant.engine.fns.observe(x0, rd.duty[:n - 1], rd.supply_V[:n - 1], plant.P, float(r.t_s[0]),
                                    plant.control_period_s, plant.substeps, plant.supply.switching,
                                    plant.supply.pwm_frequency_hz, y_rad, L, lag, X, A)
    if done < n - 1:
        return None, (f"the simulated state became non-finite in {r.name} at t = {float(r.t_s[done]):.3f} s "
                      "(observer residual)")
    ang = sensor.apply(r.t_s, np.degrees(X[:, 0]))
    return (ang, X[:, 2].copy()), None
