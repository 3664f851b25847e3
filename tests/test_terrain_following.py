"""Flyable terrain following: closed forms, constraint and minimality properties, and a
brute-force relaxation reference."""

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from chirplidar.geometry.terrain_following import flyable_profile, profile_report

SPEED, CLIMB, DESCENT = 25.0, 5.0, 2.5  # slopes 0.2 up, 0.1 down
S_UP, S_DOWN = CLIMB / SPEED, DESCENT / SPEED


def _violations(d, g, z, clearance, s_up, s_down, rtol=1e-9):
    """(clearance, climb, descent) violation flags; the tolerance is 1e-9 relative to the
    height scale of the problem (round-off of the cone terms grows with |z| and s * span)."""
    scale = 1.0 + np.abs(z).max() + max(s_up, s_down) * (d[-1] - d[0])
    tol = rtol * scale
    dz, dd = np.diff(z), np.diff(d)
    return (np.any(z < g + clearance - tol), np.any(dz > s_up * dd + tol),
            np.any(-dz > s_down * dd + tol))


def _brute_force(d, g, clearance, s_up, s_down):
    """Reference: raise samples one at a time (pure Python) until no constraint is violated."""
    z = [float(v) + clearance for v in g]
    changed = True
    while changed:
        changed = False
        for i in range(len(z)):
            need = z[i]
            if i > 0:
                need = max(need, z[i - 1] - s_down * (d[i] - d[i - 1]))
            if i < len(z) - 1:
                need = max(need, z[i + 1] - s_up * (d[i + 1] - d[i]))
            if need > z[i]:
                z[i], changed = need, True
    return np.array(z)


def test_flat_ground_is_ground_plus_clearance():  # closed form
    d = np.linspace(0.0, 5000.0, 501)
    g = np.full_like(d, 1234.5)
    z = flyable_profile(d, g, 120.0, SPEED, CLIMB, DESCENT)
    np.testing.assert_array_equal(z, g + 120.0)


def test_step_up_ramp_starts_h_over_climb_slope_before():  # closed form
    d = np.arange(0.0, 2001.0, 1.0)
    H, x_step, c = 40.0, 1000.0, 100.0
    g = np.where(d >= x_step, H, 0.0)
    z = flyable_profile(d, g, c, SPEED, CLIMB, DESCENT)
    start = x_step - H / S_UP  # 200 m before the step
    assert start == 800.0
    np.testing.assert_allclose(z[d <= start], c, rtol=0, atol=1e-12)
    assert np.all(z[(d > start) & (d < x_step)] > c)
    ramp = (d >= start) & (d <= x_step)
    np.testing.assert_allclose(z[ramp], c + S_UP * (d[ramp] - start), rtol=0, atol=1e-9)
    np.testing.assert_allclose(z[d >= x_step], H + c, rtol=0, atol=1e-12)


def test_step_down_descends_at_descent_slope():  # closed form
    d = np.arange(0.0, 2001.0, 1.0)
    H, x_last_high, c = 40.0, 1000.0, 100.0
    g = np.where(d <= x_last_high, H, 0.0)
    z = flyable_profile(d, g, c, SPEED, CLIMB, DESCENT)
    end = x_last_high + H / S_DOWN  # back at clearance 400 m after the last high sample
    assert end == 1400.0
    np.testing.assert_allclose(z[d <= x_last_high], H + c, rtol=0, atol=1e-12)
    ramp = (d >= x_last_high) & (d <= end)
    np.testing.assert_allclose(z[ramp], H + c - S_DOWN * (d[ramp] - x_last_high),
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(z[d >= end], c, rtol=0, atol=1e-12)
    rates = np.diff(z[ramp]) / np.diff(d[ramp]) * SPEED
    np.testing.assert_allclose(rates, -DESCENT, rtol=1e-9)


@st.composite
def terrains(draw):
    n = draw(st.integers(2, 60))
    steps = draw(st.lists(st.floats(0.1, 200.0), min_size=n - 1, max_size=n - 1))
    ground = draw(st.lists(st.floats(-200.0, 3500.0), min_size=n, max_size=n))
    d0 = draw(st.floats(-1e4, 1e4))
    d = d0 + np.concatenate([[0.0], np.cumsum(steps)])
    speed = draw(st.floats(5.0, 300.0))
    climb = draw(st.floats(0.1, 40.0))
    descent = draw(st.floats(0.1, 40.0))
    clearance = draw(st.floats(1.0, 1000.0))
    return d, np.array(ground), clearance, speed, climb, descent


@settings(max_examples=300, deadline=None)
@given(terrains())
def test_never_violates_limits_or_clearance(case):  # property
    d, g, c, v, climb, descent = case
    assume(np.all(np.diff(d) > 0))  # float cumsum could in principle merge samples
    z = flyable_profile(d, g, c, v, climb, descent)
    assert np.all(z >= g + c)  # exactly, not just within tolerance
    assert not any(_violations(d, g, z, c, climb / v, descent / v))


def test_minimal_lowering_any_sample_violates():  # property, random terrain
    rng = np.random.default_rng(7)
    d = np.cumsum(rng.uniform(1.0, 50.0, 400))
    g = np.cumsum(rng.normal(0.0, 8.0, 400)) + 2000.0
    c = 80.0
    z = flyable_profile(d, g, c, SPEED, CLIMB, DESCENT)
    assert not any(_violations(d, g, z, c, S_UP, S_DOWN))
    bound = z > g + c + 1e-6
    idx = np.concatenate([rng.choice(np.flatnonzero(bound), 10, replace=False),
                          rng.choice(np.flatnonzero(~bound), 5, replace=False)])
    for i in idx:
        lowered = z.copy()
        lowered[i] -= 1e-6
        assert any(_violations(d, g, lowered, c, S_UP, S_DOWN, rtol=1e-12)), i


@pytest.mark.parametrize("seed", range(20))
def test_matches_brute_force_relaxation(seed):  # brute-force reference
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 30))
    d = np.cumsum(rng.uniform(0.5, 100.0, n))
    g = rng.uniform(0.0, 300.0, n)
    c, v = rng.uniform(10.0, 200.0), rng.uniform(10.0, 80.0)
    climb, descent = rng.uniform(0.5, 10.0), rng.uniform(0.5, 10.0)
    z = flyable_profile(d, g, c, v, climb, descent)
    ref = _brute_force(d.tolist(), g.tolist(), c, climb / v, descent / v)
    np.testing.assert_allclose(z, ref, rtol=0, atol=1e-9)


