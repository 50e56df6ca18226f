"""What a listener hears, measured for the report (GUIDE section 9): harmonic levels each at the signal's own pitch,
a pitch track, the onset.

These are private to the report until the listener metrics land in bowsynth.metrics; then the report calls those
and this module shrinks to the track and the envelope, which only the report draws.
"""

from __future__ import annotations

import math

import numpy as np

from ..metrics import f0_estimate

N_HARMONICS = 10
FLOOR_DB = -60.0  # harmonics this far below the truth's fundamental are noise for the mean |dB| (as metrics uses)


# TODO(merge): use metrics.harmonic_levels
def _harmonic_amplitudes(x, sample_rate: float, n: int = N_HARMONICS) -> tuple[float, np.ndarray]:
    """(pitch Hz, amplitudes of harmonics 1..n) by least squares at the signal's own pitch over the whole of x.

    Each signal gets its own pitch: at a shared one a 0.16 % pitch difference smears harmonic 10 over 1.6 cycles and
    reads as -17 dB (GUIDE section 9). Harmonics at or above Nyquist are nan."""
    x = np.asarray(x, float)
    f0 = f0_estimate(x, sample_rate, tail=1.0)
    amps = np.full(n, np.nan)
    if not f0 > 0 or len(x) < 8:
        return f0, amps
    t = np.arange(len(x)) / sample_rate
    hs = [h for h in range(1, n + 1) if h * f0 < sample_rate / 2]
    cols = [np.ones_like(t)]
    for h in hs:
        w = 2 * np.pi * h * f0 * t
        cols += [np.cos(w), np.sin(w)]
    coef, *_ = np.linalg.lstsq(np.stack(cols, axis=1), x, rcond=None)
    for i, h in enumerate(hs):
        amps[h - 1] = math.hypot(coef[1 + 2 * i], coef[2 + 2 * i])
    return f0, amps


def harmonic_levels_db(x, ref, sample_rate: float, n: int = N_HARMONICS) -> dict:
    """Harmonics 1..n of x and of ref, each fitted at its own pitch, in dB relative to ref's fundamental (so a level
    difference of the whole note shows too), their difference, and the mean |difference| over the harmonics within
    60 dB of ref's fundamental."""
    fx, ax = _harmonic_amplitudes(x, sample_rate, n)
    fr, ar = _harmonic_amplitudes(ref, sample_rate, n)
    top = ar[0] if ar[0] > 0 else np.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        lx, lr = 20 * np.log10(ax / top), 20 * np.log10(ar / top)
    diff = lx - lr
    keep = np.isfinite(diff) & (lr >= FLOOR_DB)
    return {"f0_hz": fx, "f0_ref_hz": fr, "levels_db": lx, "levels_ref_db": lr, "diff_db": diff,
            "mean_abs_diff_db": float(np.mean(np.abs(diff[keep]))) if keep.any() else float("nan")}


def steady(n: int, k: int | None = None) -> slice:
    """The steady part compare measures pitch on: the second half of the first k samples (default all n)."""
    k = n if k is None else max(4, min(n, k))
    return slice(k // 2, k)


def pitch_track(x, sample_rate: float, f0_hint: float, hop_s: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """(frame centre times s, pitch Hz) from interpolated upward zero crossings, each frame six periods long (at
    least 40 ms) so a low note still has crossings enough; nan where a frame has none (silence, the onset)."""
    x = np.asarray(x, float)
    frame = max(int(0.04 * sample_rate), int(6 * sample_rate / f0_hint)) if f0_hint > 0 else int(0.05 * sample_rate)
    hop = max(1, int(hop_s * sample_rate))
    starts = np.arange(0, max(1, len(x) - frame + 1), hop)
    f = np.array([f0_estimate(x[s:s + frame], sample_rate, tail=1.0) for s in starts])
    return (starts + frame / 2) / sample_rate, f


def rms_envelope(x, sample_rate: float, f0: float) -> np.ndarray:
    """One-period RMS ending at each sample (the first period: over what there is so far)."""
    x = np.asarray(x, float)
    period = max(1, int(round(sample_rate / f0))) if f0 > 0 else max(1, int(0.01 * sample_rate))
    c = np.concatenate([[0.0], np.cumsum(x * x)])
    i = np.arange(1, len(x) + 1)
    lo = np.maximum(0, i - period)
    return np.sqrt((c[i] - c[lo]) / (i - lo))


# TODO(merge): use metrics.onset_time
def onset_time(x, sample_rate: float, f0: float, end: int | None = None) -> float:
    """The first time (s) a one-period RMS reaches half its final value (its value one period before `end`, the end
    of the sustain; default the end of x). nan when the note never speaks."""
    x = np.asarray(x, float)
    end = len(x) if end is None else max(1, min(len(x), end))
    env = rms_envelope(x[:end], sample_rate, f0)
    final = env[-1]
    if not final > 0:
        return float("nan")
    hit = np.flatnonzero(env >= 0.5 * final)
    return float((hit[0] + 1) / sample_rate) if len(hit) else float("nan")


def cents(f, f_ref):
    """Elementwise 1200 log2(f / f_ref); nan where either is not a pitch."""
    f, f_ref = np.asarray(f, float), np.asarray(f_ref, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 1200 * np.log2(f / f_ref)
    return np.where((f > 0) & (f_ref > 0), out, np.nan)
