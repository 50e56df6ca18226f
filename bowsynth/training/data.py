"""What the operator trains on: the band of states a render of the scene visits, a domain around it, a sampler of
states near it, and high-rate FDM trajectories over one window from those states ("a Model trains a Net on Data")."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .. import physics
from ..engines.fdm import fdm_batch, render_fdm
from ..engines.operator.domain import Domain
from ..engines.operator.npnet import NetConfig, linear_part
from ..scene import Scene
from .config import TrainConfig

GRID = 64  # domain mask resolution


def scene_band(scene: Scene, seconds: float) -> np.ndarray:
    """States (N, 2) an audio-rate FDM visits from the scene's initial state: where a render will go."""
    r = render_fdm(scene.replace(duration=max(seconds, 2.0 / scene.sample_rate)), oversample=1)
    return np.stack([r.q, r.p], axis=1)


def make_domain(scene: Scene, band: np.ndarray, window: float, margin: float, box_only: bool) -> Domain:
    lo, hi = band.min(0), band.max(0)
    rng_ = np.maximum(hi - lo, 1e-3)
    lo, hi = lo - margin * rng_, hi + margin * rng_
    dom = Domain(beta=scene.beta, vb=scene.vb, a=scene.a, window=window,
                 q_lo=float(lo[0]), q_hi=float(hi[0]), p_lo=float(lo[1]), p_hi=float(hi[1]),
                 mask=np.ones((GRID, GRID), bool))
    if not box_only:
        mask = np.zeros((GRID, GRID), bool)
        mask[dom.cell(band[:, 0], band[:, 1], GRID)] = True
        dom.mask = ndimage.binary_dilation(mask, iterations=max(1, math.ceil(margin * GRID)))
    return dom


def band_draw(cdf: np.ndarray, rng: np.random.Generator, n: int) -> np.ndarray:
    """n indices into a band drawn by its cumulative weights (a sampler's cdf)."""
    return np.minimum(np.searchsorted(cdf, rng.random(n)), len(cdf) - 1)


class StateSampler:
    """Draws training states near the band (scene sampling) or uniformly in the domain's box."""

    def __init__(self, band: np.ndarray, domain: Domain, margin: float, box: bool, rng: np.random.Generator):
        self.band, self.domain, self.box, self.rng = band, domain, box, rng
        self.sd = margin * (band.max(0) - band.min(0)).clip(1e-3) / 2
        # A render passes through its onset once and then circles its limit cycle: uniform sampling in time
        # would leave the onset almost untrained. Weight each band point by 1 / (points in its grid cell).
        i, j = domain.cell(band[:, 0], band[:, 1], GRID)
        cell = i * GRID + j
        counts = np.bincount(cell, minlength=GRID * GRID)
        w = 1.0 / counts[cell]
        self.cdf = np.cumsum(w) / w.sum()

    def on_band(self, n: int) -> tuple[np.ndarray, None]:
        """n band states, weighted as __call__ draws them, not jittered: states a render visits (and no bows: a point
        model's, as RangeSampler.on_band's pairs)."""
        return self.band[band_draw(self.cdf, self.rng, n)], None

    def __call__(self, n: int) -> np.ndarray:
        out = np.empty((0, 2))
        while len(out) < n:
            if self.box:
                d = self.domain
                x = self.rng.uniform([d.q_lo, d.p_lo], [d.q_hi, d.p_hi], size=(2 * n, 2))
            else:
                idx = band_draw(self.cdf, self.rng, 2 * n)
                x = self.band[idx] + self.rng.normal(0, 1, (2 * n, 2)) * self.sd
            x = x[self.domain.contains(x[:, 0], x[:, 1])]
            out = np.concatenate([out, x])
        return out[:n]


def fdm_windows(scene: Scene, x0: np.ndarray, window: float, n_times: int, oversample: int, on_progress=None,
                par: np.ndarray | None = None):
    """High-rate FDM trajectories over one window from each state: (tau (M+1,), x (B, M+1, 2)). par (B, 2): each
    state's own bow (beta, v_B) (range data); None: the scene's."""
    w = scene.omega
    fb, vb = (scene.fb, scene.vb) if par is None else (par[:, 0] * w, par[:, 1])
    fb_max = float(np.max(fb))
    stride = max(1, math.ceil(window / n_times / (scene.dtau / oversample)))
    k = window / (n_times * stride) / w  # seconds
    if k >= physics.max_stable_step(fb_max, scene.a):
        stride = math.ceil(window / n_times / (0.9 * physics.max_stable_step(fb_max, scene.a) * w))
        k = window / (n_times * stride) / w
    q, p = fdm_batch(x0[:, 0], x0[:, 1], n_times + 1, stride, k, w, fb, vb, scene.a, on_progress=on_progress)
    tau = np.arange(n_times + 1) * window / n_times
    return tau, np.stack([q, p], axis=-1)


