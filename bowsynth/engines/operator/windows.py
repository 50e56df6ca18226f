"""A rollout's geometry in samples and how a voice can fail: one place for the rule "window w ends at floor((w + 1) spw
+ 0.5)" (spw = samples per window, a window being one free period T in tau), which the numpy loop, the planner and
the compiled loops (their own copy, `loops.window_end`, checked against this in tests) all follow."""

from __future__ import annotations

import numpy as np

FAIL_NONFINITE, FAIL_DOMAIN = 1, 2  # why a voice stopped (the compiled loops write the same codes)
FAIL_BOW = 3  # the bow left the model's range (found before the rollout, from the scene's curves)
FAILURES = {FAIL_NONFINITE: "the rollout turned non-finite",
            FAIL_DOMAIN: "the rollout left the model's trained states",
            FAIL_BOW: "the bow left the model's range"}


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
