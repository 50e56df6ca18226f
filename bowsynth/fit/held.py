"""Fit a held note: the search (coarse grid, zoom, gradient descent from the best starts), how well the sound
determines each part of the bow, and the fitted note rendered as `render` plays it, measured against the target.

How well the sound determines the bow: a bow whose loss lies within twice the best's (plus NOISE) may be the one that
made the sound. The operator's own error at the true bow is at least the best loss (the truth's bow, played by the
operator, is one of the bows the best beat), so a bow that far from the target is as near as the truth's could be. Around the best, the bow
is moved along F_B / w, v_B and both diagonals by 1-32 % (PROBES); the farthest move in each part that stays within
SLACK, and every bow the search played within it, give the spread the sound leaves open. A part is identifiable
where that spread is within its tolerance (2 % of F_B / w, 1 % of v_B). Bows within SLACK but far from the best are
reported too: they sound alike.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from .. import physics
from ..errors import Terminated
from .search import COARSE_SECONDS, STARTS, Candidate, Scorer, coarse, descend, distinct_starts, zoom
from .target import FitMiss, Target, dc_edge

SLACK = 1.0  # a bow within (1 + SLACK) x the best loss, plus NOISE, may be the one that made the sound
# how much the loss moves between bows 1 % apart where the sound does not change (measured around held notes at 220
# and 440 Hz: 0.001-0.02, from the window geometry and the onset's sample grid moving with f0): a best that lies
# this far under its neighbours is luck, not a better bow
NOISE = 0.01
TOLERANCE = {"beta": 0.02, "vb": 0.01}  # relative: F_B / w within 2 %, v_B within 1 %
PROBES = (0.01, 0.02, 0.04, 0.08, 0.16, 0.32)  # relative moves of the bow around the best
MISS_LOSS = 0.25  # a best loss above this is not a note of this instrument (noise, speech, a chord: 0.5-1.5)


@dataclass
class Fit:
    """A fitted held note: the bow and f0, the loss, what the sound leaves open, and the work done."""

    best: Candidate
    spread: dict  # per part: (lo, hi) of the bows within SLACK
    alike: list  # other bows (Candidates) within SLACK but outside the tolerance: they sound alike
    evaluations: int
    seconds: float
    interrupted: bool = False
    checked: dict = field(default_factory=dict)  # the render's note against the target (check())
    seen: list = field(default_factory=list)  # every bow the search scored at the whole target (the report's map)

    @property
    def fb(self) -> float:
        return self.best.beta * physics.omega(self.best.f0)

    def relative_spread(self, part: str) -> float:
        lo, hi = self.spread[part]
        value = getattr(self.best, part)
        return max(value - lo, hi - value) / value

    def identifiable(self, part: str) -> bool:
        return self.relative_spread(part) <= TOLERANCE[part]

    @property
    def is_match(self) -> bool:
        return self.best.loss <= MISS_LOSS


def within(best: Candidate) -> float:
    """The loss under which a bow sounds as near the target as the best."""
    return best.loss * (1 + SLACK) + NOISE


def _spread(cands: list[Candidate], best: Candidate) -> tuple[dict, list]:
    near = [c for c in cands if c.loss <= within(best)]
    spread = {p: (min(getattr(c, p) for c in near), max(getattr(c, p) for c in near)) for p in ("beta", "vb")}
    far = [c for c in near if abs(c.beta / best.beta - 1) > 4 * TOLERANCE["beta"]
           or abs(c.vb / best.vb - 1) > 4 * TOLERANCE["vb"]]
    alike: list[Candidate] = []
    for c in sorted(far, key=lambda c: c.loss):  # one per region
        if all(abs(math.log(c.beta / o.beta)) > 0.1 or abs(c.vb / o.vb - 1) > 0.05 for o in alike):
            alike.append(c)
    return spread, alike[:3]


def probe(scorer: Scorer, best: Candidate) -> list[Candidate]:
    """The bow moved from the best along F_B / w, v_B and both diagonals, each way, by PROBES (relative), until the
    loss leaves SLACK of the best; at the best's f0 and windows."""
    out = []
    for db, dv in ((1, 0), (0, 1), (1, 1), (1, -1)):
        for sign in (1, -1):
            for step in PROBES:
                c = scorer.score(best.beta * (1 + sign * db * step), best.vb * (1 + sign * dv * step), best.f0,
                                 best.locked)
                if c is None:
                    break
                out.append(c)
                if c.loss > within(best):
                    break
    return out


