"""The sample grid a stick-slip voice is computed on: every window a whole number of samples, then resampled.

The operator hands each window's end state to the next at tau = T, the point it was trained to hand over at. On the
output grid a window whose length T / dtau is not a whole number ends at the sample nearest T instead (windows.py), up
to half a sample before or after it. Soft-bow models do not mind (soft-range at 65-880 Hz: within 0.015 dB of the
whole-window render, either way), but a stick-slip model's map has kinks at the stick capture and the slip, and the
handover that wanders around T throws it out of its cycle: `paper-fb1000` at 220-880 Hz left its trained states (p
peaks at 1.6 against the truth's 0.26; the box check refused it) and `scratch-g2` at 440 and 880 Hz did the same.
Computed at the rate where a window holds N = ceil(T / dtau) samples (at most 1 / N faster than asked) and resampled
to the asked rate, both play every pitch tried, 65-880 Hz, within 0.01 dB (harmonics) and 0.05 cents of a x100 FDM
(docs/BENCHMARKS.md, "Stick-slip at any pitch").

The resampler is a polyphase filter, a Kaiser-windowed sinc of beta 12 (measured with scipy's resample_poly of the
same design: within 3e-6 of a sine up to 10 kHz at the ratios these grids need, where its default beta 5 is 1.5e-3
off); the ratio of the rates is rounded to a fraction of denominator at most MAX_DENOMINATOR, which moves the pitch
by as much as it is off. A window just short of a whole number N of samples makes the ratio nearly N' / N, whose
nearest such fractions lie up to 1/2000 away (0.4 cents, and the filter came up short of samples: paper-fb1000 at
832.3 Hz, 52.985 samples a window, failed to render); so the grid takes the window of N to N + GRID_TRIES samples whose
ratio a fraction holds best: within 1e-6 (0.002 cents) but where the window is within ~1e-4 of a sample of whole,
and there within 1e-5 (0.02 cents).
"""

from __future__ import annotations

import copy
import math
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from ... import physics
from ...scene import Scene
from ... import compiled as core

if TYPE_CHECKING:
    from fractions import Fraction

MAX_DENOMINATOR = 2000
KAISER_BETA = 12.0
HALF_TAPS = 10  # the filter's half length in input samples (scipy's choice): output samples it reaches past an edge
PAD = HALF_TAPS + 2  # output samples rendered past the end, and given up before a failure, for that reach
RATIO_TOL = 1e-6  # a resampling fraction this close (relative) is taken at once: the pitch it moves (0.002 cents)
GRID_TRIES = 8  # windows of N .. N + GRID_TRIES samples are tried for the fraction


def needs_whole_windows(domain, beta_max: float | None = None) -> bool:
    """Does a model play stick-slip (the friction's stiffness at its largest F_B / w at or above physics.STIFF, the
    soft/stick-slip boundary its training uses too)? Those voices are computed on whole windows. beta_max: the largest
    F_B / w a voice bows (a range model's box can reach just past the boundary: the soft bows below it keep the
    output grid's windows, on which the soft models were measured); None: the model's largest."""
    top = domain.box[1] if domain.is_range else domain.beta
    beta = top if beta_max is None else min(float(beta_max), top)
    return physics.stiffness(beta, domain.a) >= physics.STIFF


def whole_window_scene(scene: Scene, spw: float) -> tuple[Scene, Fraction | int]:
    """The scene on the grid where a window of spw samples (at the scene's rate) holds a whole number N of them, with
    PAD output samples more at its end, and the ratio (output rate / grid rate) that brings it back. A window that is
    already a whole number of samples (up to 1e-7) gives the scene itself and ratio 1.

    The grid's rate is not a whole number of Hz, which a Scene built by a user may not have: this copy is for the
    engine's loops (which read sample_rate, n_samples, dtau and the curves) and is never rebuilt or validated."""
    n0 = math.ceil(spw * (1 - 1e-7))
    if abs(n0 - spw) <= 1e-7 * spw:
        return scene, 1
    from fractions import Fraction  # here, not at import: 2.4 ms of every render's process, most of which need none
    best = None  # (error, n, ratio): the whole window whose rate ratio a fraction holds best (the module's docstring)
    for n in range(n0, n0 + GRID_TRIES + 1):
        ratio = Fraction(spw / n).limit_denominator(MAX_DENOMINATOR)
        err = abs(float(ratio) * n / spw - 1)
        if best is None or err < best[0]:
            best = (err, n, ratio)
        if err <= RATIO_TOL:
            break
    _, n, ratio = best
    rate = scene.sample_rate * n / spw
    inner = copy.copy(scene)
    # the filter reads the grid at the fraction's rate: enough samples for that, whatever its small error
    n_inner = max(math.ceil((scene.n_samples + PAD) * n / spw), math.ceil((scene.n_samples + PAD) / float(ratio)))
    object.__setattr__(inner, "sample_rate", rate)
    object.__setattr__(inner, "duration", n_inner / rate)
    return inner, ratio


