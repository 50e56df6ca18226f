"""A gesture's bow frame by frame, from each 100 ms frame's timbre and pitch: where a curve fit starts.

A held bow's timbre (its harmonics' levels re the fundamental) is the same at every f0, and its pitch is f0 r(bow).
So the grid's bows are played once, each at the target's pitch, and their steady harmonic levels kept; each frame of
the target takes the bows whose levels lie nearest its own (TOP of them), and of those the one whose implied f0 =
frame pitch / r(bow) lies nearest the note's (the median over frames of the best-sounding ones' f0). The pitch
telling apart bows that sound alike is what a gesture adds over a held note: along the ridge where F_B / w and v_B
grow together the timbre hardly changes but r does.
"""

from __future__ import annotations

import math

import numpy as np

from ..metrics import f0_estimate, harmonic_levels
from ..music.ratio_map import physics_ratio, vb_stop
from .search import BETA_RANGE, GRID, VB_RANGE, Scorer, vb_axis, f0_for
from .target import Target

FRAME = 0.1  # s
TOP = 6  # the bows nearest a frame's timbre among which its pitch chooses
FLOOR_DB = -50.0  # harmonics below this (re the fundamental) are not compared
STEADY = 0.4  # s: the end of a grid bow's note whose levels are its timbre
GRID_FINE = (2 * GRID[0], 2 * GRID[1])  # the timbre table's bows


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """Mean |dB| over harmonics 2-10 that either sounds above FLOOR_DB (both floored there)."""
    a, b = np.maximum(a[1:], FLOOR_DB), np.maximum(b[1:], FLOOR_DB)
    keep = np.isfinite(a) & np.isfinite(b) & ((a > FLOOR_DB) | (b > FLOOR_DB))
    return float(np.mean(np.abs(a[keep] - b[keep]))) if keep.any() else math.inf


def timbre_table(scorer: Scorer, grid=GRID_FINE, a: float = 100.0) -> list[tuple[float, float, np.ndarray]]:
    """(F_B / w, v_B, harmonic levels) of the grid's held bows, each played from rest at the target's pitch."""
    stop = vb_stop(a)
    out = []
    n_end = int(STEADY * scorer.target.sample_rate)
    for b in np.geomspace(*BETA_RANGE, grid[0]):
        for v in stop + vb_axis(a, grid[1]) ** 3:
            f0 = f0_for(scorer.pitch, float(b), float(v))
            if f0 is None or not 20.0 <= f0 < scorer.target.sample_rate / 2.5:
                continue
            m = scorer.model_for(float(b), float(v), f0)
            if m is None:
                continue
            try:
                q = scorer.note(m, f0, False).play((float(b), float(v)))
            except Exception:  # noqa: BLE001 - a bow its model cannot play from rest: not in the table
                continue
            if np.all(np.isfinite(q)):
                out.append((float(b), float(v), harmonic_levels(q[-n_end:], scorer.target.sample_rate)))
    return out


def frame_bows(target: Target, scorer: Scorer | None = None, frame: float = FRAME, a: float = 100.0):
    """(times, beta, vb, f0): each frame's bow (at its middle time) and the note's f0; None where no frame has a
    pitch."""
    scorer = Scorer(target, seconds=1.0) if scorer is None else scorer
    table = timbre_table(scorer, a=a)
    rate = target.sample_rate
    n = int(frame * rate)
    starts = list(range(0, target.n - n + 1, n))
    rms = np.array([np.std(target.x[s:s + n]) for s in starts])
    stopped = _stopped(rms)
    frames = []
    for s, stop in zip(starts, stopped):
        if stop:  # the bow has stopped: the mass rings down (or rests) at v_B = 0, whatever its timbre
            frames.append(((s + n / 2) / rate, math.nan, None))
            continue
        x = target.x[s:s + n]
        p = f0_estimate(x, rate, tail=1.0)
        if not (math.isfinite(p) and p > 0):
            continue
        lv = harmonic_levels(x, rate, f0=p)
        near = sorted(((_distance(lv, t[2]), t[0], t[1]) for t in table), key=lambda r: r[0])[:TOP]
        frames.append(((s + n / 2) / rate, p, near))
    if not any(near for _, _, near in frames):
        return None

    def implied(p, b, v):
        try:
            return p / physics_ratio(b, v, a).r
        except Exception:  # noqa: BLE001 - a bow that does not sound
            return math.nan

    f0 = float(np.nanmedian([implied(p, near[0][1], near[0][2]) for _, p, near in frames if near]))
    times, beta, vb, stops = [], [], [], []
    for t, p, near in frames:
        if near is None:  # a stop: no speed (its force: the sustain's, below)
            times.append(t)
            beta.append(math.nan)
            vb.append(0.0)
            stops.append(True)
            continue
        stops.append(False)
        best = min(near, key=lambda r: abs(math.log(implied(p, r[1], r[2]) / f0))
                   if math.isfinite(implied(p, r[1], r[2])) else math.inf)
        times.append(t)
        beta.append(best[1])
        vb.append(best[2])
    beta, vb, stops = np.array(beta), np.array(vb), np.array(stops)
    beta[stops] = np.median(beta[~stops])  # a bow stop keeps the sustain's force
    beta, vb = _median3(beta), _median3(vb)
    return np.array(times), np.clip(beta, *BETA_RANGE), np.clip(vb, 0.0, VB_RANGE[1]), f0


STOP_FALL = 0.8  # a frame this much quieter than the one before, after the loudest, is part of a bow stop
STOP_LEVEL = 0.5  # ... once below this share of the loudest frame


def _stopped(rms: np.ndarray) -> np.ndarray:
    """Per frame: has the bow stopped (the sound falling away after its loudest frame, and staying down)?"""
    out = np.zeros(len(rms), bool)
    if len(rms) < 3:
        return out
    top = int(np.argmax(rms))
    for k in range(top + 1, len(rms)):
        falling = rms[k] < STOP_FALL * rms[k - 1] or (out[k - 1] and rms[k] <= rms[k - 1])
        if falling and rms[k] < STOP_LEVEL * rms[top]:
            out[k] = True
        elif out[k - 1]:
            break
    return out


def _median3(x: np.ndarray) -> np.ndarray:
    """A running median over 3 frames (the ends kept): one frame's odd pick does not bend the curve."""
    if len(x) < 3:
        return x
    y = x.copy()
    y[1:-1] = np.median(np.stack([x[:-2], x[1:-1], x[2:]]), axis=0)
    return y
