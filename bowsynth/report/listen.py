"""What a listener hears, measured for the report (docs/measures.md): harmonic levels each at the signal's own pitch,
a pitch track, the onset.

The measurements themselves are bowsynth.metrics'; this module holds what only the report draws: levels re the
truth's fundamental, the pitch track and the envelope.
"""

from __future__ import annotations

import numpy as np

from ..metrics import f0_estimate, harmonic_amplitudes

N_HARMONICS = 10
FLOOR_DB = -60.0  # harmonics this far below the truth's fundamental are noise for the mean |dB| (as metrics uses)


def harmonic_levels_db(x, ref, sample_rate: float, n: int = N_HARMONICS) -> dict:
    """Harmonics 1..n of x and of ref, each fitted at its own pitch, in dB relative to ref's fundamental (so a level
    difference of the whole note shows too), their difference, and the mean |difference| over the harmonics within
    60 dB of ref's fundamental."""
    fx, fr = (f0_estimate(np.asarray(v, float), sample_rate, tail=1.0) for v in (x, ref))
    ax, ar = harmonic_amplitudes(x, sample_rate, n, fx), harmonic_amplitudes(ref, sample_rate, n, fr)
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


def cents(f, f_ref):
    """Elementwise 1200 log2(f / f_ref); nan where either is not a pitch."""
    f, f_ref = np.asarray(f, float), np.asarray(f_ref, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 1200 * np.log2(f / f_ref)
    return np.where((f > 0) & (f_ref > 0), out, np.nan)
