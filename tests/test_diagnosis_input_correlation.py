"""result.input_correlation: a replayed angle residual that follows the recorded voltage starts the search
(docs/diagnosis.md, "Which residual counts"; docs/diagnosis-history.md round 32, k32match)."""
from types import SimpleNamespace

import numpy as np

from etb_gym.diagnose.result import INPUT_K, input_correlation, reading_colour

N = 6000


def _ar1(rng, a, n, sigma=1.0):
    e = rng.normal(0.0, sigma, n)
    x = np.empty(n)
    x[0] = e[0]
    for k in range(1, n):
        x[k] = a * x[k - 1] + e[k]
    return x * np.sqrt(1.0 - a * a)


def _rec(rng, noise, residual="replay", resolution=0.022):
    """A recording: a slowly varying drive voltage, readings resting at 3 deg for the first and last 1.5 s
    (rest runs) and the reading noise ``noise`` on them; a 12-bit grid of ``resolution``."""
    u = 6.0 * np.sin(np.linspace(0.0, 18.0, N)) + _ar1(rng, 0.995, N, 0.3)
    angle = 3.0 + noise
    rec = SimpleNamespace(voltage_V=u, angle_deg=angle)
    floor = float(np.sqrt(np.std(noise) ** 2 + resolution ** 2 / 12.0))
    return SimpleNamespace(rec=rec, rest=[(0, 1500), (N - 1500, N)], residual=residual, noise_deg=floor,
                           resolution_deg=resolution)


def test_noise_alone_does_not_follow_the_voltage_white_or_coloured():
    rng = np.random.default_rng(1)
    for a in (0.0, 0.5, 0.7):
        for _ in range(5):
            noise = 0.03 * _ar1(rng, a, N)
            rd = _rec(rng, noise)
            x = input_correlation(SimpleNamespace(recs=[rd]), [noise])[0]
            assert x < INPUT_K, (a, x)
            if a > 0:
                assert abs(reading_colour(rd) - a) < 0.1


def test_a_residual_driven_by_the_voltage_counts():
    rng = np.random.default_rng(2)
    noise = 0.03 * _ar1(rng, 0.0, N)
    rd = _rec(rng, noise)
    u = rd.rec.voltage_V
    du = np.convolve(u - u.mean(), np.ones(30) / 30, mode="full")[:N]    # the voltage's trace, 15 ms late
    r = noise + 0.4 * 0.03 * du / np.std(du)            # RMS 1.08x the noise: within the RMS rule's 1.5x
    assert np.sqrt(np.mean(r ** 2)) < 1.5 * 0.03
    assert input_correlation(SimpleNamespace(recs=[rd]), [r])[0] > INPUT_K


def test_observer_residuals_are_not_tested():
    rng = np.random.default_rng(3)
    noise = 0.03 * _ar1(rng, 0.0, N)
    rd = _rec(rng, noise, residual="observer")
    assert input_correlation(SimpleNamespace(recs=[rd]), [noise]) == [None]


def test_a_residual_whose_quantization_is_not_dithered_is_not_tested():
    """Reading noise below the resolution step: the quantization error follows the angle (not tested); the same
    residual on a grid the noise dithers is."""
    rng = np.random.default_rng(4)
    noise = 0.01 * _ar1(rng, 0.0, N)
    rd = _rec(rng, noise, resolution=0.022)
    assert input_correlation(SimpleNamespace(recs=[rd]), [noise]) == [None]
    rd = _rec(rng, noise, resolution=0.005)
    assert input_correlation(SimpleNamespace(recs=[rd]), [noise])[0] is not None
