"""Playing ranges: a box of bow parameters (beta = F_B / w and v_B, at one friction shape a) that one range model
covers, and the parameter points its training data comes from.

A render visits a thin band of states for each bow; a piece visits a region of bows. The data for a range comes from
renders from rest at parameter points spread over the box (Latin hypercube, beta on a log scale: the dynamics change
by factors of beta, not by steps), so the band of each point is covered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import physics
from ..errors import UsageError


def parse_range(text: str, name: str) -> tuple[float, float]:
    """A CLI value `lo:hi` (a range) or `x` (a point, lo = hi)."""
    parts = str(text).split(":")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise UsageError(f"--{name} must be a number or a range lo:hi, got {text!r}") from None
    if len(vals) not in (1, 2) or not all(math.isfinite(v) for v in vals):
        raise UsageError(f"--{name} must be a finite number or a range lo:hi, got {text!r}")
    lo, hi = vals[0], vals[-1]
    if hi < lo:
        raise UsageError(f"--{name} range {text!r} is inverted: write it low:high")
    return lo, hi


@dataclass(frozen=True)
class ParamBox:
    """beta in [beta_lo, beta_hi], v_B in [vb_lo, vb_hi], at friction shape a. A point model is a box of zero width."""

    beta_lo: float
    beta_hi: float
    vb_lo: float
    vb_hi: float
    a: float

    def __post_init__(self):
        for lo, hi, name in ((self.beta_lo, self.beta_hi, "F_B / w"), (self.vb_lo, self.vb_hi, "v_B")):
            if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
                raise UsageError(f"{name} range [{lo:g}, {hi:g}] is empty or not finite")
        if not self.beta_lo >= 0:
            raise UsageError(f"F_B / w must be >= 0, got {self.beta_lo:g}")

    @classmethod
    def from_forces(cls, fb: tuple[float, float], vb: tuple[float, float], f0: float, a: float) -> "ParamBox":
        return cls(physics.beta(fb[0], f0), physics.beta(fb[1], f0), vb[0], vb[1], a)

    @property
    def is_point(self) -> bool:
        return self.beta_lo == self.beta_hi and self.vb_lo == self.vb_hi

    def contains(self, beta, vb) -> np.ndarray:
        """Elementwise: is the bow inside the box (the same test as a model file's, model.within)?"""
        from ..engines.operator.domain import within

        return within(beta, self.beta_lo, self.beta_hi) & within(vb, self.vb_lo, self.vb_hi)

    def normalise(self, beta, vb) -> np.ndarray:
        """(beta, v_B) -> [-1, 1]^2 over the box (log beta); a zero-width side maps to 0. (N, 2)."""
        lb = np.log(np.maximum(np.asarray(beta, float), 1e-12))
        lo, hi = math.log(max(self.beta_lo, 1e-12)), math.log(max(self.beta_hi, 1e-12))
        nb = np.zeros_like(lb) if hi == lo else 2 * (lb - lo) / (hi - lo) - 1
        vb = np.asarray(vb, float)
        nv = np.zeros_like(vb) if self.vb_hi == self.vb_lo else 2 * (vb - self.vb_lo) / (self.vb_hi - self.vb_lo) - 1
        return np.stack(np.broadcast_arrays(nb, nv), axis=-1)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n parameter points (beta, v_B), a Latin hypercube over (log beta, v_B)."""
        u = (np.stack([rng.permutation(n), rng.permutation(n)], axis=1) + rng.random((n, 2))) / n
        lo, hi = math.log(max(self.beta_lo, 1e-12)), math.log(max(self.beta_hi, 1e-12))
        beta = np.exp(lo + u[:, 0] * (hi - lo)) if self.beta_hi > 0 else np.zeros(n)
        return np.stack([beta, self.vb_lo + u[:, 1] * (self.vb_hi - self.vb_lo)], axis=1)

    def grid(self, n: int) -> np.ndarray:
        """An n x n grid of points inside the box (cell centres, log beta): held-out points for evaluation."""
        f = (np.arange(n) + 0.5) / n
        lo, hi = math.log(max(self.beta_lo, 1e-12)), math.log(max(self.beta_hi, 1e-12))
        bb, vv = np.meshgrid(np.exp(lo + f * (hi - lo)), self.vb_lo + f * (self.vb_hi - self.vb_lo), indexing="ij")
        return np.stack([bb.ravel(), vv.ravel()], axis=1)

    def to_json(self) -> dict:
        return {"beta": [self.beta_lo, self.beta_hi], "vb": [self.vb_lo, self.vb_hi], "a": self.a}

    def describe(self) -> str:
        return (f"F_B / w {self.beta_lo:.4g}..{self.beta_hi:.4g}, v_B {self.vb_lo:g}..{self.vb_hi:g}, "
                f"a {self.a:g}")


def distinct(pts: np.ndarray) -> np.ndarray:
    """The rows of pts without repeats, in their order (a box with a side of zero width repeats its points)."""
    if not len(pts):
        return pts
    _, first = np.unique(pts, axis=0, return_index=True)
    return pts[np.sort(first)]


def speaks(beta, vb, a: float, f0: float = 100.0, seconds: float = 1.0) -> np.ndarray:
    """Does a note from rest speak within `seconds`? Small oscillations about the rest state grow as exp(rate tau)
    from the rest state's offset beta phi(v_B); once they reach a tenth of v_B the friction's nonlinearity takes them
    to the limit cycle within a few periods (checked against the FDM at f0 100: beta 0.4 / v_B 0.3 speaks,
    beta 0.3 / v_B 0.3 is still growing at 1 s, v_B 0.35 stays silent at beta 0.75; tests/test_ranges.py)."""
    beta, vb = np.asarray(beta, float), np.asarray(vb, float)
    rate = physics.onset_rate(beta, vb, a)
    need = physics.growth_tau(rate, np.abs(beta * physics.phi(vb, a)), np.maximum(0.1 * vb, 1e-12))
    return (rate > 0) & (need <= physics.omega(f0) * seconds)


@dataclass
class RangeBand:
    """States renders visit inside a box, each with the bow (beta, v_B) it was visited under."""

    states: np.ndarray  # (N, 2) q, p
    params: np.ndarray  # (N, 2) beta, v_B
    weights: np.ndarray  # (N,) sampling weight: each point's own onset as likely as its limit cycle
    starts: np.ndarray  # (S, 4) q, p, beta, v_B where renders from rest start their windows
    # (R, 6) per render at a held bow: beta, v_B, q_lo, q_hi, p_lo, p_hi over its second half (the limit cycle)
    extents: np.ndarray | None = None


def _balanced(states: np.ndarray, grid: int = 64) -> np.ndarray:
    """Weights 1 / (states in the same cell of a grid over their own box): a render passes its onset once and
    then circles its limit cycle, and uniform sampling in time would leave the onset untrained."""
    lo, hi = states.min(0), states.max(0)
    cell = np.floor((states - lo) / np.maximum(hi - lo, 1e-9) * (grid - 1e-9)).astype(int)
    key = cell[:, 0] * grid + cell[:, 1]
    counts = np.bincount(key, minlength=grid * grid)
    w = 1.0 / counts[key]
    return w / w.sum()


def stop_runs(box: ParamBox, n: int, seconds: float, rng: np.random.Generator) -> list:
    """n bow stops inside the box: a bow that speaks (v_B from max(0.1, the box's bottom) up) held for 40-70 % of
    `seconds`, then v_B falling linearly to the box's bottom over 20-200 ms (a score's release is 50 ms), held there:
    the states a note passes through as it dies, which renders from rest never visit (a bow below vb_stop from rest
    stays silent). Each run is ((beta, beta), vb curve)."""
    if n <= 0:
        return []
    lo = max(box.vb_lo, min(0.1, box.vb_hi))
    pts = box.sample(n, rng)
    v = lo + (pts[:, 1] - box.vb_lo) / max(box.vb_hi - box.vb_lo, 1e-12) * (box.vb_hi - lo)
    hold = rng.uniform(0.4, 0.7, n) * seconds
    fall = rng.uniform(0.02, 0.2, n)
    return [((float(b), float(b)), [(0.0, float(vv)), (float(h), float(vv)), (float(h + f), box.vb_lo)])
            for b, vv, h, f in zip(pts[:, 0], v, hold, fall)]


def range_band(box: ParamBox, points: np.ndarray, f0: float, sample_rate: int, seconds: float, window: float,
               gestures: int = 0, rng: np.random.Generator | None = None, stride: int = 1,
               stops: int = 0) -> RangeBand:
    """Audio-rate FDM renders from rest at each parameter point, plus `gestures` renders whose bow moves in a
    straight line between two random points of the box over `seconds` (the states a crescendo or a bow change
    visits), plus `stops` bow stops (stop_runs). Every run gets the same total sampling weight. stride: keep every
    stride-th state (neighbouring samples are nearly the same state; the window starts are kept whatever the
    stride)."""
    from ..engines.fdm import render_fdm
    from ..scene import Scene

    w = physics.omega(f0)
    states, params, weights, starts = [], [], [], []
    per_window = max(1, int(window / physics.dtau(f0, sample_rate) + 1e-9))
    runs = [((b, b), (v, v)) for b, v in points]
    if gestures:
        rng = rng or np.random.default_rng(0)
        ends = box.sample(2 * gestures, rng)
        runs += [((ends[i, 0], ends[gestures + i, 0]), (ends[i, 1], ends[gestures + i, 1])) for i in range(gestures)]
    if stops:
        runs += stop_runs(box, stops, seconds, rng or np.random.default_rng(0))
    extents = []
    for (b0, b1), vrun in runs:
        fb = b0 * w if b0 == b1 else [(0.0, b0 * w), (seconds, b1 * w)]
        if isinstance(vrun, list):  # a stop: its own curve
            vb, (v0, v1) = vrun, (vrun[0][1], vrun[-1][1])
        else:
            v0, v1 = vrun
            vb = v0 if v0 == v1 else [(0.0, v0), (seconds, v1)]
        r = render_fdm(Scene(f0=f0, fb=fb, vb=vb, a=box.a, duration=seconds, sample_rate=sample_rate))
        x = np.stack([r.q, r.p], axis=1)
        par = np.stack([r.controls["fb"] / w, r.controls["vb"]], axis=1)
        starts.append(np.hstack([x, par])[::per_window])
        if b0 == b1 and v0 == v1:
            tail = x[len(x) // 2:]
            extents.append([b0, v0, *tail.min(0)[[0]], *tail.max(0)[[0]], *tail.min(0)[[1]], *tail.max(0)[[1]]])
        x, par = x[::stride], par[::stride]
        states.append(x)
        params.append(par)
        weights.append(_balanced(x))
    wts = np.concatenate(weights)
    return RangeBand(np.concatenate(states), np.concatenate(params), wts / wts.sum(), np.concatenate(starts),
                     np.array(extents).reshape(-1, 6))


def fit_bow_scaling(extents: np.ndarray, pin: np.ndarray, margin: float):
    """A bow-scaled model's state scaling (npnet.state_scaling) fitted to the limit cycles of renders at held bows:
    least squares of each variable's centre and log half-range, affine in the bows' branch inputs pin (R, n_par).
    Renders that have not spoken (p's half-range below a tenth of v_B: still near rest, see speaks) say nothing about
    the playing amplitude and are left out. Returns center (2,), halfrange (2,) (times 1 + margin: the band's jitter),
    center_slope and halfrange_slope (2, n_par); None when fewer than n_par + 2 renders spoke."""
    ext = np.asarray(extents, float)
    mid = np.stack([ext[:, 2] + ext[:, 3], ext[:, 4] + ext[:, 5]], 1) / 2
    half = np.stack([ext[:, 3] - ext[:, 2], ext[:, 5] - ext[:, 4]], 1) / 2
    spoke = half[:, 1] >= 0.1 * np.abs(ext[:, 1])
    n_par = pin.shape[1]
    if spoke.sum() < n_par + 2:
        return None
    A = np.hstack([np.ones((int(spoke.sum()), 1)), np.asarray(pin, float)[spoke]])
    cm = np.linalg.lstsq(A, mid[spoke], rcond=None)[0]  # (1 + n_par, 2)
    ch = np.linalg.lstsq(A, np.log(half[spoke]), rcond=None)[0]
    return cm[0], np.exp(ch[0]) * (1 + margin), cm[1:].T, ch[1:].T