def fit_held(target: Target, models=None, starts: int = STARTS, progress=None, budget: float = math.inf) -> Fit:
    """Fit a held bow to the target. progress(stage, done, total) is called as the search goes; Ctrl-C (or SIGTERM)
    stops it with the best fit so far (Fit.interrupted). budget: seconds after which the descent stops."""
    t0 = time.monotonic()
    deadline = t0 + budget
    quick = Scorer(target, models, seconds=COARSE_SECONDS)
    full = Scorer(target, models)
    seen: list[Candidate] = []
    best = None
    interrupted = False
    say = progress or (lambda *a: None)
    try:
        say("coarse", 0, 1)
        grid = coarse(quick)
        if not grid:
            raise FitMiss(f"no model plays a held note at {target.pitch:.4g} Hz at this rate: {target.path or 'the target'} "
                          f"is not a note the operator can match (its pitch is too high, or too low, for the shipped "
                          f"models' f0 at {target.sample_rate} Hz)")
        picks = distinct_starts(grid, starts)
        for i, s in enumerate(picks):
            say("zoom", i, len(picks))
            around = full.score(s.beta, s.vb, locked=s.locked)
            near = zoom(full, s) + ([around] if around else [])
            seen += near
            if near:
                best = min([best, *near], key=lambda c: c.loss) if best else min(near, key=lambda c: c.loss)
        if best is None:
            best = grid[0]
        tops = distinct_starts(sorted(seen, key=lambda c: c.loss), starts, apart=0.1)
        for i, s in enumerate(tops):
            say("descent", i, len(tops))
            trace: list = []
            d = descend(full, s, deadline=deadline, trace=trace)
            seen += [Candidate(b, v, f, loss, s.model, s.locked) for b, v, f, loss in trace]
            # the descent moves the bow at its start's f0; the note is written at the f0 that puts the bow's pitch
            # (the map's) at the target's, so the bow is scored again there (its locked windows held the pitch at
            # the old f0 whatever the bow: at 422 Hz a bow 3 % off the start's wrote an f0 3.6 cents sharp)
            d = full.score(d.beta, d.vb, locked=d.locked) or d
            if d.loss < best.loss:
                best = d
        say("probe", 0, 1)
        seen += probe(full, best)
    except (KeyboardInterrupt, Terminated):
        interrupted = True
        if best is None:
            raise
    seen.append(best)
    spread, alike = _spread(seen, best)
    return Fit(best, spread, alike, quick.evaluations + full.evaluations, time.monotonic() - t0, interrupted,
               seen=seen)


def play_windows(best) -> str:
    """The windows the fitted note plays in (render's and score's --windows): locked to the target's period, which
    the f0 the fit writes puts at the physics' ('physics'), or the trained ones ('free')."""
    return "physics" if best.locked else "free"


def check(fit: Fit, target: Target, render) -> dict:
    """The fitted note played by `render` (api.render) as its score says to play it (the model the fit played, in its
    windows: `play_windows`) against the target, as a listener hears it (metrics.listener_errors over the note's
    second half, its last 0.2 s left out): harmonics 2-10 (median |dB| of those the target sounds), pitch (cents),
    onset (ms), and the loss. The renderer's own pick can be another model that covers the bow and sounds otherwise
    (at 422 Hz, F_B / w 0.70, v_B 0.245: 3.5 cents and 1.9 dB from the target, where the fit's model plays it)."""
    from ..engines.operator.choose import as_model
    from ..errors import ModelFileError
    from ..metrics import listener_errors
    from ..io.audio import remove_dc
    from .surrogate import note_scene

    b = fit.best
    sc = note_scene(b.f0, b.beta, b.vb, target.n / target.sample_rate, target.sample_rate)
    try:
        model = as_model(b.model) if b.model else None
    except ModelFileError:  # a model given in memory, never saved: the renderer's pick plays
        model = None
    r = render(sc, model=model, windows=play_windows(b))
    q, y = np.asarray(r.q, float), target.x
    x = remove_dc(q, target.sample_rate)  # the whole note: the filter run backwards starts up in its last 0.2 s
    n = min(len(x), len(y)) - dc_edge(len(y), target.sample_rate)
    e = listener_errors(x[:n], y[:n], target.sample_rate,
                        steady_seconds=(n - len(y) // 2) / target.sample_rate)
    return {"harmonics_db": e["harm_db_median"], "pitch_cents": e["cents"], "onset_ms": e["onset_err_ms"],
            "loss": Scorer(target).loss.value(q), "played": str(r.method),
            "model": getattr(r.info, "model_id", "")}
