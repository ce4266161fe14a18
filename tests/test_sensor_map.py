"""The sensor-side maps of a twin (issue 15 item 3): the reading curve and the reading filter as components, the
plant file's [sensor] section, and the maps learned back from synthetic readings (no simulation: the fits are
linear given the model's angle)."""
import dataclasses
import math

import numpy as np
import pytest

from etb_gym import make_plant
from etb_gym.components.effects_maps import SensorMapParams
from etb_gym.components.sensor import ReadingFilterParams, fir_series, sensor_section
from etb_gym.diagnose import sensor_map as SM
from etb_gym.diagnose.measurement import SensorModel
from etb_gym.plantfile import load_plant, load_sensor, save_plant

DT = 1e-3


def _trajectory(n=6000, seed=0, hold=300, ramp=40):
    """A plate angle [deg] that visits 5-80 deg with holds and ramps, and its time base."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    levels = rng.uniform(5.0, 80.0, n // hold + 1)
    u = np.repeat(levels, hold)[:n]
    k = np.ones(ramp) / ramp
    u = np.convolve(np.concatenate([np.full(ramp - 1, u[0]), u]), k, mode="valid")    # ramps between the holds
    return t, u


def _sensor_with_maps():
    curve = SensorMapParams(angle_rad=(0.0, 0.5, 1.0, 1.5), error_rad=(0.0, 0.003, 0.004, -0.001))
    filt = ReadingFilterParams(weights=(0.4, 0.3, 0.2, 0.1))
    return SensorModel(offset_deg=0.3, gain=1.01, delay_s=0.0, curve=curve, filter=filt)


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_sensor_maps_round_trip_through_the_plant_file(tmp_path, suffix):
    plant = make_plant("3B")
    s = _sensor_with_maps()
    path = save_plant(plant, tmp_path / f"twin{suffix}", sensor=s.section())
    assert load_plant(path).to_dict() == plant.to_dict()        # the plant does not hold the sensor
    back = SensorModel.from_section(load_sensor(path))
    assert back.curve == s.curve and back.filter == s.filter
    assert back.gain == pytest.approx(s.gain, rel=1e-15) and back.offset_deg == pytest.approx(s.offset_deg, rel=1e-12)
    t, u = _trajectory(500)
    np.testing.assert_allclose(back.apply(t, u), s.apply(t, u), rtol=0, atol=1e-12)
    assert load_sensor(save_plant(plant, tmp_path / f"plain{suffix}")) is None


def test_sensor_equations_filter_curve_and_inverse():
    s = _sensor_with_maps()
    t, u = _trajectory(800)
    w = np.asarray(s.filter.weights)
    curved = u + np.degrees(np.interp(np.radians(u), s.curve.angle_rad, s.curve.error_rad))
    expect = np.array([sum(w[j] * curved[max(k - j, 0)] for j in range(w.size)) for k in range(u.size)])
    np.testing.assert_allclose(s.apply(t, u), s.gain * expect + s.offset_deg, atol=1e-9)
    held = np.array([10.0, 40.0, 70.0])                            # at rest the filter is the identity
    y = s.gain * (held + np.degrees(np.interp(np.radians(held), s.curve.angle_rad, s.curve.error_rad))) + s.offset_deg
    np.testing.assert_allclose(s.invert(y), held, atol=1e-6)
    assert s.lag_periods(DT) == pytest.approx(1.0)                 # 0.3 + 2 * 0.2 + 3 * 0.1
    np.testing.assert_allclose(fir_series(np.array([1.0, 2.0, 3.0]), np.array([0.5, 0.5])), [1.0, 1.5, 2.5])


def test_a_reading_curve_is_recovered_from_synthetic_readings():
    t, u = _trajectory()
    rng = np.random.default_rng(1)
    bow = 0.2 * np.sin(np.pi * u / 90.0)                           # the truth's bowed characteristic [deg]
    noise = 0.01
    y = 0.1 + 1.0 * (u + bow) + rng.normal(0.0, noise, u.size)
    got = SM.fit_curve([(y, u, 1.0 / noise, t)], SensorModel(offset_deg=0.1))
    params, lam, cv0, cv1 = got
    assert cv1 < 0.05 * cv0                                        # the map explains the bow, out of fold
    a = np.degrees(params.angle_rad)
    inside = (a > 10.0) & (a < 75.0)
    np.testing.assert_allclose(np.degrees(params.error_rad)[inside], 0.2 * np.sin(np.pi * a[inside] / 90.0),
                               atol=0.01)
    # a straight reading (no curve) gives no gain out of fold
    _, _, cv0, cv1 = SM.fit_curve([(0.1 + u + rng.normal(0.0, noise, u.size), u, 1.0 / noise, t)],
                                  SensorModel(offset_deg=0.1))
    assert not cv1 < (1.0 - SM.MIN_GAIN) * cv0


def test_a_moving_average_is_recovered_as_the_reading_filter():
    t, u = _trajectory(hold=40, ramp=8)                            # fast moves: the kernel's shape is seen
    rng = np.random.default_rng(2)
    noise = 0.01
    y = fir_series(u, np.full(6, 1.0 / 6)) + rng.normal(0.0, noise, u.size)
    s = SensorModel(delay_s=2.5 * DT)                              # the pure delay the catalogue fitted
    seen = np.interp(t - s.delay_s, t, u)
    params, lam, cv1 = SM.fit_filter([(y, u, 1.0 / noise, t)], s, DT)
    cv0 = SM._reference_error([(y, seen, 1.0 / noise, t)], s)
    assert cv1 < 0.05 * cv0
    w = np.asarray(params.weights)
    assert w.size == 30 and sum(w) == pytest.approx(1.0)
    np.testing.assert_allclose(w[:6], 1.0 / 6, atol=0.03)
    assert np.max(np.abs(w[7:])) < 0.03
    assert params.mean_lag_periods == pytest.approx(2.5, abs=0.1)


@pytest.mark.parametrize("section, match", [
    ({"gain": -1.0}, r"sensor\.gain = -1\.0 is invalid: expected a finite gain > 0"),
    ({"delay_s": float("nan")}, r"sensor\.delay_s = nan is invalid"),
    ({"offset_deg": 0.1}, r"sensor: unknown key\(s\) \['offset_deg'\]"),
    ({"filter": {"weights": [0.5, 0.4]}}, r"sensor\.filter: ReadingFilterParams\.weights = \[0\.5, 0\.4\] is invalid: "
                                         r"expected weights that sum to 1"),
    ({"filter": {"weights": []}}, r"ReadingFilterParams\.weights = \[\] is invalid: expected a list of 1 to 64"),
    ({"curve": {"angle_rad": [0.0, 0.0], "error_rad": [0.0, 0.0]}},
     r"sensor\.curve: SensorMapParams\.angle_rad = \[0\.0, 0\.0\] is invalid: expected strictly increasing knots"),
    ({"curve": {"angle_rad": [0.0, 1.0], "error": [0.0, 0.0]}}, r"sensor\.curve: unknown key\(s\) \['error'\]"),
])
def test_bad_sensor_sections_name_the_field(section, match):
    with pytest.raises(ValueError, match=match):
        sensor_section(section)


def test_a_plant_file_with_a_bad_sensor_section_is_refused_naming_the_file(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('model = "3B"\n[sensor]\ngain = 0.0\n')
    with pytest.raises(ValueError, match=r"plant file .*bad\.toml: sensor\.gain = 0\.0 is invalid"):
        load_plant(path)
    with pytest.raises(ValueError, match=r"sensor\.gain"):
        save_plant(make_plant("3B"), tmp_path / "x.toml", sensor={"gain": 0.0})
    assert not (tmp_path / "x.toml").exists()
    assert math.isclose(SensorModel.from_section({"offset_rad": math.radians(1.0)}).offset_deg, 1.0)


def test_a_spec_holds_its_sensor_map_over_the_candidates_sensor_fields():
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.model import Spec
    filt = ReadingFilterParams(weights=(0.5, 0.5))
    spec = Spec(make_plant("3B"), sensor_map=SM.held("filter", filt)).with_candidate(CANDIDATES["sensor_delay"])
    x = spec.x0()
    _, sensor = spec.build(x)
    assert sensor.filter == filt and sensor.delay_s == 0.0          # the filter replaces the fitted delay
    _, plain = Spec(make_plant("3B")).with_candidate(CANDIDATES["sensor_delay"]).build(x)
    assert plain.filter is None and plain.delay_s == pytest.approx(0.001)


def _fake_fit(ids):
    from types import SimpleNamespace
    return SimpleNamespace(spec=SimpleNamespace(candidates=[SimpleNamespace(id=c) for c in ids]), x=np.zeros(1))


@pytest.mark.parametrize("h_first, h_all, dropped", [(1.02, 1.0, True), (1.3, 1.0, False)])
def test_a_sensing_familys_map_replaces_the_later_effects_only_when_it_predicts_as_well(monkeypatch, h_first,
                                                                                        h_all, dropped):
    """sensor_map.replaces_later: the first step's sensor map against every step, by held-out error (no
    simulation here: the map, the fits and the held-out errors stand in)."""
    from types import SimpleNamespace
    from etb_gym.diagnose import family_table  # noqa: F401  (imported before the patch: it binds heldout_error)
    from etb_gym.diagnose import penalized as P
    first, final = _fake_fit(["sensor_offset_gain"]), _fake_fit(["sensor_offset_gain", "shaft_flux_loss"])
    sref = SM.SensorRefinement("sensor_offset_gain", "curve", None, 1.0, 10.0, 1.0, kept=True, fit=first)
    monkeypatch.setattr(SM, "refine_sensor", lambda cur, fid, data, log: sref)
    monkeypatch.setattr(P.Problem, "make", classmethod(lambda cls, spec, x, ids: spec))
    monkeypatch.setattr(P, "heldout_error", lambda spec, data: h_first if spec is first.spec else h_all)
    steps = [SimpleNamespace(id="sensor_offset_gain", fit=first), SimpleNamespace(id="shaft_flux_loss", fit=final)]
    got = SM.replaces_later(steps, final, None, log=lambda *a: None)
    assert (got is sref) == dropped
    # a first step that is not a sensing family, or a single step: nothing to replace
    assert SM.replaces_later(steps[::-1], final, None, log=lambda *a: None) is None
    assert SM.replaces_later(steps[:1], first, None, log=lambda *a: None) is None


def test_the_reading_curve_and_the_parameters_alternate_while_the_replay_falls(monkeypatch):
    """sensor_map.refine_sensor's passes (no simulation: learn, fit and the replay stand in): a pass is taken while
    the replay's sum of squares falls by PASS_GAIN; the last learned curve is kept."""
    import dataclasses
    from types import SimpleNamespace
    from etb_gym.diagnose import fit as F

    @dataclasses.dataclass
    class Spec_:
        sensor_map: dict | None = None

    @dataclasses.dataclass
    class Fit_:
        spec: Spec_
        x: np.ndarray
        rss: float = 0.0

    learned = iter(range(1, 20))
    monkeypatch.setattr(SM, "learn", lambda spec, x, data, kind: (next(learned), 1.0, 10.0, 5.0))
    rss = {1: 80.0, 2: 70.0, 3: 65.0, 4: 64.5, 5: 10.0}          # by the curve learned last (the 5th is not reached)
    monkeypatch.setattr(SM, "replay_rss", lambda spec, x, data, kind="curve": rss[spec.sensor_map["curve"]] if spec.sensor_map
                        else 100.0)
    monkeypatch.setattr(F, "fit", lambda spec, data, x, max_nfev: Fit_(spec, x))
    monkeypatch.setattr(F, "evaluate", lambda spec, data, x: np.zeros(3))
    data = SimpleNamespace(recs=[SimpleNamespace(residual="replay")])
    ref = SM.refine_sensor(Fit_(Spec_(), np.zeros(2)), "sensor_offset_gain", data, log=lambda *a: None)
    assert ref.kept and ref.params == 4                 # passes learned curves 2, 3, 4; 65 -> 64.5 is under 2 %
    assert ref.fit.spec.sensor_map == {"curve": 4}


