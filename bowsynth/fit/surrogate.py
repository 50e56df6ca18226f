"""A held note of the operator as a torch function of its bow, so that a loss on its sound has a gradient in the bow.

The compiled rollout plays the note (the same loops and window geometry as a render in free windows, the note's first
samples by the flow at rest: engines/operator/onset.py); its states at every RUN-th window's start are the anchors.
From each anchor torch rolls RUN windows again with the bow as a tensor, all runs at once, and the note's samples are
those runs' samples. The forward values are the compiled render's (up to float32 rounding); the gradient is truncated
to RUN windows: how the bow shapes the cycle within a period or two, which is what a spectral loss hears of it. The
rest flow's samples (the growth from rest, exact and linear) carry no gradient: the onset is found by the search.
"""

from __future__ import annotations

import math

import numpy as np

from .. import physics
from ..engines.operator.basis import _operator
from ..engines.operator.onset import rest_onset
from ..engines.operator.rollout import rollout_states
from ..engines.operator.windows import FAILURES, locked_window, window_bounds
from ..scene import Scene

RUN = 8  # windows re-rolled from each anchor: at quarter-period windows two periods


class NoteFailed(Exception):
    """The operator's note left its model (its trained states, or went non-finite): no sound to compare."""


def note_scene(f0: float, beta: float, vb: float, seconds: float, sample_rate: int, a: float = 100.0) -> Scene:
    """The held note of a bow (F_B / w, v_B) at f0, as a Scene."""
    return Scene(f0=f0, fb=beta * physics.omega(f0), vb=vb, a=a, duration=seconds, sample_rate=sample_rate)


class HeldNote:
    """One range model's held notes at f0: `play` (numpy, the compiled loops) and `__call__` (torch, differentiable in
    the bow). n samples at sample_rate from rest, in windows of the trained T or, given the frequency the note
    sounds at, locked to its period."""

    def __init__(self, model, f0: float, sample_rate: int, n: int, a: float = 100.0, sounding: float | None = None):
        if not model.domain.is_range:
            raise ValueError("a held note's gradient needs a range model (a point model plays one bow)")
        self.model, self.f0, self.sample_rate, self.n, self.a = model, float(f0), int(sample_rate), int(n), float(a)
        self.dtau = physics.dtau(self.f0, self.sample_rate)
        T = _operator(model).window
        # locked to the sounding period (windows.locked_window), as a render locks a range model's held note
        self.window = None if sounding is None else locked_window(T, self.f0, sounding)
        self.spw = _operator(model).samples_per_window(self.dtau, self.window)

    def scene(self, beta: float, vb: float) -> Scene:
        return note_scene(self.f0, beta, vb, self.n / self.sample_rate, self.sample_rate, self.a)

    def _roll(self, beta: float, vb: float):
        """(h, q, p): the rest flow's samples before sample h, then the operator's (float64 q, p of all n)."""
        sc = self.scene(beta, vb)
        rest = rest_onset(sc, self.model, self.spw)
        h, qh, ph = (0, sc.q0, sc.p0) if rest is None else (rest[0], rest[3], rest[4])
        q, p = np.empty(self.n), np.empty(self.n)
        if rest is not None:
            q[:h], p[:h] = rest[1], rest[2]
        if h < self.n:
            qo, po, fail = rollout_states(self.model, np.array([[qh, ph]]), self.n - h, self.dtau,
                                          params=np.array([beta, vb]), window=self.window)
            if fail[0, 0] >= 0:
                raise NoteFailed(FAILURES.get(int(fail[0, 1]), "the rollout failed"))
            q[h:], p[h:] = qo[0], po[0]
        return h, q, p

    def play(self, beta: float, vb: float) -> np.ndarray:
        """The note's q (the mass's displacement times w, what a render writes as u) by the compiled loops."""
        return self._roll(beta, vb)[1]

    def __call__(self, bow):
        """q (n,) as a torch tensor, differentiable in bow (a (2,) tensor: F_B / w, v_B) over RUN windows."""
        import torch

        beta, vb = (float(v) for v in bow.detach())
        h, q, p = self._roll(beta, vb)
        net = self.model.net
        starts, ends = window_bounds(self.spw, self.n - h)
        ends = np.minimum(ends, self.n - h)
        lens = ends - starts
        W = len(starts)
        runs = math.ceil(W / RUN)
        n_hi = int(lens.max())
        anchors = starts[::RUN] + h
        x = torch.tensor(np.stack([q[anchors], p[anchors]], axis=1), dtype=torch.float32)
        taus = torch.arange(n_hi + 1, dtype=torch.float32) * self.dtau
        with torch.no_grad():
            tf = net.trunk_features(taus / net.window)
        par = bow.to(torch.float32)[None, :].expand(runs, 2)
        gain = net.gain(par)
        blocks = []
        for j in range(RUN):
            k = np.arange(runs) * RUN + j  # the window each run plays now
            L = torch.as_tensor(lens[np.minimum(k, W - 1)], dtype=torch.long)
            bf = net.branch_features(x, par)
            out = net.assemble(x, taus, bf, tf, gain=gain)  # (runs, n_hi + 1, 2): the samples and both ends
            blocks.append(out[:, :n_hi, 0])
            x = out[torch.arange(runs), L]  # the next window's start
        block = torch.stack(blocks, dim=1).reshape(runs * RUN, n_hi)[:W]
        keep = torch.arange(n_hi)[None, :] < torch.as_tensor(lens)[:, None]
        rolled = block[keep]
        return torch.cat([torch.as_tensor(q[:h], dtype=torch.float32), rolled])
