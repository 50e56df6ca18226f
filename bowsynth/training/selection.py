"""Scoring weights by rolling them out: the weight selection during training and the validation after it.

The two score different things on purpose. Validation: 1 s from the scene's own initial state (what a user
renders) against a x100 FDM; it is reported, never used to choose. Selection: 1 s from another state of the band,
a state the render from rest passes between two of its window starts (so every window of this rollout starts
somewhere the window-start training data never put one), against a x100 FDM from that state.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..metrics import SILENT, compare_signals, late_rms, listener_errors, nmse, note_sounds
from ..engines.fdm import TRUTH_OVERSAMPLE, render_fdm
from ..errors import BowsynthError, DomainError
from ..scene import Scene
from ..io.text import jsonable
from .data import window_starts

SELECT_OFFSET_S = 0.3  # into the note (past the onset), then 0.37 of a window further: between two window starts


def selection_scene(scene: Scene, band: np.ndarray, window: float, contains) -> Scene:
    """The scene the weights are chosen on: the scene's pitch, 1 s, from a band state off the window starts."""
    per_window = window / scene.dtau
    starts = len(window_starts(scene, band, window))
    i = int(round(min(SELECT_OFFSET_S * scene.sample_rate, (starts - 1) * per_window) + 0.37 * per_window))
    i = min(i, len(band) - 1)
    q0, p0 = (float(v) for v in band[i])
    if not contains(q0, p0):  # a band that barely moves (a bow stop): its first state is as good as any
        q0, p0 = (float(v) for v in band[0])
    return scene.replace(q0=q0, p0=p0, duration=1.0)


