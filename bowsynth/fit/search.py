"""The bow that made a held note: a coarse search over the playing space with the compiled operator, then gradient
descent through the operator's rollout (surrogate.Note) from the best few starts.

Every candidate bow (F_B / w, v_B) is played at f0 = pitch / r(bow), r the physics' sounding ratio from the shipped
map (music/ratio_map.py), so that it sounds at the target's pitch; during the descent f0 follows the candidate's own
measured pitch. The bow is searched in u = (ln F_B / w, v_B / VB_UNIT), so that a step means the same share of the
space's two sides.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from ..engines.operator.choose import available_models, covering_model
from ..errors import BowsynthError, DomainError, SceneError
from ..music.ratio_map import physics_ratio, vb_stop
from ..music.tuning import SilentNoteError
from .loss import SoundLoss
from .surrogate import Note, NoteFailed, note_scene
from .target import Target

BETA_RANGE = (0.01, 2.02)  # the playing space (F_B / w)
VB_RANGE = (None, 0.3)  # from just above vb_stop
GRID = (16, 20)  # coarse bows: F_B / w (geometric) x v_B (uniform in the cube root of v_B - vb_stop)
VB_LOW = 0.0015  # the coarse grid's lowest v_B above vb_stop
COARSE_SECONDS = 1.0  # the coarse grid listens to the target's first second
VB_UNIT = 0.01  # v_B's step unit in u
STARTS = 3  # the best coarse bows, a grid cell apart at least, that are zoomed into and descend
STEPS = 24  # gradient steps per start
LR = (0.08, 0.004)  # Adam's step in u, at the first and the last step (cosine between)


@dataclass
class Candidate:
    beta: float
    vb: float
    f0: float
    loss: float
    model: str = ""  # the model that played it: a shipped model's name, else its file (model_ref)
    locked: bool = False  # windows locked to the target's period (else the trained T)
    parts: dict = field(default_factory=dict)

    @property
    def u(self) -> np.ndarray:
        return np.array([math.log(self.beta), self.vb / VB_UNIT])


def playable(models=None) -> list:
    """The validated range models a fit plays its candidates with."""
    models = available_models() if models is None else models
    return [m for m in models if m.domain.is_range and m.failure is None]


def f0_for(pitch: float, beta: float, vb: float, a: float = 100.0) -> float | None:
    """The f0 at which a bow sounds at `pitch` by the shipped map; None where the bow does not sound."""
    try:
        return pitch / physics_ratio(beta, vb, a).r
    except (SilentNoteError, DomainError, ValueError):
        return None


def model_ref(m) -> str:
    """What names a model to `render --model` and `score --model` (choose.model_ref), or a model not saved its own
    name."""
    from ..engines.operator.choose import model_ref as file_ref

    return m.meta.name if m.path is None else file_ref(m.path)


class Scorer:
    """Plays candidate bows against one target (its first `seconds`, default all of it) and counts the notes played.

    A candidate plays in free windows and in windows locked to the target's period, and keeps the nearer: a render
    locks a range model's held note where that holds its pitch better (engine_tuning.auto_lock, measured per bow,
    too slow for hundreds of candidates), and the fit's sound is checked at the end by the render itself."""

    def __init__(self, target: Target, models=None, seconds: float | None = None):
        self.target = target
        self.n = target.n if seconds is None else min(target.n, int(round(seconds * target.sample_rate)))
        self.loss = SoundLoss(target.x[:self.n], target.sample_rate)
        self.pitch = self.loss.pitch  # over the span listened to
        self.models = playable(models)
        self.evaluations = 0
        self._notes: dict = {}

    def model_for(self, beta: float, vb: float, f0: float):
        try:
            sc = note_scene(f0, beta, vb, self.target.n / self.target.sample_rate, self.target.sample_rate)
        except SceneError:
            return None
        return covering_model(sc, self.models)

    def note(self, model, f0: float, locked: bool) -> Note:
        key = (model.key, round(f0, 9), locked)
        if key not in self._notes:
            if len(self._notes) > 64:
                self._notes.clear()
            self._notes[key] = Note(model, f0, self.target.sample_rate, self.n,
                                        sounding=self.pitch if locked else None)
        return self._notes[key]

    def score(self, beta: float, vb: float, f0: float | None = None, locked: bool | None = None) -> Candidate | None:
        """The loss of a bow played at f0 (default: the map's f0 for the target's pitch) in free or locked windows
        (None: both, the nearer kept); None where no model plays it or its notes fail."""
        f0 = f0_for(self.pitch, beta, vb) if f0 is None else f0
        if f0 is None or not 20.0 <= f0 < self.target.sample_rate / 2.5:
            return None
        m = self.model_for(beta, vb, f0)
        if m is None:
            return None
        best = None
        for lk in ((False, True) if locked is None else (locked,)):
            self.evaluations += 1
            try:
                q = self.note(m, f0, lk).play((beta, vb))
            except (NoteFailed, BowsynthError, ValueError):  # a note the model cannot play at this f0 and rate
                continue
            if not np.all(np.isfinite(q)) or np.ptp(q) == 0:
                continue
            c = Candidate(beta, vb, f0, self.loss.value(q), model_ref(m), lk)
            if best is None or c.loss < best.loss:
                best = c
        return best


