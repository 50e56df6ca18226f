"""Bow gestures: curves on fb and vb, followed per step by the FDM and reported per sample by every Render."""

import json

import numpy as np
import pytest
from conftest import run_main, shipped_pick
from hypothesis import given, settings
from hypothesis import strategies as st

from bowsynth import Scene, SceneError, render_fdm
from bowsynth.metrics import nmse
from bowsynth.controls import Curve, parse_control


@pytest.mark.parametrize("pts,needle", [
    ([], "at least one"),
    ([(0.0, 1.0), (0.0, 2.0)], "increase strictly"),
    ([(1.0, 1.0), (0.5, 2.0)], "increase strictly"),
    ([(0.0, float("nan"))], "finite"),
    ([(float("inf"), 1.0)], "finite"),
    ([(-0.1, 1.0)], ">= 0"),
    ([(0.0,)], "pairs"),
    ("abc", "number or a curve"),
])
def test_bad_curves_are_refused_with_a_reason(pts, needle):
    with pytest.raises(SceneError, match=needle):
        Scene(fb=pts)


def test_negative_force_anywhere_on_the_curve_is_refused():
    with pytest.raises(SceneError, match="fb must be >= 0"):
        Scene(fb=[(0.0, 100.0), (0.5, -1.0)])


def test_curve_is_linear_between_and_held_outside():
    c = Curve(((0.5, 10.0), (1.5, 30.0)))
    np.testing.assert_allclose(c.at([0.0, 0.5, 1.0, 1.5, 9.0]), [10.0, 10.0, 20.0, 30.0, 30.0])
    assert (c.lo, c.hi, c.first, c.last) == (10.0, 30.0, 10.0, 30.0)


def test_a_curve_holding_one_value_is_a_constant_and_scenes_round_trip_through_json():
    assert Scene(fb=[(0.0, 80.0), (1.0, 80.0)]).fb == 80.0
    s = Scene(fb=[(0.0, 50.0), (1.0, 200.0)], vb=[[0.0, 0.2], [0.5, 0.05]])
    assert s.varying and isinstance(s.fb, Curve)
    back = Scene.from_dict(json.loads(json.dumps(s.to_dict())))
    assert back == s
    with pytest.raises(SceneError, match="varies"):
        s.beta
    assert s.beta_range == pytest.approx((50 / s.omega, 200 / s.omega))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 100), st.floats(-1e6, 1e6)), min_size=1, max_size=6, unique_by=lambda p: p[0]))
def test_parse_control_round_trips_any_sorted_curve(pts):
    pts = sorted(pts)
    text = ",".join(f"{v!r}@{t!r}" for t, v in pts)
    got = parse_control(text, "fb")
    want = Curve(tuple(pts))
    if want.constant:
        assert got == want.first
    else:
        assert got == want


def test_fdm_applies_the_curve_per_sample_and_reports_it():
    s = Scene(fb=[(0.0, 50.0), (0.3, 200.0)], vb=[(0.1, 0.2), (0.25, 0.1)], duration=0.4)
    r = render_fdm(s)
    np.testing.assert_allclose(r.controls["fb"], s.fb.at(r.t))
    np.testing.assert_allclose(r.controls["vb"], s.vb.at(r.t))
    assert r.controls["fb"][0] == 50.0 and r.controls["fb"][-1] == 200.0


def test_a_curve_that_starts_after_the_render_ends_renders_exactly_as_its_held_value():
    const = render_fdm(Scene(fb=120.0, duration=0.3))
    held = render_fdm(Scene(fb=[(1.0, 120.0), (2.0, 400.0)], duration=0.3))
    np.testing.assert_array_equal(held.p, const.p)
    np.testing.assert_array_equal(held.q, const.q)


def test_gesture_render_converges_with_the_fdm_rate():
    # a crescendo and a bow-speed change at once: the error against x100 falls at second order with the rate
    s = Scene(fb=[(0.0, 50.0), (0.25, 200.0)], vb=[(0.0, 0.1), (0.25, 0.28)], duration=0.25)
    ref = render_fdm(s, oversample=100).p
    e1, e4 = nmse(render_fdm(s, oversample=1).p, ref), nmse(render_fdm(s, oversample=4).p, ref)
    assert e4 < e1 / 8
    assert e4 < 1e-4


