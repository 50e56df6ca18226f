"""Fit a gesture: the bow as breakpoint curves (F_B / w and v_B every STEP s), from the frame-by-frame start
(frames.py) or the held fit, by gradient descent through the operator, smooth unless the sound says otherwise; how
well the sound determines each breakpoint.

f0 starts at the start's and follows the note's pitch track to the target's (the median of their 100 ms frames'
difference; a string's tuning does not move with the bow, the pitch moves with r(bow(t)) as in the physics). The
curves play in free windows with the model whose box holds most of the start's breakpoints, inside that box: the surrogate rolls one
model, so a gesture that crosses from one model's box into another's (a render chains the two) is fitted up to the
box's edge, and the fit says so (CurveFit.at_edge). Smoothness: SMOOTH times the curves' squared second differences in u (ln F_B / w, v_B / VB_UNIT) joins the
loss, so a breakpoint moves away from its neighbours only where the sound pays for it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..engines.operator.choose import covering_model
from ..errors import BowsynthError, Terminated
from .held import NOISE, TOLERANCE, Fit
from .search import BETA_RANGE, VB_RANGE, VB_UNIT, Scorer
from .surrogate import Note, NoteFailed, note_scene
from .target import Target

STEP = 0.1  # s between breakpoints
STEPS = 40  # gradient steps
LR = (0.06, 0.004)  # Adam's step in u, first and last (cosine between)
SMOOTH = 0.002  # the squared second differences' weight
PROBE = (0.05, 0.05)  # relative moves of one breakpoint (F_B / w, v_B) that measure how the loss bends there


@dataclass
class CurveFit:
    """Fitted curves: breakpoint times (s), F_B / w and v_B there, f0, the loss, and per breakpoint the relative
    change of each part that the sound leaves open (spread, (K, 2))."""

    times: np.ndarray
    beta: np.ndarray
    vb: np.ndarray
    f0: float
    loss: float
    model: str
    spread: np.ndarray = None
    at_edge: bool = False  # the curves end at the box of the one model the surrogate rolls
    evaluations: int = 0
    seconds: float = 0.0
    interrupted: bool = False
    checked: dict = field(default_factory=dict)

    def identifiable(self) -> np.ndarray:
        """(K, 2) bool: is each breakpoint's F_B / w (within 2 %) and v_B (within 1 %) determined by the sound?"""
        return self.spread <= np.array([TOLERANCE["beta"], TOLERANCE["vb"]])

    def scene(self, seconds: float, sample_rate: int):
        return note_scene(self.f0, self.beta, self.vb, seconds, sample_rate, times=self.times)


def breakpoint_times(seconds: float, step: float = STEP) -> np.ndarray:
    """Breakpoints every `step` s from 0 to the end of the span listened to (the last one at its end)."""
    k = max(1, int(round(seconds / step)))
    return np.linspace(0.0, seconds, k + 1)


def _bow(u):
    import torch

    return torch.stack([u[:, 0].exp(), u[:, 1] * VB_UNIT], dim=1)


FRAME = 0.1  # s: the pitch track's frames


def pitch_offset(x: np.ndarray, y: np.ndarray, rate: float) -> float:
    """The median over 100 ms frames of x's pitch against y's (cents, signed; NaN where no frame is pitched)."""
    from ..metrics import cents, f0_estimate

    n = int(FRAME * rate)
    c = [cents(f0_estimate(x[a:a + n], rate, tail=1.0), f0_estimate(y[a:a + n], rate, tail=1.0))
         for a in range(n, min(len(x), len(y)) - n + 1, n)]
    c = np.asarray(c, float)
    return float(np.median(c[np.isfinite(c)])) if np.isfinite(c).any() else float("nan")


def _roughness(u):
    d2 = u[2:] - 2 * u[1:-1] + u[:-2]
    return d2.square().sum()


def _model_for(scorer: Scorer, f0: float, times, beta, vb, n: int, rate: int):
    """The model whose box holds most of the curve's breakpoints (the smaller box of two that hold as many; a box
    that holds them all is one that covers the whole curve)."""
    held = [m for m in scorer.models if m.domain.is_range]
    if not held:
        return None
    count = lambda m: int(np.sum(m.domain.box_contains(np.asarray(beta), np.asarray(vb))))  # noqa: E731
    return max(held, key=lambda m: (count(m), -m.domain.bow_extent))