def test_single_sample_is_lower_bound():
    np.testing.assert_array_equal(flyable_profile([5.0], [10.0], 50.0, 20.0, 3.0, 3.0), [60.0])


def test_profile_report_closed_form():
    d = np.array([0.0, 100.0, 200.0, 300.0])
    g = np.array([0.0, 0.0, 10.0, 0.0])
    z = np.array([100.0, 120.0, 130.0, 110.0])
    r = profile_report(d, g, z, 25.0)
    assert r == {"min_clearance_m": 100.0, "max_clearance_m": 120.0,
                 "max_climb_mps": 5.0, "max_descent_mps": 5.0}
    flat = profile_report(d, g, np.full(4, 200.0), 25.0)
    assert flat["max_climb_mps"] == 0.0 and flat["max_descent_mps"] == 0.0


def test_profile_report_of_flyable_profile_within_limits():
    d = np.arange(0.0, 3000.0, 10.0)
    g = 300.0 * np.sin(d / 200.0)
    z = flyable_profile(d, g, 50.0, SPEED, CLIMB, DESCENT)
    r = profile_report(d, g, z, SPEED)
    assert r["min_clearance_m"] == pytest.approx(50.0)
    assert r["max_clearance_m"] > 50.0
    assert r["max_climb_mps"] <= CLIMB * (1 + 1e-9)
    assert r["max_descent_mps"] <= DESCENT * (1 + 1e-9)


GOOD = dict(distance_m=[0.0, 1.0, 2.0], ground_m=[0.0, 1.0, 0.0], clearance_m=10.0,
            speed_mps=20.0, max_climb_mps=2.0, max_descent_mps=2.0)


@pytest.mark.parametrize("arg,value", [
    ("distance_m", [0.0, 2.0, 1.0]),
    ("distance_m", [0.0, 1.0, 1.0]),
    ("distance_m", [[0.0, 1.0, 2.0]]),
    ("distance_m", [0.0, np.nan, 2.0]),
    ("distance_m", []),
    ("ground_m", [0.0, 1.0]),
    ("ground_m", [0.0, np.inf, 0.0]),
    ("clearance_m", 0.0),
    ("clearance_m", -5.0),
    ("speed_mps", 0.0),
    ("speed_mps", np.nan),
    ("max_climb_mps", 0.0),
    ("max_climb_mps", [1.0, 2.0]),
    ("max_descent_mps", -1.0),
])
def test_bad_inputs_raise_naming_argument(arg, value):
    with pytest.raises(ValueError, match=arg):
        flyable_profile(**{**GOOD, arg: value})


@pytest.mark.parametrize("arg,value", [("z_m", [1.0, 2.0]), ("z_m", [1.0, np.nan, 2.0]),
                                       ("speed_mps", -1.0), ("distance_m", [0.0, 0.0, 1.0])])
def test_profile_report_bad_inputs(arg, value):
    kw = dict(distance_m=[0.0, 1.0, 2.0], ground_m=[0.0, 0.0, 0.0], z_m=[5.0, 6.0, 5.0],
              speed_mps=10.0)
    with pytest.raises(ValueError, match=arg):
        profile_report(**{**kw, arg: value})
