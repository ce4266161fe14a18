"""closed_twin._continued: a closed loop's family table over angle beyond the visited knots (round 23)."""
import math

import numpy as np

from etb_gym.diagnose.closed_twin import _continued

GRID = np.radians(np.arange(0.0, 91.0, 10.0))       # knots 0..90 deg


def test_the_edges_slope_is_continued_where_the_formula_goes_further():
    prof = -0.001 * np.arange(GRID.size) ** 2        # the formula steepens
    total = np.zeros(GRID.size)
    total[:7] = [0, 0, 0, 0, -0.002, -0.004, -0.006]  # visited 0..60 deg, still falling at the edge
    total[7:] = -0.006                               # held (penalized.hold_rows)
    out = _continued(total, prof, GRID, np.arange(7), math.nan)
    np.testing.assert_allclose(out[7:], [-0.008, -0.010, -0.012])
    np.testing.assert_array_equal(out[:7], total[:7])  # the visited knots are untouched


def test_the_continuation_goes_no_further_than_the_formula_and_holds_where_they_part():
    total = np.zeros(GRID.size)
    total[:7] = [0, 0, 0, 0, -0.002, -0.004, -0.006]
    total[7:] = -0.006
    flat = np.full(GRID.size, -0.01)
    flat[8:] = -0.0105                               # the formula saturates beyond 70 deg
    out = _continued(total, flat, GRID, np.arange(7), math.nan)
    np.testing.assert_allclose(out[7:], [-0.006, -0.0065, -0.0065])
    rising = np.linspace(0.0, 0.01, GRID.size)       # the formula goes the other way: held
    np.testing.assert_allclose(_continued(total, rising, GRID, np.arange(7), math.nan)[7:], -0.006)


def test_the_continuation_does_not_cross_limp_home():
    prof = -0.001 * np.arange(GRID.size)[::-1] ** 2    # the formula steepens towards 0 deg
    total = np.zeros(GRID.size)
    total[3:] = [-0.006, -0.004, -0.002, 0, 0, 0, 0]   # visited 30..90 deg
    total[:3] = -0.006
    out = _continued(total, prof, GRID, np.arange(3, 10), math.radians(15.0))
    np.testing.assert_allclose(out[:3], [-0.008, -0.008, -0.008])   # 20 deg continued, held below 15 deg


def test_a_knot_the_data_approach_to_less_than_half_its_interval_is_not_reached():
    from etb_gym.diagnose.closed_twin import reached_knots
    visit = np.full(GRID.size, 0.5)
    visit[9] = 0.03                                   # 90 deg: hat-weighted time from the samples at 82-85 deg
    angles = np.radians(np.linspace(6.0, 84.0, 500))
    np.testing.assert_array_equal(reached_knots(GRID, visit, angles), np.arange(1, 9))   # nor 0 deg (data from 6)
    angles = np.radians(np.linspace(0.0, 86.0, 500))  # past the middle of 80..90: the 90 deg knot is reached
    np.testing.assert_array_equal(reached_knots(GRID, visit, angles), np.arange(10))
    visit[4] = 0.0                                    # an interior knot without visit time is still not identified
    assert 4 not in reached_knots(GRID, visit, angles)


def _case(monkeypatch, replay_cost, significant=None, family="mechanical", prof=None, table=None):
    """continue_tables on stand-ins: one table over GRID (one parameter per knot, init 0, scale 1), visited
    (hat-weighted time) up to 80 deg and at 90 deg, the recorded angles 0..83 deg; the formula steepens."""
    from types import SimpleNamespace as NS

    from etb_gym.diagnose import closed_twin as CT
    from etb_gym.diagnose import family_table, penalized, shapes
    from etb_gym.diagnose.fit import FitResult
    term = NS(id="f_map", family=family, grid=GRID, value_fields=("d",), cls=NS(grid_field="angle_rad"))
    ps = [("f_map", NS(init=0.0, scale=1.0)) for _ in GRID]
    spec = NS(params=ps, bounds=lambda: (np.full(GRID.size, -1.0), np.full(GRID.size, 1.0)),
              base=NS(limp_home_rad=math.nan))
    if table is None:
        table = np.zeros(GRID.size)
        table[9] = -0.05                              # the 90 deg knot at a wild extrapolation
    final = FitResult(spec, table, 0.0, 0, None, 0)
    ref = NS(kept=True, term=term, family_id="f", fit=final)
    visit = np.full(GRID.size, 0.5)
    visit[9] = 0.03
    prof = -0.001 * np.arange(GRID.size) ** 2 if prof is None else prof
    monkeypatch.setattr(penalized, "formula_profile", lambda comp, t: prof)
    monkeypatch.setattr(family_table, "_formula_component", lambda fr, cid: object())
    monkeypatch.setattr(shapes, "visit_time_s", lambda t, d: visit)
    monkeypatch.setattr(shapes, "data_angles_rad", lambda d: np.radians(np.linspace(0.0, 83.0, 200)))
    monkeypatch.setattr(CT, "replay_view", lambda d: d)
    monkeypatch.setattr(CT, "_replay_cost", lambda fr, rv: (replay_cost(fr.x), 100))
    data = NS(recs=[NS(residual="observer")])
    note = {}
    out = CT.continue_tables(final, NS(refinements=[ref]), data, note, significant)
    return final, out, note