def window_starts(scene: Scene, band: np.ndarray, window: float) -> np.ndarray:
    """The band states where a render from the scene's initial state starts its windows."""
    n_win = max(1, int(window / scene.dtau + 1e-9))
    return band[::n_win]


@dataclass
class TrainingData:
    band: np.ndarray
    domain: Domain
    sampler: StateSampler
    x0: np.ndarray  # (B, 2) window start states of the FDM data
    tau: np.ndarray  # (M + 1,) times in the window
    x: np.ndarray  # (B, M + 1, 2) FDM trajectories
    corr_scale: np.ndarray  # (2,) RMS size of the friction correction per variable
    par: np.ndarray | None = None  # range data: (B, 2) each trajectory's bow (beta, v_B)
    box: object = None  # range data: the ParamBox
    extents: np.ndarray | None = None  # range data: ranges.RangeBand.extents
    # the rollout term's chains (cfg.rollout > 0): (C, K + 1, 2) the FDM's states at K + 1 window boundaries from
    # band states, and (range data) (C, 2) each chain's bow
    chain_x: np.ndarray | None = None
    chain_par: np.ndarray | None = None


def add_chains(data: TrainingData, scene: Scene, cfg: TrainConfig, window: float, on_progress=None) -> TrainingData:
    """The rollout term's chains: K windows of the FDM from band states, not jittered as the data's are (the sampler's
    rng comes after every other draw, so a recipe without the term draws the same data as before it existed). Why not
    jittered: from jittered starts a few chains leave the states any render visits and their errors,
    0.1-0.6 of the correction scale where the median chain's is 1e-8, made the whole term; its first training raised
    the data loss from 2.4e-7 to 3e-3 in 500 steps."""
    if not cfg.rollout > 0:
        return data
    n, k = cfg.rollout_chains, cfg.rollout_windows
    x0, par = data.sampler.on_band(n)
    # one call over K windows, kept at their boundaries; its step, like the data's, at most dtau / oversample
    _, x = fdm_windows(scene, x0, window * k, k, cfg.data_oversample, par=par,
                       on_progress=None if on_progress is None else lambda f: on_progress(
                           f"FDM rollout chains: {n} x {k} windows", f))
    data.chain_x, data.chain_par = x, par
    return data


def build(scene: Scene, cfg: TrainConfig, window: float, rng: np.random.Generator, on_progress=None) -> TrainingData:
    """Band, domain, sampler and FDM data for a scene. on_progress(phase, fraction) reports the slow parts."""
    report = on_progress or (lambda phase, frac: None)
    report("scene band (audio-rate FDM)", 0.0)
    box = cfg.sampling == "box"
    band = scene_band(scene, cfg.band_seconds)
    domain = make_domain(scene, band, window, cfg.margin, box_only=box)
    sampler = StateSampler(band, domain, cfg.margin, box, rng)
    # FDM trajectories from band states: the data loss, and the correction scale c even without it
    x0 = sampler(cfg.n_data if cfg.hybrid else min(cfg.n_data, 512))
    if cfg.hybrid and cfg.start_share > 0:
        # A render from the scene's initial state starts its windows at exactly these band states; its onset
        # windows are visited once and were its largest error. Train on them, with a little noise so that
        # other sample rates and pitches (other window alignments) stay covered.
        starts = window_starts(scene, band, window)
        m = min(len(x0), int(cfg.start_share * len(x0)))
        pick = starts[np.arange(m) % len(starts)]
        jitter = rng.normal(0, 1, pick.shape) * sampler.sd * 0.2
        jitter[: len(starts)] = 0.0
        x0[:m] = pick + jitter
    tau, x = fdm_windows(scene, x0, window, cfg.data_times, cfg.data_oversample,
                         on_progress=lambda f: report(f"FDM data: {len(x0)} windows at x{cfg.data_oversample}", f))
    lin = physics.rest_linearisation(scene.beta, scene.vb, scene.a) if cfg.net.rest_linear else None
    return TrainingData(band, domain, sampler, x0, tau, x,
                        correction_scale(x0, tau, x, window, cfg.net, lin=lin))


def correction_scale(x0, tau, x, window: float, net: NetConfig, gain=None, lin=None) -> np.ndarray:
    """c (2,): the RMS of what friction adds to the net's linear part over a window, per s (and per unit of a range
    model's gain (B,)); lin: the rest-state linearisation the flow carries (NetConfig.rest_linear)."""
    m11, m12, m21, m22, kq, kp = (c[None, :] for c in linear_part(net, tau, lin))
    lq, lp = m11 * x0[:, 0:1] + m12 * x0[:, 1:2] + kq, m21 * x0[:, 0:1] + m22 * x0[:, 1:2] + kp
    corr = (x - np.stack([lq, lp], -1))[:, 1:] / (tau[1:] / window)[None, :, None]
    if gain is not None:
        corr = corr / np.asarray(gain, float)[:, None, None]
    return np.sqrt(np.mean(corr ** 2, axis=(0, 1))).clip(1e-6)


