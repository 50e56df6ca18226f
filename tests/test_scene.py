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