@lru_cache(maxsize=64)
def _phases(up: int, down: int) -> tuple[np.ndarray, int]:
    """The polyphase filter: per phase r = (j down) mod up of an output sample j, the weights (up, K) of the input
    samples floor(j down / up) - K0 + k, k < K, each phase normalised to unit gain at DC; and K0. The filter is a
    Kaiser-windowed sinc at the upsampled rate, cut at the lower Nyquist frequency, HALF_TAPS input samples each side
    (scipy.signal.firwin's design: scipy.signal itself costs ~0.9 s to import, more than a whole render)."""
    m = max(up, down)
    half = HALF_TAPS * m  # in samples of the upsampled rate
    k0 = half // up + 1
    t = np.arange(up)[:, None] - (np.arange(2 * k0 + 1) - k0)[None, :] * up  # (up, K) offsets at the upsampled rate
    inside = np.abs(t) <= half
    w = np.sinc(t / m) * np.i0(KAISER_BETA * np.sqrt(np.clip(1 - (t / half) ** 2, 0, None))) * inside
    return w / w.sum(axis=1, keepdims=True), k0


def to_output(x, ratio: Fraction, n: int) -> np.ndarray:
    """Rows of samples on a grid (an array (R, n_grid), or a list of R rows) resampled by `ratio` (output rate / grid
    rate) to their first n output samples, float32 (the network's precision). NaN (a stopped voice) is held at the
    last finite sample first, so it does not spread back through the filter; the caller marks that stretch again
    (from_grid). A list's rows are read where they lie (a render's q and p: no stacked copy)."""
    rows = [np.asarray(r) for r in x] if isinstance(x, (list, tuple)) else list(np.atleast_2d(np.asarray(x)))
    if ratio == 1:
        return np.ascontiguousarray(np.stack([r[:n] for r in rows]), dtype=np.float32)
    up, down = ratio.numerator, ratio.denominator
    w, k0 = _phases(up, down)
    y = np.empty((len(rows), n), np.float32)
    # with an odd continuation at both ends (a note that starts from a moving state is not cut to zero before it),
    # in one compiled pass per row (the grid's samples are the network's float32)
    for i, r in enumerate(rows):
        core.resample_rows(np.ascontiguousarray(r, dtype=np.float32)[None], w, k0, up, down, y[i:i + 1])
    return y


def to_output_in_place(rows: list[np.ndarray], ratio: Fraction, n: int) -> list[np.ndarray]:
    """to_output's samples written over the grid's own rows (float32, contiguous, writable, ratio <= 1: a grid is
    never coarser than the output), returned as each row's first n: a render's output needs no fresh array, whose
    first touch cost ~0.8 ms of a 5 s stick-slip render at 100 Hz that now takes ~5. The rows' grid samples are
    gone after it."""
    if ratio == 1:
        return [r[:n] for r in rows]
    up, down = ratio.numerator, ratio.denominator
    w, k0 = _phases(up, down)
    for r in rows:
        if r.dtype != np.float32 or not r.flags.c_contiguous or not r.flags.writeable:
            raise ValueError("to_output_in_place: rows must be writable contiguous float32")
        core.resample_rows(r[None], w, k0, up, down, r[None, :n])
    return [r[:n] for r in rows]


def from_grid(i: int, ratio: Fraction) -> int:
    """The output sample from which a voice that stopped at grid sample i is no longer its own render (the filter
    reaches PAD samples back from the first lost one); i < 0 (no stop) stays."""
    if i < 0 or ratio == 1:
        return i
    return max(int(math.floor(i * ratio)) - PAD, 0)


def to_grid(n: int, ratio: Fraction, n_grid: int) -> np.ndarray:
    """For each of n output samples, the grid sample at or before it (for per-sample controls)."""
    return np.minimum(np.floor(np.arange(n) / float(ratio)).astype(np.int64), n_grid - 1)