def test_the_knot_beyond_the_datas_reach_is_continued_where_the_replay_allows(monkeypatch):
    final, out, note = _case(monkeypatch, lambda x: 100.0)
    np.testing.assert_allclose(out.x[9] - 0.081, -0.064 - 0.013)   # the total: 80 deg's + the 60-70 slope
    assert note["beyond_visited"]["kept"] and note["beyond_visited"]["tables"][0]["knots_by"] == "data edge"


def test_where_the_replay_refuses_the_datas_reach_the_visited_knots_rule_stands(monkeypatch):
    final, out, note = _case(monkeypatch, lambda x: 100.0 if x[9] < -0.04 else 1e4)
    assert out is final                              # nothing beyond the visited knots (90 deg has visit time)
    assert not note["beyond_visited"]["kept"] and note["beyond_visited"]["tables"][0]["knots_by"] == "data edge"


def test_the_datas_reach_is_refused_where_it_would_leave_a_significant_mismatch(monkeypatch):
    final, out, note = _case(monkeypatch, lambda x: 100.0, significant=lambda fr: fr.x[9] > -0.04)
    assert out is final and note["beyond_visited"]["verdict_guard"].startswith("the edit would leave")
    final, out, note = _case(monkeypatch, lambda x: 100.0, significant=lambda fr: False)
    assert out is not final and note["beyond_visited"]["verdict_guard"] == "passed"


def test_a_hold_is_the_smaller_extrapolation_of_a_friction_level():
    from etb_gym.diagnose.closed_twin import _toward_edge
    total = np.array([0.0, 0.0, 0.001, 0.002, -0.04])  # visited 0..30 deg (still rising); 40 deg the formula's
    seen = np.arange(4)
    held = total.copy()
    held[4] = total[3]                               # the slope rule: the formula falls, the data rise: held
    np.testing.assert_array_equal(_toward_edge(held, total, total, seen)[4], -0.04)     # old rule: the formula's
    np.testing.assert_array_equal(_toward_edge(held, total, total, seen, hold=True)[4], 0.002)
    went = held.copy()
    went[4] = 0.004                                  # a step the other way than the visited rule's: not taken
    np.testing.assert_array_equal(_toward_edge(went, total, total, seen, hold=True)[4], -0.04)


def test_a_friction_table_holds_its_edge_beyond_the_datas_reach(monkeypatch):
    # angle_dependent_friction@1 3B closed s41 (round 31): the data rise to the last reached knot, the formula's
    # curvature (fitted with the table) falls into the stop; the visited-knot rule would keep the formula's
    prof = -0.001 * np.arange(GRID.size) ** 2
    table = -prof.copy()                             # the total flat at 0 over the data ...
    table[7:9] += [0.001, 0.002]                     # ... rising at 70-80 deg
    table[9] = 0.0                                   # 90 deg: anchored, the formula alone (-0.081)
    final, out, note = _case(monkeypatch, lambda x: 100.0, family="friction", prof=prof, table=table)
    assert note["beyond_visited"]["kept"]
    np.testing.assert_allclose(out.x[9] + prof[9], 0.002)        # held at 80 deg's total
    final, out, note = _case(monkeypatch, lambda x: 100.0, family="mechanical", prof=prof, table=table)
    assert out is final                              # other families: the formula's continuation stays


def test_a_friction_level_holds_its_edge_where_no_visited_interval_gives_a_slope():
    # angle_dependent_friction@1 random closed s41 (round 31): the data from limp-home (3 deg) up, the knot below it
    # at the formula's curvature, the interval above the edge knot not visited (no slope)
    total = np.zeros(GRID.size)
    total[0] = -0.04                                 # the formula's value: not reached
    total[1] = 0.004                                 # the edge knot; 20 deg not visited, 30.. deg visited
    seen = np.array([1, 3, 4, 5, 6, 7, 8, 9])
    np.testing.assert_array_equal(_continued(total, total, GRID, seen, math.nan)[0], -0.04)   # left as it is
    np.testing.assert_array_equal(_continued(total, total, GRID, seen, math.nan, hold=True)[0], 0.004)