class Selector:
    """Keeps the weights that roll out best on the selection scene."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self._ref = None
        self.best: dict = {"score": math.inf, "step": None, "state": None, "scored": 0}

    def score(self, model) -> float:
        from ..engines.operator.engine import render_operator

        try:
            if self._ref is None:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    self._ref = render_fdm(self.scene, oversample=TRUTH_OVERSAMPLE).p
            s = float(nmse(render_operator(self.scene, model=model).p, self._ref))
        except BowsynthError:  # the rollout left its domain
            return math.inf
        return s if math.isfinite(s) else math.inf

    def consider(self, model, step: int, state: dict) -> None:
        score = self.score(model)
        self.best["scored"] += 1
        if score < self.best["score"]:
            self.best.update(score=score, step=step, state={k: v.detach().clone() for k, v in state.items()})

    def record(self) -> dict:
        return {"step": self.best["step"], "scored": self.best["scored"],
                "score_nmse_p": jsonable(self.best["score"]),
                "from_state": [self.scene.q0, self.scene.p0]}


# what a listener hears, each error divided by its target (harmonics 0.2 dB median and 1 dB worst, pitch 0.2 cent):
# NMSE from rest asks for the bow to be exact to 1e-4 and chose weights whose upper harmonics were 7-30 dB weak
TARGET_HARM_MEDIAN_DB, TARGET_HARM_MAX_DB, TARGET_CENTS = 0.2, 1.0, 0.2


def listener_score(x, ref, sample_rate: float) -> float:
    """The selection's score of one rollout against its reference (both from rest): the listener errors over their
    targets, summed (0 is perfect; inf when the render has no pitch or lacks a harmonic the truth has). Where the
    truth rests (a bow that damps the mass), what a listener hears is whether the render rests too: its RMS over its
    last half in units of SILENT."""
    if not note_sounds(ref):
        return late_rms(x) / SILENT
    e = listener_errors(x, ref, sample_rate)
    s = (e["harm_db_median"] / TARGET_HARM_MEDIAN_DB + e["harm_db_max"] / TARGET_HARM_MAX_DB
         + abs(e["cents"]) / TARGET_CENTS)
    return s if math.isfinite(s) else math.inf


class RangeSelector(Selector):
    """Selection for a range model: the mean listener score (listener_score) of rollouts from rest, `seconds` long
    (TrainConfig.judge_seconds), at `n` bows of the box drawn apart from the training points (another seed), where
    the note speaks within them."""

    def __init__(self, scene: Scene, box, n: int, seed: int, seconds: float = 1.0):
        from .ranges import distinct, speaks

        pts = box.sample(4 * n, np.random.default_rng(seed))
        pts = distinct(pts[speaks(pts[:, 0], pts[:, 1], box.a, scene.f0, seconds)])[:n]
        if not len(pts):
            pts = np.array([[box.beta_hi, (box.vb_lo + box.vb_hi) / 2]])
        self.scenes = [scene.replace(fb=float(b) * scene.omega, vb=float(v), duration=seconds) for b, v in pts]
        super().__init__(self.scenes[0])
        self._refs = None

    def score(self, model) -> float:
        from ..engines.operator.engine import render_operator

        try:
            if self._refs is None:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    self._refs = [render_fdm(s, oversample=TRUTH_OVERSAMPLE).p for s in self.scenes]
            rs = render_operator(self.scenes, model=model)
            s = float(np.mean([listener_score(r.p, ref, sc.sample_rate)
                               for r, ref, sc in zip(rs, self._refs, self.scenes)]))
        except BowsynthError:
            return math.inf
        return s if math.isfinite(s) else math.inf

    def record(self) -> dict:
        return {"step": self.best["step"], "scored": self.best["scored"],
                "score_mean_listener": jsonable(self.best["score"]),
                "bows": [[s.beta, s.vb] for s in self.scenes]}


def validate_range(model, scene: Scene, box, n: int = 3, seconds: float = 1.0,
                   ref_oversample: int = TRUTH_OVERSAMPLE) -> dict:
    """validate() at the n x n grid of the box (from rest, the scene's pitch) where the note speaks: the median
    NMSE(p) is the model's score ('nmse'), the worst beside it; the silent corners must stay finite, and
    'resting' counts the grid bows where the truth rests, 'silent_sounding' those of them where the model does not
    (metrics.note_sounds), 'speaking' those where the note speaks."""
    from .ranges import distinct, speaks

    pts = distinct(box.grid(n))  # a side of zero width (a score's held v_B, a refined point) repeats points
    rows = []
    for b, v in pts:
        sc = scene.replace(fb=float(b) * scene.omega, vb=float(v))
        rec = validate(model, sc, seconds, ref_oversample)
        rec.update(beta=float(b), vb=float(v), speaks=bool(speaks(b, v, box.a, scene.f0, seconds)))
        rows.append(rec)
    spk = [r for r in rows if r["speaks"]]
    errs = [r for r in rows if r.get("error")]
    vals = [r["nmse"] for r in spk if isinstance(r.get("nmse"), float)]
    out = {"points": rows, "seconds": seconds, "ref_oversample": ref_oversample, "grid": n,
           "speaking": len(spk), "resting": sum(1 for r in rows if r.get("truth_sounds") is False),
           "silent_sounding": sum(1 for r in rows if r.get("truth_sounds") is False and r.get("op_sounds"))}
    if errs:
        out["error"] = f"{len(errs)} of {len(rows)} grid points failed: {errs[0]['error']}"
    if vals:
        out["nmse"] = float(np.median(vals))
        out["nmse_max"] = float(np.max(vals))
    heard = [r for r in spk if isinstance(r.get("harm_db_median"), float)]
    if heard:  # what a listener hears, over the speaking grid points (docs/measures.md)
        out["harm_db_median"] = float(np.median([r["harm_db_median"] for r in heard]))
        out["harm_db_max"] = float(np.max([r["harm_db_max"] for r in heard if r.get("harm_db_max") is not None]))
        out["cents_abs_max"] = float(np.max([abs(r["heard_cents"]) for r in heard if r.get("heard_cents") is not None]))
    return out


def validate(model, scene: Scene, seconds: float = 1.0, ref_oversample: int = TRUTH_OVERSAMPLE,
             windows: str | None = None) -> dict:
    """NMSE etc. of a rollout from the scene's initial state against a high-rate FDM, over `seconds`, in the windows
    a render plays it in (windows None: the render's default, auto; music.engine_tuning.sounding_for). 'windows' in
    the record: 'free', or the windows a sounding period of a lock.

    Why the render's windows: a model is picked, or not, by this record, and a render plays auto windows. Validated
    in free windows, `stick-halt-high` failed at F_B / w 1.767, v_B 0.125: -12.2 cents, where auto locks
    it to the physics' period (24 windows a period) and it plays -0.10 cents at 1 s, -0.004 at 2 s."""
    from ..engines.operator.engine import render_operator
    from ..music.engine_tuning import sounding_for

    s = scene.replace(duration=seconds)
    ref = render_fdm(s, oversample=ref_oversample)
    try:
        r = render_operator(s, model=model, sounding=sounding_for(s, windows, model))
    except DomainError as e:  # an undertrained model: keep it, but say so in its record
        return {"error": str(e), "seconds": seconds, "ref_oversample": ref_oversample}
    m = compare_signals(r.p, ref.p, s.sample_rate, r.q, ref.q)
    heard = listener_errors(r.p, ref.p, s.sample_rate)
    m.update(heard_cents=heard["cents"], harm_db_median=heard["harm_db_median"], harm_db_max=heard["harm_db_max"],
             onset_err_ms=heard["onset_err_ms"])
    m["nmse_q"] = float(np.mean((r.q - ref.q) ** 2) / np.var(ref.q))
    m["truth_sounds"], m["op_sounds"] = note_sounds(ref.p), note_sounds(r.p)
    m["seconds"] = seconds
    m["ref_oversample"] = ref_oversample
    m["windows"] = "free" if r.info.windows is None else f"{r.info.windows} a period"
    return {k: (jsonable(v) if isinstance(v, float) else v) for k, v in m.items()}
