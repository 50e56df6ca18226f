"""The trained operator in numpy, without torch: the branch and trunk weights as arrays, and the trunk evaluated once
per pitch at the samples' offsets inside a window (the bases every loop multiplies)."""

from __future__ import annotations

import math

import numpy as np

from ...errors import DomainError
from . import npnet
from .modelfile import OperatorModel


LINE_FLOATS = 16  # float32 values in a 64-byte cache line


def whole_lines(n: int) -> int:
    """n floats rounded up to whole 64-byte lines: a row of that length keeps the next row on a line too."""
    return -(-n // LINE_FLOATS) * LINE_FLOATS


def lined(a) -> np.ndarray:
    """a as a C-ordered float32 array that starts on a 64-byte line. The compiled products load 8 or 16 floats at
    a time along a weight row: an array 16 or 48 bytes past a line (where safetensors' buffers and numpy's copies
    fall) split every other load, or every one, across two lines (64 voices 2688-3287x by the process, 3602-3955x
    with the weights and bases on lines: docs/BENCHMARKS.md, "Weights on 64-byte lines and in panels")."""
    a = np.asarray(a, dtype=np.float32)
    buf = np.empty(a.size + LINE_FLOATS, np.float32)
    start = (-buf.ctypes.data // 4) % LINE_FLOATS
    out = buf[start:start + a.size].reshape(a.shape)
    out[...] = a
    return out


class NumpyOperator:
    """The trained network's weights as float32 numpy arrays (the precision it was trained in), laid out for the
    rollout loops (numpy in rollout._roll_numpy, compiled in src/core/rollout.cpp)."""

    def __init__(self, model: OperatorModel):
        w = model.weights
        self.cfg = cfg = model.cfg
        self._w = w
        f32 = lined
        g = lambda name: (f32(w[f"branch.{name}.weight"].T), f32(w[f"branch.{name}.bias"]))  # noqa: E731
        rest = [g(f"hidden.{i}") for i in range(1, cfg.depth)]
        width = cfg.width
        self.ff = np.ascontiguousarray(2 * np.pi * w["branch.ff.B"].astype(np.float64))
        gates = [g(name) for name in ("U", "V", "hidden.0")]  # one product for the three (src/core/rollout.cpp: gates)
        self.weights = (f32(np.hstack([m for m, _ in gates])), f32(np.concatenate([b for _, b in gates])),
                        f32(np.array([m for m, _ in rest]).reshape(-1, width, width)),
                        f32(np.array([b for _, b in rest]).reshape(-1, width)), *g("out"))
        d64 = lambda name: w[name].astype(np.float64)  # noqa: E731
        self.center, self.halfrange = d64("center"), d64("halfrange")
        self.corr_scale, self.window, self.bias = d64("corr_scale"), float(w["window"]), d64("bias")
        self.lin = tuple(float(v) for v in w["lin"]) if cfg.rest_linear else None  # (d, q_s), see NetConfig
        self._model = model  # for its trunk grid (trunk_grid)

    def window_inputs(self, par: np.ndarray) -> tuple[np.ndarray, ...]:
        """Bows (B, W, 2) (beta, v_B) per window -> the loops' pin (B, W, n_par), gain (B, W) and the state's
        scaling center, halfrange (B, W, 2) (npnet.state_scaling), float64."""
        B, W = par.shape[:2]
        if not self.cfg.params:
            c = np.ascontiguousarray(np.broadcast_to(self.center, (B, W, 2)))
            h = np.ascontiguousarray(np.broadcast_to(self.halfrange, (B, W, 2)))
            return np.zeros((B, W, 0)), np.ones((B, W)), c, h
        flat = par.reshape(-1, 2)
        pin = npnet.param_inputs(self._w, flat)
        c, h = npnet.state_scaling(self._w, self.cfg, pin)
        f = lambda a, *shape: np.ascontiguousarray(np.reshape(a, (B, W, *shape)))  # noqa: E731
        return f(pin, -1), f(npnet.gain(self._w, self.cfg, flat[:, 0])), f(c, 2), f(h, 2)

    def trunk_features(self, s_list: list) -> list:
        """The trunk features (M, 2, k) at each array of window fractions (0..2) in s_list, float64.

        Up to DIRECT_POINTS points in all (a note or two), evaluated directly; beyond, by cubic interpolation from the
        model's trunk grid (trunk_grid: evaluated once, kept on disk). A score at 21 pitches needs ~3,800 points: the
        width-128 trunk took 90 ms of its process at each run, the grid's interpolation ~5 ms. The trunk is smooth in
        s (Fourier features of scale sigma_trunk): measured interpolation error below 1e-9 of the features' size, far
        below float32 rounding (tests/test_kernels.py checks it).
        """
        if sum(len(a) for a in s_list) <= DIRECT_POINTS:
            f = npnet.trunk_features(self._w, self.cfg, np.concatenate(s_list))
            return np.split(f, np.cumsum([len(a) for a in s_list])[:-1])
        grid = trunk_grid(self._model).reshape(TRUNK_POINTS, -1)
        h = TRUNK_H
        out = []
        for s in s_list:  # cubic Lagrange interpolation on the uniform grid (nodes i - 1 .. i + 2)
            u = s / h + 1
            i = np.clip(np.floor(u).astype(np.int64), 1, TRUNK_POINTS - 3)
            t = u - i
            w = np.stack([-t * (t - 1) * (t - 2) / 6, (t + 1) * (t - 1) * (t - 2) / 2,
                          -(t + 1) * t * (t - 2) / 2, (t + 1) * t * (t - 1) / 6], axis=1)
            f = np.einsum("mj,mjc->mc", w, grid[i[:, None] + np.arange(-1, 3)])
            out.append(f.reshape(len(s), 2, -1))
        return out

    def samples_per_window(self, dtau: float, window: float | None = None) -> float:
        """Samples per window at spacing dtau: the trained window T, or a shorter `window` (in tau; see
        windows.locked_window)."""
        spw = (self.window if window is None else window) / dtau
        if abs(spw - round(spw)) < 1e-9 * spw:  # a whole number of samples, up to rounding: every window alike
            spw = float(round(spw))
        return spw

    def window_basis(self, dtau: float, tf: np.ndarray | None = None, window: float | None = None):
        """The output side of the windows of a render whose samples are dtau apart in tau, each window T long (or
        `window` <= T: the trunk is then read at s < 1 only).

        A window holds n_lo = floor(T / dtau) or n_hi = ceil(T / dtau) samples (windows.window_end: window w starts
        at the sample nearest w T; at a pitch where T / dtau is not a whole number, windows of n_lo samples alone
        would start ever earlier than the states the model trained on, measured 2.6x the error at 200 Hz). A window
        of n_hi samples runs past T by less than one sample spacing.
        Returns spw = T / dtau, n_lo; Bq, Bp (k + 3, n_hi) float32: the trunk features times s c at the sample
        offsets, then cos, sin and the bias term (see src/core/rollout.cpp: samples); for the end state after n_lo and after
        n_hi samples, in float64, the features endb (2, 2, k) and endlin (2, 6) = (m11, m12, bias_q, bias_p, m22,
        -m21) of the linear flow M (the rotation: cos, sin, ..., cos, sin; see physics.flow_coefficients).
        The trunk is evaluated in numpy, float64 (once per render and pitch); tf: its features at the offsets
        j dtau / T, j <= n_hi, if already computed (trunk_features).
        """
        spw = self.samples_per_window(dtau, window)
        n_lo, n_hi = math.floor(spw), math.ceil(spw)
        tau = np.arange(n_hi + 1) * dtau
        s = tau / self.window
        if tf is None or len(tf) != n_hi + 1:
            tf = self.trunk_features([s])[0]  # (n_hi+1, 2, k)
        basis = np.transpose(tf, (1, 2, 0)) * (s * self.corr_scale[:, None])[:, None, :]  # (2, k, n_hi+1)
        bias = self.bias[:, None] * self.corr_scale[:, None] * s[None, :]  # (2, n_hi+1)
        m11, m12, m21, m22, kq, kp = npnet.linear_part(self.cfg, tau, self.lin)
        # q rows act on (q0, p0), p rows on (p0, -q0) (src/core/rollout.cpp: samples); the flow's constant joins the bias row
        # (a point model's gain is 1)
        bias = bias + np.stack([kq, kp])
        lin = ((m11, m12), (m22, -m21))
        rows = lambda i: np.ascontiguousarray(  # noqa: E731
            np.vstack([basis[i, :, :n_hi], lin[i][0][:n_hi], lin[i][1][:n_hi], bias[i, :n_hi]]), dtype=np.float32)
        ends = (n_lo, n_hi)
        endb = np.ascontiguousarray(np.stack([basis[:, :, e] for e in ends]))
        endlin = np.array([[m11[e], m12[e], bias[0, e], bias[1, e], m22[e], -m21[e]] for e in ends])
        return spw, n_lo, rows(0), rows(1), endb, endlin


def numpy_operator(model: OperatorModel) -> NumpyOperator:
    op = model.__dict__.get("_numpy_op")
    if op is None:  # weights don't change after loading: convert once per model
        op = model.__dict__["_numpy_op"] = NumpyOperator(model)
    return op


def window_bases(model: OperatorModel, keys):
    """The window bases (NumpyOperator.window_basis) of the distinct (sample spacing, window) pairs `keys` (the
    window in tau, or None for the trained T), stacked and padded to the longest window: spw (P,), n_lo (P,), Bq, Bp
    (P, k + 3, n_max), endb (P, 2, 2, k), endlin (P, 2, 6). Cached per model: the last stack, and each pair's basis."""
    key = tuple((float(d), None if w is None else float(w)) for d, w in keys)
    last = model.__dict__.get("_stack")
    if last is not None and last[0] == key:
        return last[1]
    op = numpy_operator(model)
    cache = model.__dict__.setdefault("_basis_cache", {})
    new = [dw for dw in key if dw not in cache]
    if new:  # one trunk evaluation for every new pitch
        offsets = [np.arange(math.ceil(op.samples_per_window(d, w)) + 1) * d / op.window for d, w in new]
        for (d, w), tf in zip(new, op.trunk_features(offsets)):
            cache[(d, w)] = op.window_basis(d, tf, w)
    parts = [cache[d] for d in key]
    if min(p[1] for p in parts) < 1:
        raise DomainError(f"the model's window ({op.window:.3g} in tau) is shorter than one sample")
    # rows of whole 64-byte lines, on a line (lined): the windows' products load a row 8 or 16 floats at a time
    n_max = whole_lines(max(p[2].shape[1] for p in parts))
    k3 = parts[0][2].shape[0]
    Bq = lined(np.zeros((len(parts), k3, n_max), np.float32))
    Bp = lined(np.zeros((len(parts), k3, n_max), np.float32))
    for i, p in enumerate(parts):
        Bq[i, :, :p[2].shape[1]] = p[2]
        Bp[i, :, :p[3].shape[1]] = p[3]
    stack = (np.array([p[0] for p in parts]), np.array([p[1] for p in parts], np.int64), Bq, Bp,
             np.ascontiguousarray(np.stack([p[4] for p in parts])), np.ascontiguousarray(np.stack([p[5] for p in parts])))
    model.__dict__["_stack"] = (key, stack)
    return stack


DIRECT_POINTS = 1024  # trunk points evaluated directly (a note at 43 Hz); more come from the grid
# The trunk grid, shared by the offline bases and the live voices (bank.VoiceBank): window fractions s = (i - 1) h,
# up to n_hi / spw < 1 + 1 / spw <= 2, spacing h ~2.4e-4 of a window (cubic interpolation error ~1e-9)
TRUNK_POINTS = 8192
TRUNK_H = 2.0 / (TRUNK_POINTS - 3)
TRUNK_CACHE_VERSION = 1  # raise when npnet.trunk_features changes what a model's weights compute


def trunk_grid(model: OperatorModel) -> np.ndarray:
    """The model's trunk features at s = (i - 1) TRUNK_H, i < TRUNK_POINTS: (TRUNK_POINTS, 2, k) float64. Once per
    process and model, and kept on disk by the model's id (`io.cache`: 8 MB at 64 features; evaluating it takes
    ~0.2 s at width 128), so that a score or a live start does not evaluate the network at every sample offset."""
    g = model.__dict__.get("_trunk_grid")
    if g is not None:
        return g
    from ...io.cache import read_array, write_array

    k = model.cfg.k
    name = f"trunk-{TRUNK_CACHE_VERSION}-{TRUNK_POINTS}-{model.id.replace('/', '_')}"
    g = read_array(name, (TRUNK_POINTS, 2, k))
    if g is not None:  # a copy edited or damaged on disk is not trusted: 16 rows checked against the network (~1 ms)
        i = np.linspace(0, TRUNK_POINTS - 1, 16).astype(np.int64)
        want = npnet.trunk_features(model.weights, model.cfg, (i - 1.0) * TRUNK_H)
        if not np.abs(g[i] - want).max() <= 1e-9 * np.abs(want).max():
            g = None
    if g is None:
        g = npnet.trunk_features(model.weights, model.cfg, (np.arange(TRUNK_POINTS) - 1.0) * TRUNK_H)
        write_array(name, g)
    g.setflags(write=False)
    model.__dict__["_trunk_grid"] = g
    return g
