"""Control curves: bow parameters that change within a note (a crescendo, an attack, a bow stop).

A curve is a list of breakpoints (t, value), t in seconds from the start of the render, linear between them and held
before the first and after the last. Engines turn a scene's controls into arrays with the one resampler here
(`at`): the FDM per step, the operator per window, and every Render reports them per output sample.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .errors import SceneError


@dataclass(frozen=True)
class Curve:
    """Breakpoints ((t0, v0), (t1, v1), ...), times strictly increasing, all finite."""

    points: tuple

    def __post_init__(self):
        pts = self.points
        if isinstance(pts, Curve):
            pts = pts.points
        try:
            pts = tuple((float(t), float(v)) for t, v in pts)
        except (TypeError, ValueError):
            raise SceneError(f"a curve is a list of [time, value] pairs, got {self.points!r}") from None
        if not pts:
            raise SceneError("a curve needs at least one [time, value] pair")
        for t, v in pts:
            if not (math.isfinite(t) and math.isfinite(v)):
                raise SceneError(f"curve breakpoints must be finite, got [{t:g}, {v:g}]")
            if t < 0:
                raise SceneError(f"curve times must be >= 0 s, got {t:g}")
        for (t0, _), (t1, _) in zip(pts, pts[1:]):
            if not t1 > t0:
                raise SceneError(f"curve times must increase strictly, got {t0:g} then {t1:g}")
        object.__setattr__(self, "points", pts)

    @property
    def times(self) -> np.ndarray:
        return np.array([t for t, _ in self.points])

    @property
    def values(self) -> np.ndarray:
        return np.array([v for _, v in self.points])

    @property
    def lo(self) -> float:
        return min(v for _, v in self.points)

    @property
    def hi(self) -> float:
        return max(v for _, v in self.points)

    @property
    def first(self) -> float:
        return self.points[0][1]

    @property
    def last(self) -> float:
        return self.points[-1][1]

    @property
    def constant(self) -> bool:
        return self.lo == self.hi

    def at(self, t) -> np.ndarray:
        """Values at times t (s): linear between breakpoints, held outside them."""
        return np.interp(np.asarray(t, float), self.times, self.values)

    def to_list(self) -> list:
        return [[t, v] for t, v in self.points]

    def __str__(self) -> str:
        return ",".join(f"{v:g}@{t:g}" for t, v in self.points)


def as_control(value):
    """A scene control from a number, a Curve or a list of [t, value] pairs: a float if it holds one value, else a
    Curve. Anything else is returned as is, for the Scene's own type check to name."""
    if isinstance(value, Curve):
        c = value
    elif isinstance(value, (list, tuple)):
        c = Curve(tuple(value))
    else:
        return value
    return float(c.first) if c.constant else c


def breakpoints(value) -> tuple[np.ndarray, np.ndarray]:
    """(times, values) arrays of a control (a number is one breakpoint): what the compiled FDM loop reads."""
    if isinstance(value, Curve):
        return value.times, value.values
    return np.zeros(1), np.array([float(value)])


def sample(value, t) -> np.ndarray:
    """A control (number or Curve) at times t, as a float array."""
    if isinstance(value, Curve):
        return value.at(t)
    return np.full(np.shape(t), float(value))


def bounds(value) -> tuple[float, float]:
    """(lowest, highest) value a control takes."""
    if isinstance(value, Curve):
        return value.lo, value.hi
    return float(value), float(value)


def after(value, t0: float):
    """A control as seen from t0 on (time t0 becomes 0): how a render continued from the middle of a note (the
    operator's FDM fallback) keeps following the same curve."""
    if not isinstance(value, Curve) or t0 <= 0:
        return value
    pts = [(t - t0, v) for t, v in value.points if t > t0]
    return as_control([(0.0, float(value.at(t0)))] + pts)


def between(value, t0: float, t1: float):
    """A control over [t0, t1] only, seen from t0 on (time t0 becomes 0) and held after t1: a stretch of a note
    played on its own (a chain of models' turns, engines/operator/chain.py), whose range is that stretch's alone."""
    if not isinstance(value, Curve):
        return value
    inner = [(t - t0, v) for t, v in value.points if t0 < t < t1]
    return as_control([(0.0, float(value.at(t0)))] + inner + [(t1 - t0, float(value.at(t1)))])


def parse_control(text: str, name: str):
    """A CLI value: a number (`100`) or a curve as VALUE@TIME pairs (`50@0,200@1.5`: 50 at 0 s rising to 200 at
    1.5 s)."""
    text = text.strip()
    if "@" not in text:
        try:
            return float(text)
        except ValueError:
            raise SceneError(f"--{name} must be a number or a curve like 50@0,200@1 (VALUE@SECONDS, comma-"
                             f"separated), got {text!r}") from None
    pts = []
    for part in text.split(","):
        v, sep, t = part.partition("@")
        try:
            pts.append((float(t), float(v)))
        except ValueError:
            raise SceneError(f"--{name}: {part!r} is not VALUE@SECONDS (a curve looks like 50@0,200@1)") from None
    try:
        return as_control(pts)
    except SceneError as e:
        raise SceneError(f"--{name}: {e}") from None
