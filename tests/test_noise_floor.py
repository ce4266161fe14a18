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
