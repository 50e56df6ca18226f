"""A note's moving pitch as written in a score (docs/score.md, "Pitch curves"): `pitch` as breakpoints and/or
`cents` as an offset curve, into [(t, Hz), ...] breakpoints that `score` tunes one by one."""

from __future__ import annotations

import numpy as np

from ..controls import Curve, as_control
from ..errors import SceneError
from .notes import parse_pitch

MAX_PITCH_POINTS = 4096  # a pitch curve's breakpoints (the operator's curve path holds as many)
CENTS_STEP = 0.005  # s: a cents curve is sampled this often between its breakpoints (linear in Hz, not in cents)


def pitch_points(where: str, fields: dict, a4: float):
    """[(t, Hz), ...] for a note whose `pitch` is breakpoints [[t, "A4"], [t, 440.0], ...] and/or whose `cents`
    ([[t, cents], ...] or a number) moves it; None for a pitch that holds. Raises SceneError (one line)."""
    pitch, cents = fields.get("pitch"), fields.get("cents")
    if not isinstance(pitch, list) and cents is None:
        return None
    if isinstance(pitch, list):
        try:
            base = as_control([(float(t), parse_pitch(v, a4)) for t, v in pitch])
        except (TypeError, ValueError):
            raise SceneError(f"a pitch curve is [[seconds, pitch], ...] (pitch a note name or Hz), got "
                             f"{pitch!r}") from None
    elif "pitch" in fields:
        base = parse_pitch(pitch, a4)
    else:
        raise SceneError("cents moves a pitch: give pitch too")
    if cents is None:
        cents = 0.0
    if isinstance(cents, bool) or not isinstance(cents, (int, float, list)):
        raise SceneError(f"cents must be a number or a curve [[seconds, cents], ...], got {cents!r}")
    c = as_control(cents)
    times = set(_times(base)) | set(_times(c))
    if isinstance(c, Curve):  # 2^(c / 1200) is not linear in c: sample between the cents breakpoints
        times |= set(np.arange(0.0, c.times[-1], CENTS_STEP).tolist())
    t = np.array(sorted(times))
    hz = base.at(t) if isinstance(base, Curve) else np.full(len(t), float(base))
    hz = hz * 2.0 ** ((c.at(t) if isinstance(c, Curve) else float(c)) / 1200.0)
    if len(t) > MAX_PITCH_POINTS:
        raise SceneError(f"the pitch curve needs {len(t)} breakpoints, at most {MAX_PITCH_POINTS}")
    return list(zip(t.tolist(), hz.tolist()))


def _times(c) -> list[float]:
    return c.times.tolist() if isinstance(c, Curve) else [0.0]