def test_the_offset_and_gain_candidate_bends_with_its_bow_and_keeps_a_learned_curve_on_top():
    """sensor_offset_gain's bow (round 26): a parabola over the travel, zero at the stops, the bow at mid-travel; in
    a closed loop offset and gain trade against the calibrated spring, the bow cannot. A learned curve held in
    Spec.sensor_map is added to it (the curve is learned on top of the bow), not replaced by it."""
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.model import Spec
    plant = make_plant("3B")
    spec = Spec(plant, (CANDIDATES["sensor_offset_gain"],))
    vals = {"sensor_offset_gain.offset_deg": 0.2, "sensor_offset_gain.gain": 1.01, "sensor_offset_gain.bow_deg": 0.12}
    _, s = spec.build(spec.x_from_values(vals))
    lo, hi = math.degrees(plant.angle_min_rad), math.degrees(plant.angle_max_rad)
    phi = np.array([lo, 0.25 * lo + 0.75 * hi, 0.5 * (lo + hi), hi])
    bow = 4.0 * 0.12 * (phi - lo) / (hi - lo) * (1.0 - (phi - lo) / (hi - lo))
    np.testing.assert_allclose(s.apply(np.arange(4) * DT, phi), 1.01 * (phi + bow) + 0.2, atol=1e-3)
    np.testing.assert_allclose(s.invert(1.01 * (phi + bow) + 0.2), phi, atol=1e-3)
    learned = SensorMapParams(angle_rad=(0.2, 0.8), error_rad=(0.001, 0.002))
    held = dataclasses.replace(spec, sensor_map={"curve": learned})
    _, s2 = held.build(held.x_from_values(vals))
    extra = np.degrees(np.interp(np.radians(phi), learned.angle_rad, learned.error_rad))
    np.testing.assert_allclose(s2.apply(np.arange(4) * DT, phi), 1.01 * (phi + bow + extra) + 0.2, atol=1e-3)
    _, s0 = held.build(held.x_from_values({**vals, "sensor_offset_gain.bow_deg": 0.0}))
    assert s0.curve == learned                                    # no bow: the learned curve as it was


