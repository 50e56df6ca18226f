"""A note of a piece: its scene, how long the bow is held, and the bow stop that ends it (the bow slowed to v_B = 0
over the release, then the tail until the mass has rung down)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .. import physics
from ..controls import Curve, as_control
from ..scene import Scene

RELEASE = 0.05  # s: default bow-stop time
TAIL = 0.03  # s: the shortest render after the bow stops
TAIL_TIME_CONSTANTS = 10.0  # e^-10 by the linear rate; the saturated friction of the first ms is slower
MAX_TAIL = 2.0
MAX_RELEASE = 10.0


def stop_tail(fb: float, f0: float, a: float) -> float:
    """Seconds to render after the bow has stopped (v_B = 0) for the mass to come to rest (-60 dB).

    On a stopped bow the friction is a damper of rate c = F_B phi'(0): the mass rings down at c / 2 when c < 2w;
    above that it creeps back to rest at the slow root (c - sqrt(c^2 - 4 w^2)) / 2 (a pressed bow holds the mass
    aside: measured at F_B / w 0.64, C2, 19 % of the peak was left 30 ms after the stop).

    Parameters
    ----------
    fb : float
        The bow force at the stop (m/s^2).
    f0 : float
        Hz.
    a : float
        The friction shape (s^2/m^2).

    Returns
    -------
    float
        Seconds, from TAIL to MAX_TAIL (MAX_TAIL where no friction damps the mass).

    Examples
    --------
    >>> round(stop_tail(100.0, 100.0, 100.0), 4), stop_tail(0.0, 100.0, 100.0)
    (0.0544, 2.0)
    """
    c = fb * physics.dphi(0.0, a)
    if c <= 0:
        return MAX_TAIL
    w = physics.omega(f0)
    rate = 0.5 * (c - math.sqrt(max(c * c - 4 * w * w, 0.0)))
    return float(min(MAX_TAIL, max(TAIL, TAIL_TIME_CONSTANTS / rate)))


@dataclass
class Note:
    """One note: its own bowed mass from rest, starting `start` s into the piece (what a score is made of).

    A voice is a name for a group of notes (one stem), and its notes may overlap. The end of a note is a physical
    bow stop: v_B falls linearly to 0 over `release` seconds, the friction (its slope is positive below
    v_B = 1/sqrt(2a)) damps the mass, and the render stops TAIL s later (`stop_tail`). A note's sustain is rendered
    by the chosen engine; its release by a model whose box reaches v_B = 0 where one covers it, else by the FDM,
    from the sustain's state at the hold (`perform.finish_releases`). `bowsynth.music.score` reads notes from TOML
    scores and MIDI files.

    Parameters
    ----------
    name : str
        Its voice.
    scene : Scene
        The whole note: its sustain of `hold` s, then the bow stop of `release` s and the tail.
    start : float
        Seconds into the piece.
    hold : float, optional
        Seconds of bowing before the release (default: the scene's duration).
    release : float
        Seconds of the bow stop.
    pitch : float, optional
        The asked pitch in Hz (None for a note given by f0).
    label : str
        What messages call it (`describe`; default its voice's name).
    extra : dict
        What the reader adds (a MIDI note's number and velocity).

    Examples
    --------
    >>> from bowsynth.scene import Scene
    >>> n = Note("solo", Scene(duration=0.5), start=1.0)
    >>> n.hold, n.end, n.gesture, n.describe()
    (0.5, 1.5, False, 'solo')
    """

    name: str
    scene: Scene
    start: float = 0.0
    hold: float | None = None
    release: float = 0.0
    pitch: float | None = None
    label: str = ""
    extra: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.hold is None:
            self.hold = self.scene.duration

    @property
    def end(self) -> float:
        """Seconds into the piece where its render (tail included) ends."""
        return self.start + self.scene.duration

    @property
    def gesture(self) -> bool:
        """Does the bow change during the sustain (before the release)?"""
        return self.sustain_scene().varying

    def sustain_scene(self, extra_samples: int = 0) -> Scene:
        """The note without its release: the controls over [0, hold], constant ones as numbers."""
        sc = self.scene
        n = self.hold_samples + extra_samples
        # a moving pitch keeps its force curve (F_B = beta w(t) follows the pitch through the note)
        fb = sc.fb if sc.pitch_varies else _clip(sc.fb, self.hold)
        return sc.replace(fb=fb, vb=_clip(sc.vb, self.hold), duration=n / sc.sample_rate)

    @property
    def hold_samples(self) -> int:
        """Samples of the sustain: hold x the sample rate, rounded."""
        return int(round(self.hold * self.scene.sample_rate))

    def rollout_scene(self) -> Scene:
        """What the operator plays: the sustain, its bow held to the note's end when there is a release (the release
        then overwrites the samples after the hold in place: copying a 60 s voice into a new array cost more than
        rolling the sustain on through its release)."""
        return self.sustain_scene(self.scene.n_samples - self.hold_samples if self.release > 0 else 0)

    def describe(self) -> str:
        """What messages call the note: its label, else its voice."""
        return self.label or self.name


def _clip(control, end: float):
    """A control over [0, end] only (what it does after `end` dropped), as a number if constant there."""
    if not isinstance(control, Curve):
        return control
    t = np.concatenate([[0.0], control.times[(control.times > 0) & (control.times < end)], [end]])
    pts = [(float(a), float(b)) for a, b in zip(t, control.at(t))]
    dedup = [pts[0]] + [p for prev, p in zip(pts, pts[1:]) if p[0] > prev[0]]
    return as_control(dedup)


def with_release(vb, hold: float, release: float):
    """vb over [0, hold], then a linear fall to 0 over `release` seconds."""
    held = _clip(vb, hold)
    at_hold = float(held.at(hold)) if isinstance(held, Curve) else float(held)
    pts = held.to_list() if isinstance(held, Curve) else [[0.0, at_hold], [hold, at_hold]]
    if pts[-1][0] < hold:
        pts.append([hold, at_hold])
    if pts[0][0] == hold == 0.0:
        pts = [[0.0, at_hold]]
    pts.append([hold + release, 0.0])
    return as_control(pts)


def scaled(control, k: float):
    if isinstance(control, Curve):
        return Curve(tuple((t, v * k) for t, v in control.points))
    return float(control) * k
