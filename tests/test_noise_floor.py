"""The noise floor read off a recording (measurement.noise_floor): rest runs, and the second-difference
fallback when the plate moves throughout (a slow sample rate)."""
import math

import numpy as np

from etb_gym.diagnose.measurement import noise_floor, quiet_sigma, second_difference_sigma


def _quantize(y, q):
    return q * np.round(y / q)


def test_a_plate_that_moves_throughout_at_a_slow_rate_does_not_inflate_the_floor():
    # 500 Hz, 1 s: a plate stepping between set-points every 100 ms with a fast (5 ms) first-order response,
    # so more than 5 % of the second differences carry motion and no rest run of 40 samples exists
    t = np.arange(500) * 2e-3
    sigma, q = 0.006, 100.0 / 4096
    true = math.sqrt(sigma ** 2 + q ** 2 / 12.0)
    for seed in range(4):
        rng = np.random.default_rng(seed)
        target = 5.0 + 50.0 * rng.uniform(size=10)[np.minimum((t / 0.1).astype(int), 9)]
        phi = np.empty_like(t)
        phi[0] = 5.0
        for k in range(1, t.size):
            phi[k] = phi[k - 1] + (target[k] - phi[k - 1]) * (1.0 - math.exp(-2e-3 / 0.005))
        y = _quantize(phi + sigma * rng.standard_normal(t.size), q)
        assert second_difference_sigma(y) > 4 * true          # the 95 % estimate is motion
        floor, _ = noise_floor(t, y, q)
        assert floor < 2.0 * true, (seed, floor, true)


def test_where_the_differences_are_noise_the_estimate_is_unchanged():
    rng = np.random.default_rng(4)
    for sigma in (0.005, 0.01, 0.03):
        y = _quantize(20.0 + sigma * rng.standard_normal(3000), 90.0 / 4096)
        assert quiet_sigma(y, 90.0 / 4096) == second_difference_sigma(y)
    y = 20.0 + 0.02 * rng.standard_normal(3000)           # no quantization
    assert quiet_sigma(y) == second_difference_sigma(y)


def _steps_and_rests(rng, n=6000, dt=1e-3):
    """A plate that rests 150-400 ms between quick moves, with a little creep while it rests."""
    phi = np.empty(n)
    k, level = 0, 10.0
    while k < n:
        rest = int(rng.uniform(0.15, 0.4) / dt)
        seg = np.arange(min(rest, n - k))
        phi[k:k + seg.size] = level + 0.002 * np.sqrt(seg)          # presliding creep
        k += seg.size
        move = min(10, n - k)
        new = rng.uniform(5.0, 80.0)
        phi[k:k + move] = np.linspace(level, new, move + 2)[1:-1]
        k += move
        level = new
    return np.arange(n) * dt, phi


def _ar1(rng, n, a, sigma):
    e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - a * a)
    x = np.empty(n)
    x[0] = rng.standard_normal() * sigma
    for k in range(1, n):
        x[k] = a * x[k - 1] + e[k]
    return x


def test_coloured_noise_is_not_read_as_a_smaller_floor():
    # AR(1) noise of a = 0.85 is smooth: its second differences understate it 3x, and rest runs found in a
    # band of that size only admit stretches where the noise stayed small; the floor must still be its size
    q = 90.0 / 4096
    for seed in range(3):
        rng = np.random.default_rng(seed)
        t, phi = _steps_and_rests(rng)
        for a, sigma in ((0.0, 0.03), (0.85, 0.03)):
            y = _quantize(phi + _ar1(rng, t.size, a, sigma), q)
            floor, _ = noise_floor(t, y, q)
            true = math.sqrt(sigma ** 2 + q ** 2 / 12.0)
            assert 0.85 * true < floor < 1.2 * true, (seed, a, floor, true)
