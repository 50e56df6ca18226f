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

from ..errors import BowsynthError, DomainError
from ..fdm import render_fdm
from ..metrics import compare_signals, nmse
from ..scene import Scene
from .data import window_starts

REF_OVERSAMPLE = 100
SELECT_OFFSET_S = 0.3  # into the note (past the onset), then 0.37 of a window further: between two window starts


def json_number(x: float):
    """x for JSON metadata: inf and NaN (no score) become null."""
    return x if math.isfinite(x) else None


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
        from ..rollout import render_operator

        try:
            if self._ref is None:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    self._ref = render_fdm(self.scene, oversample=REF_OVERSAMPLE).p
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
                "score_nmse_p": json_number(self.best["score"]),
                "from_state": [self.scene.q0, self.scene.p0]}


def validate(model, scene: Scene, seconds: float = 1.0, ref_oversample: int = REF_OVERSAMPLE) -> dict:
    """NMSE etc. of a rollout from the scene's initial state against a high-rate FDM, over `seconds`."""
    from ..rollout import render_operator

    s = scene.replace(duration=seconds)
    ref = render_fdm(s, oversample=ref_oversample)
    try:
        r = render_operator(s, model=model)
    except DomainError as e:  # an undertrained model: keep it, but say so in its record
        return {"error": str(e), "seconds": seconds, "ref_oversample": ref_oversample}
    m = compare_signals(r.p, ref.p, s.sample_rate, r.q, ref.q)
    m["nmse_q"] = float(np.mean((r.q - ref.q) ** 2) / np.var(ref.q))
    m["seconds"] = seconds
    m["ref_oversample"] = ref_oversample
    return {k: (json_number(v) if isinstance(v, float) else v) for k, v in m.items()}