class RangeSampler:
    """Draws (state, bow) pairs near the band of a range: a band state with the bow it was visited under (each
    render's onset as likely as its limit cycle, see ranges.range_band), the state jittered like StateSampler's and
    the bow by PARAM_JITTER of the box (log beta), kept inside the box and the state domain."""

    PARAM_JITTER = 0.02

    def __init__(self, band, domain: Domain, margin: float, box, rng: np.random.Generator):
        self.band, self.domain, self.box, self.rng = band, domain, box, rng
        self.sd = margin * (band.states.max(0) - band.states.min(0)).clip(1e-3) / 2
        self.cdf = np.cumsum(band.weights) / band.weights.sum()
        lo = np.array([math.log(max(box.beta_lo, 1e-12)), box.vb_lo])
        hi = np.array([math.log(max(box.beta_hi, 1e-12)), box.vb_hi])
        self.lo, self.hi = lo, hi

    def on_band(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """n (state, bow) pairs of the band, weighted as __call__ draws them, not jittered: what renders visit."""
        idx = band_draw(self.cdf, self.rng, n)
        return self.band.states[idx].copy(), self.band.params[idx].copy()

    def __call__(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        xs, ps, have = [], [], 0
        while have < n:
            idx = band_draw(self.cdf, self.rng, 2 * n)
            x = self.band.states[idx] + self.rng.normal(0, 1, (2 * n, 2)) * self.sd
            u = np.stack([np.log(np.maximum(self.band.params[idx, 0], 1e-12)), self.band.params[idx, 1]], 1)
            u = np.clip(u + self.rng.normal(0, 1, u.shape) * self.PARAM_JITTER * (self.hi - self.lo), self.lo, self.hi)
            keep = self.domain.contains(x[:, 0], x[:, 1])
            xs.append(x[keep])
            ps.append(np.stack([np.exp(u[keep, 0]), u[keep, 1]], 1))
            have += int(keep.sum())
        return np.concatenate(xs)[:n], np.concatenate(ps)[:n]


def build_range(scene: Scene, box, cfg: TrainConfig, window: float, rng: np.random.Generator,
                on_progress=None) -> TrainingData:
    """The data of a range model: renders from rest at cfg.range_points bows of the box and cfg.range_gestures
    straight-line gestures through it (ranges.range_band, at the scene's pitch and rate), the state domain around
    all of them, and FDM windows from (state, bow) pairs near that band, a share of them where the renders start
    their windows."""
    from .ranges import distinct, range_band

    report = on_progress or (lambda phase, frac: None)
    # bow stops only where the box holds bows that stop the mass; a box of zero width (a bow refined from a range
    # model) is one bow: one render, no gestures
    stops = cfg.range_stops if not box.is_point and box.vb_lo < physics.vb_stop(box.a) else 0
    report(f"range band: {cfg.range_points} renders from rest, {cfg.range_gestures} gestures, {stops} bow stops", 0.0)
    band = range_band(box, distinct(box.sample(cfg.range_points, rng)), scene.f0, scene.sample_rate,
                      cfg.band_seconds, window, gestures=0 if box.is_point else cfg.range_gestures, rng=rng,
                      stride=cfg.range_band_stride, stops=stops)
    domain = make_domain(scene, band.states, window, cfg.margin, box_only=cfg.sampling == "box")
    lb = (math.log(max(box.beta_lo, 1e-12)) + math.log(max(box.beta_hi, 1e-12))) / 2
    domain.beta, domain.vb = math.exp(lb), (box.vb_lo + box.vb_hi) / 2
    domain.box = [box.beta_lo, box.beta_hi, box.vb_lo, box.vb_hi]
    sampler = RangeSampler(band, domain, cfg.margin, box, rng)
    n = cfg.range_n_data
    x0, par = sampler(n)
    if cfg.start_share > 0:  # where renders from rest start their windows (see build), with their bows
        m = min(n, int(cfg.start_share * n))
        pick = band.starts[rng.integers(0, len(band.starts), m)]
        x0[:m] = pick[:, :2] + rng.normal(0, 1, (m, 2)) * sampler.sd * 0.2
        par[:m] = pick[:, 2:]
        ok = domain.contains(x0[:m, 0], x0[:m, 1])
        x0[:m][~ok] = pick[~ok, :2]
    tau, x = fdm_windows(scene, x0, window, cfg.data_times, cfg.data_oversample, par=par,
                         on_progress=lambda f: report(f"FDM data: {n} windows at x{cfg.data_oversample}", f))
    gain = par[:, 0] / domain.beta if cfg.range_corr_beta else None
    c = correction_scale(x0, tau, x, window, cfg.net, gain)
    return TrainingData(band.states, domain, sampler, x0, tau, x, c, par=par, box=box, extents=band.extents)
