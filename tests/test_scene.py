import math

import pytest

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
    from bowsynth.music.tuning import sounding_pitch

    s = make_scene(pitch="A3", beta=1 / (2 * math.pi))
    assert math.isclose(s.beta, 1 / (2 * math.pi), rel_tol=1e-12)
    assert math.isclose(sounding_pitch(s.f0, s.fb, s.vb), 220.0, rel_tol=1e-7)
    assert make_scene(beta=0.2, f0=200).fb == pytest.approx(0.2 * 2 * math.pi * 200)
    with pytest.raises(UsageError, match="fb or as beta"):
        make_scene(beta=0.2, fb=100)