def fit_curves(target: Target, held: Fit, models=None, step: float = STEP, steps: int = STEPS, progress=None,
               budget: float = math.inf, frames=None) -> CurveFit:
    """Curves by Adam through the operator from the held fit's bow, or from `frames` (frames.frame_bows: times,
    F_B / w, v_B and f0 frame by frame); Ctrl-C stops with the best curves so far."""
    import torch

    t0 = time.monotonic()
    scorer = Scorer(target, models)
    n, rate = scorer.n, target.sample_rate
    times = breakpoint_times(n / rate, step)
    K = len(times)
    b = held.best
    if frames is None:
        f0, init = b.f0, np.tile(b.u, (K, 1))
    else:
        ft, fbeta, fvb, f0 = frames
        init = np.stack([np.interp(times, ft, np.log(fbeta)), np.interp(times, ft, fvb) / VB_UNIT], axis=1)
    model = _model_for(scorer, f0, times, np.exp(init[:, 0]), init[:, 1] * VB_UNIT, n, rate)
    if model is None:
        raise BowsynthError("no model plays the fit's start as curves at this pitch")
    bl, bh, vl, vh = model.domain.box
    lo = torch.tensor([math.log(max(bl, BETA_RANGE[0])), vl / VB_UNIT], dtype=torch.float64)
    hi = torch.tensor([math.log(min(bh, BETA_RANGE[1])), min(vh, VB_RANGE[1]) / VB_UNIT], dtype=torch.float64)
    u = torch.maximum(torch.minimum(torch.tensor(init, dtype=torch.float64), hi), lo).requires_grad_(True)
    opt = torch.optim.Adam([u], lr=LR[0])
    best = None
    interrupted = False
    say = progress or (lambda *a: None)
    bl, bh, vl, vh = model.domain.box
    lo = torch.tensor([math.log(max(bl, BETA_RANGE[0])), vl / VB_UNIT])
    hi = torch.tensor([math.log(min(bh, BETA_RANGE[1])), min(vh, VB_RANGE[1]) / VB_UNIT])
    try:
        for i in range(steps):
            if time.monotonic() - t0 > budget:
                break
            say("curves", i, steps)
            lr = LR[1] + 0.5 * (LR[0] - LR[1]) * (1 + math.cos(math.pi * i / max(1, steps - 1)))
            for g in opt.param_groups:
                g["lr"] = lr
            bows = _bow(u.detach()).numpy()
            note = Note(model, f0, rate, n, times=times)
            try:
                q = note(_bow(u))
            except (NoteFailed, BowsynthError):
                break
            scorer.evaluations += 1
            parts = scorer.loss.parts(q)
            sound = parts["spectral"] + parts["onset"]
            if best is None or float(sound.detach()) < best.loss:
                edge = bool(torch.any(u.detach() <= lo + 1e-9) or torch.any(u.detach() >= hi - 1e-9))
                best = CurveFit(times, bows[:, 0].copy(), bows[:, 1].copy(), f0, float(sound.detach()),
                                model.meta.name, at_edge=edge)
            opt.zero_grad()
            (sound + SMOOTH * _roughness(u)).backward()
            if not torch.all(torch.isfinite(u.grad)):
                break
            opt.step()
            with torch.no_grad():
                u.copy_(torch.maximum(torch.minimum(u, hi), lo))
            off = pitch_offset(q.detach().double().numpy(), scorer.target.x[:n], rate)
            if math.isfinite(off):  # f0 follows the pitch track to the target's
                f0 *= 2 ** (-off / 1200)
        say("probe", 0, 1)
        if best is not None:
            best.spread = probe(scorer, best)
    except (KeyboardInterrupt, Terminated):
        interrupted = True
    if best is None:
        raise BowsynthError("no model plays the held fit's bow as curves at this pitch")
    if best.spread is None:
        best.spread = np.full((K, 2), np.inf)
    best.evaluations, best.seconds, best.interrupted = scorer.evaluations, time.monotonic() - t0, interrupted
    return best


def probe(scorer: Scorer, fit: CurveFit) -> np.ndarray:
    """(K, 2): per breakpoint and part, the relative change that raises the loss by NOISE, from the loss's bend
    under a move of PROBE either way (inf where the loss does not bend: the sound does not determine it)."""
    rate, n = scorer.target.sample_rate, scorer.n

    def loss(beta, vb):
        sc = note_scene(fit.f0, beta, vb, n / rate, rate, times=fit.times)
        m = covering_model(sc, scorer.models)
        if m is None:  # past the box: the loss there is not the surrogate's
            return math.inf
        try:
            q = Note(m, fit.f0, rate, n, times=fit.times).play(np.stack([beta, vb], axis=1))
        except (NoteFailed, BowsynthError):
            return math.inf
        scorer.evaluations += 1
        return scorer.loss.sound(q)

    base = loss(fit.beta, fit.vb)
    out = np.full((len(fit.times), 2), np.inf)
    for k in range(len(fit.times)):
        for j, (arr, h) in enumerate(((fit.beta, PROBE[0]), (fit.vb, PROBE[1]))):
            up, down = arr.copy(), arr.copy()
            up[k] *= 1 + h
            down[k] *= 1 - h
            lu = loss(up, fit.vb) if j == 0 else loss(fit.beta, up)
            ld = loss(down, fit.vb) if j == 0 else loss(fit.beta, down)
            bend = (lu + ld - 2 * base) / (h * h)
            if math.isfinite(bend) and bend > 0:
                out[k, j] = math.sqrt(2 * NOISE / bend)
    return out


def check(fit: CurveFit, target: Target, render) -> dict:
    """The fitted curves played by `render` (api.render) against the target, per 100 ms frame (frame_errors: median
    harmonic dB and |cents| over frames), both at unit RMS."""
    from ..metrics import frame_errors
    from ..io.audio import remove_dc

    r = render(fit.scene(target.n / target.sample_rate, target.sample_rate))
    x = remove_dc(np.asarray(r.q, float), target.sample_rate)
    fe = frame_errors(x / np.std(x), target.x / np.std(target.x), target.sample_rate)
    return {"harmonics_db": fe["harm_db_median"], "harmonics_db_worst": fe["harm_db_worst_frame"],
            "pitch_cents": fe["cents_median"], "frames": fe["frames"], "played": str(r.method)}
