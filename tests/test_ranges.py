"""Playing ranges: parsing lo:hi, the parameter box, where a note speaks (against the FDM), per-state bows in the
batch FDM that range training uses."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bowsynth import Scene, UsageError, render_fdm
from bowsynth.engines.fdm import fdm_batch
from bowsynth.training.ranges import ParamBox, parse_range, speaks


@pytest.mark.parametrize("text,want", [("50:200", (50.0, 200.0)), ("100", (100.0, 100.0)), ("0.1:0.1", (0.1, 0.1))])
def test_parse_range(text, want):
    assert parse_range(text, "fb") == want


@pytest.mark.parametrize("text,needle", [("200:50", "inverted"), ("a:b", "range lo:hi"), ("1:2:3", "range lo:hi"),
                                         ("nan:1", "finite"), ("", "range lo:hi")])
def test_parse_range_refuses(text, needle):
    with pytest.raises(UsageError, match=needle):
        parse_range(text, "fb")


@settings(max_examples=30, deadline=None)
@given(st.floats(1e-3, 10), st.floats(1.5, 50), st.floats(0.01, 0.3), st.floats(0, 0.3), st.integers(1, 64))
def test_box_samples_stay_inside_and_fill_it(b0, ratio, v0, dv, n):
    box = ParamBox(b0, b0 * ratio, v0, v0 + dv, 100.0)
    pts = box.sample(n, np.random.default_rng(0))
    assert pts.shape == (n, 2) and box.contains(pts[:, 0], pts[:, 1]).all()
    z = box.normalise(pts[:, 0], pts[:, 1])
    assert np.all(np.abs(z) <= 1 + 1e-9)
    if n >= 16:  # a Latin hypercube puts one point in each of n strips per axis
        assert len(np.unique(np.floor((z[:, 0] + 1) / 2 * n).clip(0, n - 1))) == n


def test_a_point_is_a_box_of_zero_width():
    box = ParamBox(0.159, 0.159, 0.2, 0.2, 100.0)
    assert box.is_point and box.contains(0.159, 0.2) and not box.contains(0.16, 0.2)
    np.testing.assert_array_equal(box.normalise(0.159, 0.2), [0.0, 0.0])


@pytest.mark.parametrize("beta,vb", [(0.016, 0.2), (0.4, 0.3), (1.0, 0.1), (0.1, 0.1),   # speak within 1 s
                                     (0.2, 0.3), (0.75, 0.35), (0.05, 0.06)])              # do not
def test_speaks_agrees_with_the_fdm(beta, vb):
    r = render_fdm(Scene(fb=beta * 2 * np.pi * 100, vb=vb, duration=1.0), oversample=2)
    sounding = np.std(r.p[-4410:]) > 0.05
    assert bool(speaks(beta, vb, 100.0, f0=100.0)) == sounding


def test_batch_fdm_takes_one_bow_per_state():
    q0, p0 = np.array([0.0, 0.1, 0.0]), np.array([0.0, 0.0, 0.05])
    fb, vb = np.array([100.0, 300.0, 50.0]), np.array([0.2, 0.1, 0.3])
    k, w = 1 / 44100 / 4, 2 * np.pi * 100
    q, p = fdm_batch(q0, p0, 40, 4, k, w, fb, vb, 100.0)
    for i in range(3):
        qi, pi = fdm_batch(q0[i:i + 1], p0[i:i + 1], 40, 4, k, w, fb[i], vb[i], 100.0)
        np.testing.assert_array_equal(q[i], qi[0])
        np.testing.assert_array_equal(p[i], pi[0])


def test_range_band_pairs_each_state_with_the_bow_it_was_visited_under():
    from bowsynth.training.ranges import range_band

    box = ParamBox(0.1, 0.3, 0.15, 0.25, 100.0)
    pts = box.sample(4, np.random.default_rng(1))
    rb = range_band(box, pts, 100.0, 44100, 0.2, 2 * np.pi, gestures=2, rng=np.random.default_rng(2))
    n = int(0.2 * 44100)
    assert rb.states.shape == rb.params.shape == (6 * n, 2)
    for i, (b, v) in enumerate(pts):  # the points' renders hold their bow; the gestures' stay inside the box
        np.testing.assert_allclose(rb.params[i * n:(i + 1) * n], np.tile([b, v], (n, 1)), rtol=1e-12)
    assert box.contains(rb.params[:, 0], rb.params[:, 1]).all()
    assert not np.allclose(rb.params[4 * n], rb.params[5 * n - 1])  # a gesture moves
    np.testing.assert_allclose(rb.weights.sum(), 1.0)
    # window starts: every 441st state of each render (one window of 2 pi at f0 100, 44.1 kHz)
    np.testing.assert_array_equal(rb.starts[:3, :2], rb.states[[0, 441, 882]])


_ENDS = st.floats(-3, 3, allow_nan=False) | st.sampled_from([0.0, 0.0708, 1.0, 2.0])


@settings(max_examples=300, deadline=None)
@given(x=st.floats(allow_nan=True, allow_infinity=True) | _ENDS | st.integers(-3, 3), lo=_ENDS, hi=_ENDS,
       nudge=st.sampled_from([0.0, 1e-13, -1e-13, 1e-9, -1e-9, 1e-6, -1e-6]))
def test_one_bows_range_test_is_the_arrays(x, lo, hi, nudge):
    """A model lookup tests one bow in plain arithmetic (domain.within's fast path); it answers as the array test
    does, at the ends of a box and its tolerance too."""
    from bowsynth.engines.operator.domain import within

    lo, hi = min(lo, hi), max(lo, hi)
    for v in (x, x + nudge * max(abs(hi), 1.0) if isinstance(x, float) else x, lo + nudge, hi + nudge):
        one, many = within(v, lo, hi), within(np.array([v], float), lo, hi)
        assert isinstance(one, np.bool_) and bool(one) == bool(many[0]), (v, lo, hi)