def coarse(scorer: Scorer, grid=GRID, a: float = 100.0) -> list[Candidate]:
    """Every bow of a grid over the playing space, scored, best first."""
    stop = vb_stop(a)
    betas = np.geomspace(*BETA_RANGE, grid[0])
    out = []
    for b in betas:
        for v in stop + vb_axis(a, grid[1]) ** 3:
            c = scorer.score(float(b), float(v))
            if c is not None and math.isfinite(c.loss):
                out.append(c)
    return sorted(out, key=lambda c: c.loss)


def vb_axis(a: float, n: int) -> np.ndarray:
    """The coarse grid's v_B axis as the cube root of v_B - vb_stop: fine near vb_stop, where the timbre changes
    fastest, and a few hundredths apart at the fastest bows."""
    return np.linspace(VB_LOW ** (1 / 3), (VB_RANGE[1] - vb_stop(a)) ** (1 / 3), n)


def zoom(scorer: Scorer, around: Candidate, grid=GRID, n: int = 5, a: float = 100.0) -> list[Candidate]:
    """A finer n x n grid across one coarse cell either side of a candidate (in ln F_B / w and the coarse v_B axis),
    in the candidate's windows, best first."""
    stop = vb_stop(a)
    db = math.log(BETA_RANGE[1] / BETA_RANGE[0]) / (grid[0] - 1)
    axis = vb_axis(a, grid[1])
    dy = axis[1] - axis[0]
    y0 = max(around.vb - stop, 1e-9) ** (1 / 3)
    out = []
    for x in np.linspace(-db, db, n):
        for y in np.linspace(-dy, dy, n):
            b = float(np.clip(around.beta * math.exp(x), *BETA_RANGE))
            v = float(min(stop + max(y0 + y, 1e-3) ** 3, VB_RANGE[1]))
            c = scorer.score(b, v, locked=around.locked)
            if c is not None and math.isfinite(c.loss):
                out.append(c)
    return sorted(out, key=lambda c: c.loss)


def distinct_starts(cands: list[Candidate], k: int = STARTS, apart: float = 0.35) -> list[Candidate]:
    """The best k candidates at least `apart` from each other in (ln F_B / w, ln (v_B - vb_stop))."""
    stop = vb_stop()
    key = lambda c: np.array([math.log(c.beta), math.log(max(c.vb - stop, 1e-6))])  # noqa: E731
    out: list[Candidate] = []
    for c in cands:
        if all(np.linalg.norm(key(c) - key(o)) >= apart for o in out):
            out.append(c)
        if len(out) == k:
            break
    return out


def descend(scorer: Scorer, start: Candidate, steps: int = STEPS, deadline: float = math.inf,
            trace: list | None = None) -> Candidate:
    """Adam on the bow from `start`, through the operator's rollout; the best candidate seen (by the whole loss)."""
    import torch

    u = torch.tensor(start.u, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.Adam([u], lr=LR[0])
    best, f0 = start, start.f0
    for i in range(steps):
        if time.monotonic() > deadline:
            break
        lr = LR[1] + 0.5 * (LR[0] - LR[1]) * (1 + math.cos(math.pi * i / max(1, steps - 1)))
        for g in opt.param_groups:
            g["lr"] = lr
        beta, vb = math.exp(float(u[0].detach())), float(u[1].detach()) * VB_UNIT
        m = scorer.model_for(beta, vb, f0)
        if m is None:
            break
        note = scorer.note(m, f0, start.locked)
        bow = torch.stack([u[0].exp(), u[1] * VB_UNIT])
        try:
            q = note(bow)
        except (NoteFailed, SceneError):
            break
        scorer.evaluations += 1
        parts = scorer.loss.parts(q)
        qn = q.detach().double().numpy()
        pitch_term, c = scorer.loss.pitch_term(qn)
        total = float((parts["spectral"] + parts["onset"]).detach()) + pitch_term
        if trace is not None:
            trace.append((beta, vb, f0, total))
        if total < best.loss:
            best = Candidate(beta, vb, f0, total, model_ref(m), start.locked,
                             {k: float(v.detach()) for k, v in parts.items()} | {"pitch_cents": c})
        opt.zero_grad()
        (parts["spectral"] + parts["onset"]).backward()
        if not torch.all(torch.isfinite(u.grad)):
            break
        opt.step()
        with torch.no_grad():
            u[0].clamp_(math.log(BETA_RANGE[0]), math.log(BETA_RANGE[1]))
            u[1].clamp_((vb_stop() + 1e-4) / VB_UNIT, VB_RANGE[1] / VB_UNIT)
        if math.isfinite(c):  # f0 follows the note's own pitch to the target's
            f0 *= 2 ** (-c / 1200)
    return best
