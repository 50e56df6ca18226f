"""A note as a player asks for it, made a Scene: a preset, a pitch (Hz or a note name) or an f0, a bow force as F_B or
as beta = F_B / w. The one place these either-or rules live (the CLI, scores and the API come through here)."""

from __future__ import annotations

from .. import controls, physics
from ..controls import Curve
from ..errors import SceneError, UsageError
from ..scene import Scene, load_preset


def make_scene(preset: str | None = None, pitch=None, a4: float | None = None, beta=None, ratio=None,
               **overrides) -> Scene:
    """A Scene from an optional preset, a pitch or an f0, and a bow force as F_B or as F_B / w.

    Parameters
    ----------
    preset : str, optional
        A shipped preset's name (`bowsynth presets`); its fields are the starting point. A preset may itself say
        pitch = "A3" and beta = ... instead of f0 and fb.
    pitch : float or str, optional
        The note to sound, in Hz or as a name such as "A4" (tuned to `a4`): f0 becomes the f0 that sounds at that
        pitch with the scene's bow (see `bowsynth.music.tuning`). A preset's f0 gives way to it; an explicit f0
        conflicts.
    a4 : float, optional
        The tuning of note names (default 440 Hz); only with `pitch`.
    beta : float or curve, optional
        F_B / w, replacing fb by beta 2 pi f0: the same timbre at every pitch. An explicit fb conflicts.
    ratio : callable, optional
        The sounding ratio of the engine that will play the note (`api.tuning_for` gives it), else the physics' from
        the shipped map (`ratio_map.map_ratio`: no reference runs).
    **overrides
        Scene fields (f0, fb, vb, a, duration, sample_rate, ...); None values are ignored.

    Returns
    -------
    Scene

    Raises
    ------
    UsageError
        pitch and f0 both given, fb and beta both given, or a4 without pitch.

    Examples
    --------
    >>> from bowsynth import make_scene
    >>> make_scene("paper-fb100", duration=0.2).fb
    100.0
    >>> s = make_scene(pitch="A4", fb=300, duration=0.5)   # friction lowers the pitch: f0 lies above 440 Hz
    >>> 440 < s.f0 < 470
    True
    >>> s = make_scene(pitch=220.0, beta=0.3, vb=0.2)
    >>> round(s.fb / (2 * 3.141592653589793 * s.f0), 3)
    0.3
    >>> make_scene(pitch="A4", f0=300)
    Traceback (most recent call last):
    ...
    bowsynth.errors.UsageError: give the note as pitch or as f0, not both
    """
    fields = load_preset(preset) if preset else {}
    if overrides.get("f0") is not None and pitch is not None:
        raise UsageError("give the note as pitch or as f0, not both")
    if overrides.get("fb") is not None and beta is not None:
        raise UsageError("give the bow force as fb or as beta (F_B / w), not both")
    if overrides.get("f0") is not None or pitch is not None:
        fields.pop("pitch", None)
        fields.pop("f0", None)
    if overrides.get("fb") is not None or beta is not None:
        fields.pop("beta", None)
        fields.pop("fb", None)
    pitch = fields.pop("pitch", pitch)
    beta = fields.pop("beta", beta)
    fields.update({k: v for k, v in overrides.items() if v is not None})
    if pitch is None:
        if a4 is not None:
            raise UsageError("--a4 tunes a note name or pitch: give --pitch too")
        if beta is not None:
            fields["fb"] = _times(beta, physics.omega(fields.get("f0", Scene.f0)))
        return Scene.from_dict(fields)
    from . import tuning as P
    from .notes import A4_HZ, parse_pitch
    from .ratio_map import map_ratio

    ratio = map_ratio if ratio is None else ratio
    hz = parse_pitch(pitch, A4_HZ if a4 is None else a4)
    probe = {**fields, "f0": hz}
    if beta is not None:
        probe["fb"] = _times(beta, physics.omega(hz))
    sc = Scene.from_dict(probe)  # validates the bow before the solve
    vb = P.held_value(sc.vb, sc.duration)
    if beta is not None:
        f0 = P.tune(hz, None, beta=P.held_value(beta, sc.duration), vb=vb, a=sc.a, ratio=ratio).f0
        return sc.replace(f0=f0, fb=_times(beta, physics.omega(f0)))
    return sc.replace(f0=P.f0_for_pitch(hz, fb=P.held_value(sc.fb, sc.duration), vb=vb, a=sc.a, ratio=ratio))


def _times(control, k: float):
    """A control (number, Curve or [[t, v], ...]) with its values multiplied by k."""
    c = controls.as_control(control)
    if isinstance(c, Curve):
        return Curve(tuple((t, v * k) for t, v in c.points))
    if isinstance(c, bool) or not isinstance(c, (int, float)):
        raise SceneError(f"beta must be a number or a curve, got {control!r}")
    return float(c) * k
