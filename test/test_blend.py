"""control.blend: the bumpless-restart offset against its defining properties, checked analytically and numerically."""

import math

import numpy as np
import pytest
from numpy.polynomial import Polynomial

from robotino_geom_mpc.control.blend import BlendError, ReferenceBlend

pytestmark = pytest.mark.unit

PERIOD = 0.01
CASES = [  # dp, dv, da, linear limit, angular limit
    ((0.8, -0.5, 0.3), (0.3, 0.1, -0.2), (-0.05, 0.04, 0.0), 0.3, 1.0),  # restart far from the reference
    ((0.002, 0.0, -0.01), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.3, 1.0),  # small position offset only
    ((0.0, 0.0, 0.0), (-0.31, 0.0, 0.5), (0.0, 0.0, 0.0), 0.3, 1.0),  # velocity only
    ((0.3, 0.2, 1.0), (0.0, 0.0, 0.0), (0.0, 0.0, -0.2), 1.0, 0.8),  # other limits
]


def _independent_offset(blend, t):
    """o(t) = q(t) (1 - s(tau)) written out from the definition, with s the septic smoothstep."""
    tau = np.clip((t - blend.t0_s) / blend.duration_s, 0.0, 1.0)
    s = 35 * tau**4 - 84 * tau**5 + 70 * tau**6 - 20 * tau**7
    u = (t - blend.t0_s)[:, None]
    q = np.array(blend.dp) + np.array(blend.dv) * u + np.array(blend.da) * u * u / 2
    return q * (1.0 - s)[:, None]


def _exact_peaks(blend):
    """max over the blend of |(x'', y'')| and |theta''|, from the roots of the derivative of o''^2 (a polynomial)."""
    T = blend.duration_s
    tau = Polynomial([0.0, 1.0])
    w = 1 - (35 * tau**4 - 84 * tau**5 + 70 * tau**6 - 20 * tau**7)
    acc = [(blend.dp[a] * w + blend.dv[a] * T * tau * w + blend.da[a] * T * T * tau * tau * w / 2).deriv(2) / T**2
           for a in range(3)]
    peaks = []
    for group in (acc[:2], acc[2:]):
        square = sum((p * p for p in group), Polynomial([0.0]))
        taus = [0.0, 1.0] + [r.real for r in square.deriv().roots() if abs(r.imag) < 1e-9 and 0 < r.real < 1]
        peaks.append(math.sqrt(max(square(np.array(taus)))))
    return peaks


@pytest.mark.parametrize("dp, dv, da, lin, ang", CASES)
def test_offset_starts_at_the_offset_and_meets_the_reference_with_three_derivatives(dp, dv, da, lin, ang):
    blend = ReferenceBlend.engage(2.0, dp, dv, da, lin, ang, PERIOD)
    t0, T = blend.t0_s, blend.duration_s
    for order, expected in enumerate((dp, dv, da)):
        assert blend.derivatives(t0, order)[0] == pytest.approx(expected, abs=1e-12)
    for order in range(4):  # zero with all derivatives at t0 + T and after
        assert np.abs(blend.derivatives([t0 + T, t0 + T + 0.5], order)).max() < 1e-9
        assert np.abs(blend.derivatives(t0 + T * (1 - 1e-7), order)).max() < 1e-4
    t = t0 + T * np.linspace(0.0, 1.2, 301)
    np.testing.assert_allclose(blend.offset(t), _independent_offset(blend, t), atol=1e-12)
    assert blend.remaining_s(t0) == pytest.approx(T) and blend.remaining_s(t0 + 2 * T) == 0.0


@pytest.mark.parametrize("dp, dv, da, lin, ang", CASES)
def test_acceleration_within_the_limits_and_the_duration_is_the_shortest(dp, dv, da, lin, ang):
    blend = ReferenceBlend.engage(0.0, dp, dv, da, lin, ang, PERIOD)
    assert not blend.limited and blend.limits == (lin, ang)
    peaks = _exact_peaks(blend)
    assert peaks[0] <= lin * (1 + 1e-12) and peaks[1] <= ang * (1 + 1e-12)
    if blend.duration_s > PERIOD:  # a little shorter breaks a limit
        shorter = ReferenceBlend(0.0, blend.duration_s * 0.99, blend.dp, blend.dv, blend.da, blend.limits, False)
        short_peaks = _exact_peaks(shorter)
        assert short_peaks[0] > lin or short_peaks[1] > ang


@pytest.mark.parametrize("dp, dv, da, lin, ang", CASES)
def test_offset_is_c3_by_finite_differences(dp, dv, da, lin, ang):
    """Each derivative is the difference quotient of the one below, across t0 + T too (no jump anywhere)."""
    blend = ReferenceBlend.engage(0.0, dp, dv, da, lin, ang, PERIOD)
    T, h = blend.duration_s, blend.duration_s * 1e-5
    t = np.concatenate((np.linspace(0.01 * T, 1.2 * T, 97), [T - h / 3]))
    for order in range(3):
        lower_plus, lower_minus = blend.derivatives(t + h, order), blend.derivatives(t - h, order)
        quotient = (lower_plus - lower_minus) / (2 * h)
        scale = np.abs(blend.derivatives(t, order + 1)).max() + 1e-9
        np.testing.assert_allclose(quotient, blend.derivatives(t, order + 1), atol=1e-4 * scale)
    third = blend.derivatives(np.array([T - 1e-9, T + 1e-9]), 3)
    assert np.abs(third).max() < 1e-6 * (np.abs(blend.derivatives(np.linspace(0, T, 101), 3)).max() + 1e-9)


def test_zero_offset_lasts_one_period_and_is_zero():
    blend = ReferenceBlend.engage(5.0, (0, 0, 0), (0, 0, 0), (0, 0, 0), 0.3, 1.0, PERIOD)
    assert blend.duration_s == PERIOD and not blend.limited
    assert not blend.offset(5.0 + np.arange(5) * 0.003).any()


def test_a_reference_acceleration_above_the_limit_raises_it_to_twice_its_need():
    """o''(t0) = da cannot shrink with T: a limit below what da needs is raised, and says so."""
    da = (-0.3, 0.0, 0.0)  # 0.3 m/s^2, the (tau^2 w)''/2 factor peaks at 1.6875
    blend = ReferenceBlend.engage(0.0, (0.1, 0, 0), (0, 0, 0), da, 0.3, 1.0, PERIOD)
    assert blend.limited and blend.limits[0] == pytest.approx(2 * 1.6875 * 0.3)
    assert _exact_peaks(blend)[0] <= blend.limits[0] * (1 + 1e-12)


@pytest.mark.parametrize("kwargs, match", [
    ({"dp": (0, math.nan, 0)}, "dp must be finite"),
    ({"dv": (0, 0)}, r"dv must have shape \(3,\)"),
    ({"linear_limit": 0.0}, "linear_limit must be positive"),
    ({"period_s": -0.01}, "period_s must be positive"),
    ({"t0_s": math.inf}, "t0_s must be finite"),
])
def test_bad_inputs_raise_naming_them(kwargs, match):
    args = {"t0_s": 0.0, "dp": (0, 0, 0), "dv": (0, 0, 0), "da": (0, 0, 0), "linear_limit": 0.3,
            "angular_limit": 1.0, "period_s": PERIOD, **kwargs}
    with pytest.raises(BlendError, match=match):
        ReferenceBlend.engage(**args)