def test_a_closed_loops_reading_filter_is_learned_on_the_observers_angle():
    """sensor_map._view (round 31): in a closed loop the filter is learned on the observer's angle (the replay
    whose segments restart at the readings drifts there: the controller's voltage reacted to the rig's plate),
    its weights held non-negative. The truth reads through a 10-sample moving average; the model is the truth's
    plant with the pure delay that fits the average best (4.5 samples)."""
    from etb_gym.diagnose import truth_shapes as ts
    from etb_gym.diagnose.candidates import CANDIDATES
    from etb_gym.diagnose.model import Spec, prepare
    from etb_gym.diagnose.synthetic import make_recording
    truth = make_plant("3B", substeps=20)
    rec = make_recording(truth, np.random.default_rng(3), duration_s=3.0, closed=True, noise_deg=0.01,
                         reading=ts.SensorFilter(average_samples=10, profile=1.0))
    data = prepare([rec], 12.0, residual="observer")
    spec = Spec(make_plant("3B", substeps=5)).with_candidate(CANDIDATES["sensor_delay"])
    x = spec.x_from_values({"sensor_delay.delay_s": 4.5e-3})
    assert spec.build(x)[1].delay_s == pytest.approx(4.5e-3)
    assert SM._view(data, "filter").recs[0].residual == "observer"      # the filter's view keeps the observer
    assert SM._view(data, "curve").recs[0].residual == "replay"         # the curve's does not
    params, lam, cv0, cv1 = SM.learn(spec, x, data, "filter")
    assert cv1 < 0.6 * cv0                                              # a lag shaped like the average is learned
    w = np.asarray(params.weights)
    assert np.min(w) >= 0.0 and sum(w) == pytest.approx(1.0)
    assert params.mean_lag_periods == pytest.approx(4.5, abs=0.6)
    assert np.sum(w[:10]) > 0.8                                         # its weight within the 10 samples


def test_a_non_negative_reading_filter_is_a_moving_average_without_a_tail():
    """fit_filter(nonneg=True): the bounded fit recovers the average and puts no negative weight anywhere
    (the unconstrained fit scatters small weights of either sign over the kernel's tail)."""
    t, u = _trajectory(hold=40, ramp=8)
    rng = np.random.default_rng(2)
    noise = 0.01
    y = fir_series(u, np.full(6, 1.0 / 6)) + rng.normal(0.0, noise, u.size)
    free, _, _ = SM.fit_filter([(y, u, 1.0 / noise, t)], SensorModel(), DT)
    assert np.min(free.weights) < 0.0
    params, lam, cv1 = SM.fit_filter([(y, u, 1.0 / noise, t)], SensorModel(), DT, nonneg=True)
    w = np.asarray(params.weights)
    assert np.min(w) >= 0.0 and sum(w) == pytest.approx(1.0)
    np.testing.assert_allclose(w[:6], 1.0 / 6, atol=0.03)
    assert params.mean_lag_periods == pytest.approx(2.5, abs=0.1)
