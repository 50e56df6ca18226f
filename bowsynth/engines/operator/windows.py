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


class Lock(float):
    """A frequency (Hz), or a ratio to f0, that a voice's windows are locked to, with `more`: windows a period beyond
    the fewest of at most T that fill it (locked_window). A plain float is a lock with more = 0.

    Why more: a lock is measured (music.model_ratio.lock_ratio), and the fewest windows do not always hold it.
    stick-stops at F_B / w 0.719, v_B 0.08 fills the physics' period with 16.9 trained windows; 17 windows, each
    0.994 T, leave its pitch where its own period is (+5.3 / +5.8 cents at 110 / 440 Hz, harmonics 0.49 dB worst),
    18 hold it (+0.012 / -0.002 cents, 0.048 dB: benchmarks/map_cell.py). Arithmetic on a Lock gives a
    plain float, so a lock is made anew where it is scaled (engine_tuning.operator_sounding)."""

    more: int

    def __new__(cls, value: float, more: int = 0):
        lock = super().__new__(cls, value)
        lock.more = int(more)
        return lock

    def __repr__(self) -> str:
        return f"Lock({float(self)!r}, more={self.more})"


def lock_more(sounding) -> int:
    """The windows a period beyond the fewest that a lock asks for (0 for a plain float)."""
    return getattr(sounding, "more", 0)


def lock_at(ratio, f0: float) -> Lock | None:
    """The lock of a held note at f0 whose windows hold `ratio` (a sounding ratio, with its `more`); None: free."""
    return None if ratio is None else Lock(f0 * float(ratio), lock_more(ratio))


def locked_window(T: float, f0: float, sounding: float) -> float:
    """The window (in tau, at most the trained T) of a voice locked to the period it sounds at: that period over k,
    k the fewest windows of at most T that fill it, plus the lock's `more` (a Lock; 0 for a float).

    Why: a window's error depends on where in the limit cycle it starts. Windows of T (the free period) are shorter
    than the sounding period (friction lowers the pitch), so each starts at another phase of the cycle, and the
    errors come out at sums and differences of the window rate and the note's harmonics: lines between and below the
    harmonics. Measured (velocity-soft, B3 sounding at 247 Hz from f0 299 Hz, 2 s): q's content below the fundamental
    -62.5 dB re its peak where the FDM's is -120 dB; locked (k = 2) -82 dB, the note's own error then landing on its
    harmonics. The sounding frequency is needed to ~1 %: a mismatch moves the lines to within that share of each
    harmonic. The price: k * ratio windows per free period instead of one (1.7-2x for a soft bow)."""
    period = 2 * math.pi * f0 / sounding
    k = max(1, math.ceil(period / T * (1 - 1e-12))) + lock_more(sounding)
    return period / k
