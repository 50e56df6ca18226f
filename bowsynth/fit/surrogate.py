"""A note of the operator as a torch function of its bow (held, or breakpoint curves), so that a loss on its sound has
a gradient in the bow.

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

from ..controls import Curve
from .. import physics
from ..engines.operator.basis import numpy_operator
from ..engines.operator.onset import rest_onset
from ..engines.operator.rollout import rollout_states, scene_bows
from ..engines.operator.windows import FAILURES, locked_window, window_bounds
from ..scene import Scene

RUN = 8  # windows re-rolled from each anchor: at quarter-period windows two periods


class NoteFailed(Exception):
    """The operator's note left its model (its trained states, or went non-finite): no sound to compare."""


def note_scene(f0: float, beta, vb, seconds: float, sample_rate: int, a: float = 100.0, times=None) -> Scene:
    """A note of a bow (F_B / w, v_B) at f0, as a Scene: held (numbers), or curves through breakpoints at `times`
    (s; arrays beta, vb of their length)."""
    if times is None:
        return Scene(f0=f0, fb=beta * physics.omega(f0), vb=vb, a=a, duration=seconds, sample_rate=sample_rate)
    w = physics.omega(f0)
    fb = Curve([(float(t), float(b) * w) for t, b in zip(times, beta)])
    return Scene(f0=f0, fb=fb, vb=Curve([(float(t), float(v)) for t, v in zip(times, vb)]), a=a, duration=seconds,
                 sample_rate=sample_rate)


def interp_matrix(times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(len(t), len(times)): the weights of linear interpolation between breakpoints at `times`, held outside them
    (controls.Curve's rule), so that values at t are M @ values at the breakpoints."""
    K = len(times)
    M = np.zeros((len(t), K))
    if K == 1:
        M[:, 0] = 1.0
        return M
    j = np.clip(np.searchsorted(times, t, side="right") - 1, 0, K - 2)
    f = np.clip((t - times[j]) / (times[j + 1] - times[j]), 0.0, 1.0)
    M[np.arange(len(t)), j] = 1 - f
    M[np.arange(len(t)), j + 1] = f
    return M


class Note:
    """One range model's notes at f0: `play` (numpy, the compiled loops) and `__call__` (torch, differentiable in
    the bow). n samples at sample_rate from rest, in windows of the trained T or, given the frequency the note
    sounds at, locked to its period. A bow is (F_B / w, v_B) held, or breakpoints (K, 2) at `times` (s)."""

    def __init__(self, model, f0: float, sample_rate: int, n: int, a: float = 100.0, sounding: float | None = None,
                 times=None):
        if not model.domain.is_range:
            raise ValueError("a note's gradient needs a range model (a point model plays one bow)")
        self.model, self.f0, self.sample_rate, self.n, self.a = model, float(f0), int(sample_rate), int(n), float(a)
        self.times = None if times is None else np.asarray(times, float)
        self.dtau = physics.dtau(self.f0, self.sample_rate)
        T = numpy_operator(model).window
        # locked to the sounding period (windows.locked_window), as a render locks a range model's held note
        self.window = None if sounding is None else locked_window(T, self.f0, sounding)
        self.spw = numpy_operator(model).samples_per_window(self.dtau, self.window)

    def scene(self, bow) -> Scene:
        bow = np.asarray(bow, float)
        if self.times is None:
            return note_scene(self.f0, float(bow[0]), float(bow[1]), self.n / self.sample_rate, self.sample_rate,
                              self.a)
        return note_scene(self.f0, bow[:, 0], bow[:, 1], self.n / self.sample_rate, self.sample_rate, self.a,
                          self.times)

    def _roll(self, bow):
        """(h, q, p, mid): the rest flow's samples before sample h, then the operator's (float64 q, p of all n), and
        the operator's windows' middle times (s)."""
        sc = self.scene(bow)
        rest = rest_onset(sc, self.model, self.spw)
        h, qh, ph = (0, sc.q0, sc.p0) if rest is None else (rest[0], rest[3], rest[4])
        q, p = np.empty(self.n), np.empty(self.n)
        if rest is not None:
            q[:h], p[:h] = rest[1], rest[2]
        starts, ends = window_bounds(self.spw, max(1, self.n - h))
        mid = (h + 0.5 * (starts + np.minimum(ends, self.n - h))) / self.sample_rate
        if h < self.n:
            after = sc.after(h / self.sample_rate, duration=(self.n - h) / self.sample_rate, q0=qh, p0=ph)
            par = scene_bows(after, self.spw)
            qo, po, fail = rollout_states(self.model, np.array([[qh, ph]]), self.n - h, self.dtau,
                                          params=par[None], window=self.window)
            if fail[0, 0] >= 0:
                raise NoteFailed(FAILURES.get(int(fail[0, 1]), "the rollout failed"))
            q[h:], p[h:] = qo[0], po[0]
        return h, q, p, mid

    def play(self, bow) -> np.ndarray:
        """The note's q (the mass's displacement times w, what a render writes as u) by the compiled loops."""
        return self._roll(bow)[1]

    def __call__(self, bow):
        """q (n,) as a torch tensor, differentiable in bow (a (2,) or (K, 2) tensor of F_B / w, v_B) over RUN
        windows."""
        import torch

        h, q, p, mid = self._roll(bow.detach().numpy())
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
        if self.times is None:
            per_window = bow.to(torch.float32)[None, :].expand(W, 2)
        else:  # each window's bow: the curves at its middle (rollout.scene_bows' rule)
            M = torch.as_tensor(interp_matrix(self.times, mid), dtype=torch.float32)
            per_window = M @ bow.to(torch.float32)
        per_window = torch.cat([per_window, per_window[-1:].expand(runs * RUN - W, 2)])
        blocks = []
        for j in range(RUN):
            k = np.arange(runs) * RUN + j  # the window each run plays now
            L = torch.as_tensor(lens[np.minimum(k, W - 1)], dtype=torch.long)
            par = per_window[torch.as_tensor(k)]
            bf = net.branch_features(x, par)
            out = net.assemble(x, taus, bf, tf, gain=net.gain(par))  # (runs, n_hi + 1, 2): samples and both ends
            blocks.append(out[:, :n_hi, 0])
            x = out[torch.arange(runs), L]  # the next window's start
        block = torch.stack(blocks, dim=1).reshape(runs * RUN, n_hi)[:W]
        keep = torch.arange(n_hi)[None, :] < torch.as_tensor(lens)[:, None]
        rolled = block[keep]
        return torch.cat([torch.as_tensor(q[:h], dtype=torch.float32), rolled])