def test_a_bow_stop_lets_friction_damp_the_mass():
    # v_B falls below 1/sqrt(2a) = 0.071: the friction slope at rest turns positive and damps the oscillation
    s = Scene(fb=100.0, vb=[(0.0, 0.2), (0.5, 0.2), (0.6, 0.0)], duration=1.2)
    p = render_fdm(s, oversample=2).p
    n = len(p)
    playing, after = np.std(p[int(0.3 * n / 1.2):int(0.5 * n / 1.2)]), np.std(p[-int(0.1 * n / 1.2):])
    assert playing > 0.1
    assert after < 0.05 * playing


def test_cli_renders_a_gesture_with_the_fdm_and_stores_the_curve(tmp_path, monkeypatch, capsys):
    out = tmp_path / "g.wav"
    code, _, err = run_main(["render", "--method", "fdm", "--fb", "50@0,200@0.2", "-d", "0.3", str(out)],
                            capsys, monkeypatch)
    assert code == 0, err
    from bowsynth.io.audio import read_wav

    sc = read_wav(out).scene
    assert sc.fb == Curve(((0.0, 50.0), (0.2, 200.0)))


@pytest.mark.parametrize("flag,needle", [("200@1,50@0", "increase strictly"), ("50@x", "VALUE@SECONDS"),
                                         ("fast", "number or a curve"), ("50@0,-3@1", "fb must be >= 0")])
def test_cli_refuses_bad_gestures_in_one_line(flag, needle, tmp_path, monkeypatch, capsys):
    code, _, err = run_main(["render", "--method", "fdm", "--fb", flag, str(tmp_path / "x.wav")], capsys, monkeypatch)
    assert code == 2 and needle in err and err.count("\n") == 1
    assert not (tmp_path / "x.wav").exists()


def test_operator_refuses_a_gesture_it_cannot_follow(tmp_path, monkeypatch, capsys):
    """A crescendo past every model's range: one line naming the value, the time it leaves and the train command;
    nothing written. A shipped soft range model follows one inside its box (the renderer's pick for it)."""
    out = tmp_path / "x.wav"
    code, _, err = run_main(["render", "--fb", "50@0,3000@0.2", str(out)], capsys, monkeypatch)
    assert code == 1 and "--method fdm" in err and err.count("\n") == 1
    assert "F_B = " in err and "t = " in err and "bowsynth train --fb 50:3000" in err and not out.exists()
    pick = shipped_pick(Scene(fb=[(0.0, 50.0), (0.2, 200.0)], duration=0.3))
    assert pick.domain.is_range, pick.path
    code, so, err = run_main(["render", "--fb", "50@0,200@0.2", "-d", "0.3", str(out)], capsys, monkeypatch)
    assert code == 0 and "method operator" in so + err and pick.path.name in so + err and "range_fb" in so + err


def test_after_shifts_a_curve_to_start_at_t0():
    """Scene.after(t0): the rest of a note seen from t0 (how the FDM fallback continues an operator render)."""
    from bowsynth import Scene
    from bowsynth.controls import Curve, after

    c = Curve(((0.0, 50.0), (1.0, 150.0), (2.0, 100.0)))
    d = after(c, 0.5)
    t = np.linspace(0, 2, 41)
    np.testing.assert_allclose(d.at(t), c.at(t + 0.5))
    assert after(c, 3.0) == 100.0  # past the last breakpoint: held
    assert after(7.0, 1.0) == 7.0 and after(c, 0.0) is c
    sc = Scene(fb=c, vb=[[0.0, 0.1], [1.0, 0.3]], duration=2.0)
    rest = sc.after(1.0, duration=1.0)
    np.testing.assert_allclose(rest.fb_at(t / 2), sc.fb_at(t / 2 + 1.0))
    assert rest.vb == 0.3 and rest.duration == 1.0
