"""A rollout's geometry in samples and how a voice can fail: one place for the rule "window w ends at floor((w + 1) spw
+ 0.5)" (spw = samples per window, a window being one free period T in tau), which the numpy loop, the planner and
the compiled loops (their own copy, window_end in src/core/rollout.cpp, checked against this in tests) all follow."""

from __future__ import annotations

import math

import numpy as np

FAIL_NONFINITE, FAIL_DOMAIN = 1, 2  # why a voice stopped (the compiled loops write the same codes)
FAIL_BOW = 3  # the bow left the model's range (found before the rollout, from the scene's curves)
FAIL_MUTE = 4  # a held note that did not speak where the physics grows it (onset.mute_from, after the rollout)
FAILURES = {FAIL_NONFINITE: "the rollout turned non-finite",
            FAIL_DOMAIN: "the rollout left the model's trained states",
            FAIL_BOW: "the bow left the model's range",
            FAIL_MUTE: "the note was still silent, though its bow drives the mass,"}


def max_windows(n_samples: int, spw) -> int:
    """Enough windows of spw samples  to pass n_samples, at the shortest spacing given."""
    return int(np.ceil((n_samples + 0.5) / np.min(spw))) + 1


def window_ends(spw, W: int) -> np.ndarray:
    """The end samples of windows 1..W at spw samples per window (a number, or one per voice: then one row each)."""
    spw = np.asarray(spw, dtype=float)
    return np.floor(np.arange(1, W + 1) * spw[..., None] + 0.5).astype(np.int64)


def window_bounds(spw: float, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) in samples of the windows that cover n_samples at spw samples per window ."""
    W = max_windows(n_samples, spw)
    ends = window_ends(spw, W)
    keep = int(np.searchsorted(ends, n_samples)) + 1  # the first window that reaches n_samples is the last
    ends = ends[:keep]
    return np.concatenate([[0], ends[:-1]]).astype(np.int64), ends


def locked_window(T: float, f0: float, sounding: float) -> float:
    """The window (in tau, at most the trained T) of a voice locked to the period it sounds at: that period over k,
    k the fewest windows of at most T that fill it.

    Why: a window's error depends on where in the limit cycle it starts. Windows of T (the free period) are shorter
    than the sounding period (friction lowers the pitch), so each starts at another phase of the cycle, and the
    errors come out at sums and differences of the window rate and the note's harmonics: lines between and below the
    harmonics. Measured (velocity-soft, B3 sounding at 247 Hz from f0 299 Hz, 2 s): q's content below the fundamental
    -62.5 dB re its peak where the FDM's is -120 dB; locked (k = 2) -82 dB, the note's own error then landing on its
    harmonics. The sounding frequency is needed to ~1 %: a mismatch moves the lines to within that share of each
    harmonic. The price: k * ratio windows per free period instead of one (1.7-2x for a soft bow)."""
    period = 2 * math.pi * f0 / sounding
    k = max(1, math.ceil(period / T * (1 - 1e-12)))
    return period / k
