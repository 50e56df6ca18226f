import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bowsynth import Scene, SceneError, UsageError, make_scene
from bowsynth.scene import list_presets, load_preset


@pytest.mark.parametrize("field,value,match", [
    ("f0", 0.0, "f0 must be > 0"), ("f0", 30000.0, "Nyquist"), ("fb", -1.0, "fb must be >= 0"),
    ("a", 0.0, "a must be > 0"), ("duration", 0.0, "duration must be > 0"),
    ("sample_rate", 4000, r"sample_rate must be in \[8000, 384000\]"),
    ("sample_rate", 400_000, "sample_rate must be in"), ("vb", math.nan, "vb must be finite"),
    ("fb", math.inf, "fb must be finite"), ("q0", "x", "q0 must be a number"),
])
def test_scene_rejects_bad_values(field, value, match):
    with pytest.raises(SceneError, match=match):
        Scene(**{field: value})


def test_scene_defaults_and_dimensionless():
    s = Scene()
    assert (s.f0, s.fb, s.vb, s.a, s.duration, s.sample_rate, s.q0, s.p0) == (100, 100, 0.2, 100, 1.0, 44100, 0, 0)
    assert math.isclose(s.beta, Scene(fb=300, f0=300).beta, rel_tol=1e-12)
    assert Scene.from_dict(s.to_dict()) == s


def test_presets_and_overrides():
    assert {"paper-fb10", "paper-fb100", "paper-fb1000"} <= set(list_presets())
    assert load_preset("paper-fb1000")["fb"] == 1000
    s = make_scene("paper-fb1000", vb=0.3, f0=None)
    assert (s.fb, s.vb, s.f0) == (1000, 0.3, 100)
    with pytest.raises(UsageError, match="unknown preset"):
        make_scene("nope")
    with pytest.raises(SceneError, match="unknown scene field"):
        Scene.from_dict({"fbb": 1})


def test_presets_sound_at_their_names_and_name_their_model(capsys, monkeypatch):
    """`bowsynth presets`: every preset builds, says the pitch it sounds at, and which model plays it (or none)."""
    from conftest import run_main

    code, out, err = run_main(["presets"], capsys, monkeypatch)
    assert code == 0, err
    blocks = {b.split()[0]: b for b in out.strip().split("\n") if b and not b.startswith(" ")}
    assert set(blocks) == set(list_presets())
    text = out.replace("\n    ", " ")
    for name in list_presets():
        line = next(l for l in text.splitlines() if l.startswith(name + " "))
        assert "model: " in line
        if name in ("viola-a3", "violin-a4"):  # F_B / w of paper-fb100: the shipped model plays them
            assert "model: paper-fb100.safetensors" in line
            assert f"({name[-2:].upper()})" in line  # sounds at the named note
        # the model named is the one a render picks; none only where no model covers the preset (curves included)
        from bowsynth.engines.operator.choose import find_model, train_hint
        from bowsynth.errors import DomainError

        try:
            assert f"model: {find_model(make_scene(name)).path.name}" in line
        except DomainError:
            assert f"model: none: FDM only, train with `{train_hint(make_scene(name))}`" in line


def test_make_scene_with_pitch_and_beta():
    """A note asked at a pitch is tuned with the shipped map of the physics' ratio, which is the reference's solve
    within hundredths of a cent."""
    from bowsynth.music.ratio_map import physics_ratio
    from bowsynth.music.tuning import sounding_pitch

    s = make_scene(pitch="A3", beta=1 / (2 * math.pi))
    assert math.isclose(s.beta, 1 / (2 * math.pi), rel_tol=1e-12)
    assert math.isclose(s.f0 * physics_ratio(s.beta, s.vb).r, 220.0, rel_tol=1e-9)
    assert math.isclose(sounding_pitch(s.f0, s.fb, s.vb), 220.0, rel_tol=1e-5)
    assert make_scene(beta=0.2, f0=200).fb == pytest.approx(0.2 * 2 * math.pi * 200)
    with pytest.raises(UsageError, match="fb or as beta"):
        make_scene(beta=0.2, fb=100)


@pytest.mark.parametrize("fb,vb,duration,held", [
    (300.0, [(1.0, 0.2), (1.1, 0.0)], 1.6, (300.0, 0.2)),  # a bow stop: v_B falls to 0 after the hold
    ([(0.0, 0.0), (0.05, 120.0)], 0.2, 1.5, (120.0, 0.2)),  # an attack from F_B 0
    ([(0.0, 0.0), (0.1, 120.0), (1.2, 120.0), (1.3, 0.0)], 0.15, 1.5, (120.0, 0.15)),  # both
    (300.0, 0.2, 1.0, (300.0, 0.2)),  # a held bow is its own
    ([(0.3, 30.0), (1.8, 300.0)], 0.2, 2.0, None),  # a crescendo: a gesture
    (300.0, [(0.5, 0.12), (1.5, 0.25)], 2.0, None),  # a bow-speed change holds for half the note, but not from rest
    (300.0, [(0.1, 0.2), (0.6, 0.0)], 1.0, None),  # the stop takes most of the note
    (300.0, [(1.0, 0.2), (1.1, 0.0), (1.2, 0.1)], 2.0, None),  # it stops, then bows again
    (300.0, [(0.5, 0.2), (0.6, 0.1), (0.7, 0.2)], 2.0, None),  # a dip before the hold is no attack
    ([(0.0, 50.0), (0.05, 120.0)], 0.2, 1.5, None),  # a force that rises from 50, not from the string at rest
])
def test_the_held_bow_of_a_note_is_the_one_it_holds_between_an_attack_and_a_stop(fb, vb, duration, held):
    got = Scene(f0=150.0, fb=fb, vb=vb, duration=duration).held_bow()
    assert (None if got is None else (got.fb, got.vb)) == (None if held is None else pytest.approx(held))
    assert got is None or not got.varying


def test_a_moving_pitch_holds_no_bow():
    assert Scene(f0=[(0.0, 150.0), (1.0, 160.0)], fb=300.0, vb=0.2).held_bow() is None


_times = st.lists(st.floats(0.0, 3.0, allow_nan=False), min_size=1, max_size=5, unique=True).map(sorted)


@st.composite
def _curve(draw, hi):
    ts = draw(_times)
    return [(t, draw(st.sampled_from([0.0, hi / 2, hi]))) for t in ts]


@settings(max_examples=200, deadline=None)
@given(fb=st.one_of(st.just(300.0), _curve(300.0)), vb=st.one_of(st.just(0.2), _curve(0.2)),
       duration=st.floats(0.05, 3.0))
def test_a_held_bow_is_held_for_half_the_note_and_every_other_bow_is_an_attack_or_a_stop(fb, vb, duration):
    """Any breakpoints: held_bow never raises; where it names a bow, the curves hold exactly that bow for at least
    HELD_SHARE of the note, rise to it from a bow at rest and fall from it to a bow at rest, never beyond it."""
    from bowsynth.scene import HELD_SHARE

    sc = Scene(f0=150.0, fb=fb, vb=vb, duration=duration)
    h = sc.held_bow()
    if h is None:
        return
    assert not h.varying
    t = np.linspace(0.0, duration, 4001)
    f, v = sc.fb_at(t), sc.vb_at(t)
    held = (f == h.fb) & (v == h.vb)
    assert held.mean() >= HELD_SHARE - 2e-3
    assert (f <= h.fb).all() and (v <= h.vb).all()  # the bow moves only below the held one: to or from rest
    if sc.varying and not held.all():
        ends = [i for i in (0, -1) if not held[i]]
        assert all(min(f[i], v[i]) == 0.0 for i in ends)
