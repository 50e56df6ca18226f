"""Rolling render: the operator applied window to window, each window seeded by the previous window's end state.

The audio samples sit at fixed offsets tau_j = j w / sr inside every window, so the trunk features there are
computed once per render and pitch; a window then costs one branch evaluation and a small matmul. No torch here; the
loops run in numpy, or compiled (`kernels`, numba) when the work repays importing numba.
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

from . import npnet, physics
from .errors import DomainError, ModelFileError, UsageError
from .model import OperatorModel, load_model
from .render import Render
from .scene import Scene

SHIPPED_DIR = Path(__file__).resolve().parent / "models"  # inside the package: a wheel carries them
FAIL_NONFINITE, FAIL_DOMAIN = 1, 2  # why a voice stopped (the compiled loops in `kernels` write the same codes)
FAIL_BOW = 3  # the bow left the model's range (found before the rollout, from the scene's curves)
FAILURES = {FAIL_NONFINITE: "the rollout turned non-finite",
            FAIL_DOMAIN: "the rollout left the model's trained states",
            FAIL_BOW: "the bow left the model's range"}


def model_dirs() -> list[Path]:
    dirs = [Path.cwd() / "models", SHIPPED_DIR]
    out = []
    for d in dirs:
        if d.is_dir() and d.resolve() not in [o.resolve() for o in out]:
            out.append(d)
    return out


def model_path(name) -> Path:
    """A model file given as a path, or by its name in ./models or the shipped models (`soft-range`): what
    `--model` and `train --from` take."""
    path = Path(name)
    if path.exists() or path.suffix or len(path.parts) > 1:
        return path
    for d in model_dirs():
        if (d / f"{name}.safetensors").is_file():
            return d / f"{name}.safetensors"
    names = sorted({f.stem for d in model_dirs() for f in d.glob("*.safetensors")})
    raise ModelFileError(f"model {name} not found: no such file, and no model of that name in ./models or the "
                         f"shipped models ({', '.join(names) or 'none'})")


def as_model(model) -> OperatorModel:
    """An OperatorModel as given, or read from a file path or a model's name (model_path)."""
    return model if isinstance(model, OperatorModel) else load_model(model_path(model))


# Model files read in this process, by resolved path: (size, mtime_ns) when read, and the model or why it failed to
# load. A file is read again only when its size or modification time changes, so `render_operator(scene)` with no
# model costs a few stat calls, not a load per call (measured ~110-160 ms per call with torch before).
_SCANNED: dict = {}


def scan_models() -> list[tuple[Path, OperatorModel | None, str | None]]:
    """Every model file in ./models and the shipped ones: (path, model, None) or (path, None, why it is unreadable).
    Models are shared by all callers in this process: do not modify them."""
    found = []
    for d in model_dirs():
        for p in sorted(d.glob("*.safetensors")):
            if p.name.endswith(".ckpt.safetensors"):
                continue
            try:
                st = p.stat()
            except OSError:
                continue
            key, stamp = p.resolve(), (st.st_size, st.st_mtime_ns)
            hit = _SCANNED.get(key)
            if hit is None or hit[0] != stamp:
                try:
                    hit = (stamp, load_model(p), None)
                except ModelFileError as e:
                    hit = (stamp, None, str(e))
                _SCANNED[key] = hit
            found.append((p, hit[1], hit[2]))
    return found


RATIO_F0 = 100.0  # the rate a model's ratio is measured at: its window chain does not depend on f0, only the samples
RATIO_PERIODS = 300  # sounding periods measured after the truth's settling time


def operator_ratio(model):
    """The sounding ratio of a trained operator, as `pitch.tune(ratio=...)` takes it: the model rolled out from rest
    at the bow until the truth's settling time plus RATIO_PERIODS periods, its pitch over those periods. A model's
    window chain depends on (beta, v_B) only, so one measurement per model and bow serves every pitch (cached on disk
    with the model's id)."""
    from . import pitch as P
    from .metrics import f0_estimate

    m = as_model(model)

    def ratio(beta: float, vb: float, a: float, f0: float) -> float:
        def measure():
            truth = P.sounding_ratio(beta, vb, a)
            seconds = min((truth.settle_periods + RATIO_PERIODS / truth.r) / RATIO_F0, 60.0)
            sc = Scene(f0=RATIO_F0, fb=beta * physics.omega(RATIO_F0), vb=vb, a=a, duration=seconds)
            r = render_operator(sc, model=m)
            tail = r.q[-int(RATIO_PERIODS / (truth.r * RATIO_F0) * sc.sample_rate):]
            return f0_estimate(tail, sc.sample_rate, tail=1.0) / RATIO_F0
        return P.engine_ratio(f"operator{RATIO_PERIODS} {m.id}", beta, vb, a, measure)
    return ratio


def unreadable_notes() -> list[str]:
    """One line per model file the default lookup skipped because it cannot be used (damaged, foreign, forged)."""
    return [f"note: skipped {p}: {why.replace(str(p), p.name)}" for p, m, why in scan_models() if m is None]


def available_models() -> list[OperatorModel]:
    """The readable models (./models first, then the shipped ones), including those whose validation failed."""
    return [m for _, m, _ in scan_models() if m is not None]


def train_hint(scene: Scene) -> str:
    """The `bowsynth train` command whose model would cover the scene (a range for a scene whose bow moves)."""
    from .controls import bounds

    def arg(v):
        lo, hi = bounds(v)
        return f"{lo:g}" if lo == hi else f"{lo:g}:{hi:g}"
    return (f"bowsynth train --fb {arg(scene.fb)} --f0 {arg(scene.f0)} --vb {arg(scene.vb)} --a {scene.a:g}"
            + (f" --q0 {scene.q0:g} --p0 {scene.p0:g}" if scene.q0 or scene.p0 else ""))


def first_bow_outside(model: OperatorModel, scene: Scene) -> tuple[float, str] | None:
    """Where the scene's bow first leaves the model's range, in the windows the operator would play it: (time in s,
    'F_B = ... at t = ...' naming the parameter and value), or None if it never does."""
    spw = _operator(model).samples_per_window(scene.dtau)
    out = _bow_exit(model, scene, spw, scene_bows(scene, spw))
    return None if out is None else (out[1] / scene.sample_rate, out[2])


def _bow_exit(model: OperatorModel, scene: Scene, spw: float, bows: np.ndarray) -> tuple[int, int, str] | None:
    """The first window whose bow (of `bows`, scene_bows) is outside the model's range: (window, its first sample,
    what left and when), or None."""
    d = model.domain
    bad = np.flatnonzero(~d.box_contains(bows[:, 0], bows[:, 1]))
    if not bad.size:
        return None
    w = int(bad[0])
    start = int(window_bounds(spw, scene.n_samples)[0][w])
    t = start / scene.sample_rate
    beta, vb = bows[w]
    v_in = d.vb if d.box is None else min(max(vb, d.box[2]), d.box[3])  # v_B moved inside: does beta alone leave?
    if not d.box_contains(beta, v_in):
        return w, start, f"F_B = {beta * scene.omega:.4g} (F_B / w {beta:.4g}) at t = {t:.3f} s"
    return w, start, f"v_B = {vb:.4g} at t = {t:.3f} s"


def find_model(scene: Scene, models: list[OperatorModel] | None = None) -> OperatorModel:
    """The best validated model (lowest validation NMSE(p); ./models before the shipped ones on a tie) among those
    (found, or the given list) that cover the scene. A model whose validation failed is never picked here (see
    model.validation_failure): pass it explicitly to use it. Otherwise a DomainError says which models come nearest
    and how to train one that covers the scene."""
    if models is None:
        models = available_models()
    covering = [m for m in models if m.covers(scene)]
    good = [m for m in covering if m.failure is None]
    if good:
        return min(good, key=lambda m: m.meta.validation["nmse"])  # min keeps the first of equals
    if covering:
        bad = "; ".join(f"{m.path or m.meta.name} ({m.failure})" for m in covering)
        raise DomainError(f"the models that cover this scene failed their validation: {bad}. Pass one with --model "
                          f"to use it anyway, train longer with `{train_hint(scene)} --minutes 10`, or render with "
                          f"--method fdm")

    (blo, bhi), (vlo, vhi) = scene.beta_range, scene.vb_range

    def dist(m):
        d = m.domain
        b0, b1, v0, v1 = d.box if d.box else (d.beta, d.beta, d.vb, d.vb)
        db = max(0.0, math.log(max(b0, 1e-9) / max(blo, 1e-9)), math.log(max(bhi, 1e-9) / max(b1, 1e-9)))
        return db + max(0.0, v0 - vlo, vhi - v1) + abs(math.log(scene.a / d.a))
    near = sorted(models, key=dist)[:3]

    def why(m):
        out = m.domain.mismatch(scene)
        where = first_bow_outside(m, scene) if m.domain.is_range else None
        if where:
            out = [f"{where[1]} leaves its {m.domain.describe_bows()}"] + [
                o for o in out if not o.startswith(("F_B", "v_B"))]
        return ", ".join(out)
    lines = "; ".join(f"{m.path.name if m.path else m.meta.name} ({why(m)})" for m in near) or "none found"
    bow = (f"F_B / w = {_span(blo, bhi)}, v_B = {_span(vlo, vhi)}")
    raise DomainError(f"no model covers this scene ({bow}, a = {scene.a:g}); nearest: {lines}. Train one with "
                      f"`{train_hint(scene)}`, or render with --method fdm (or --fallback fdm)")


def _span(lo: float, hi: float) -> str:
    return f"{lo:.4g}" if lo == hi else f"{lo:.4g}..{hi:.4g}"


def partial_model(scene: Scene, models: list[OperatorModel] | None = None):
    """For --fallback fdm when no model covers the whole scene: the validated model that plays its opening longest
    (the start state and first bow inside, the bow leaving later), and the time it leaves; or None."""
    if models is None:
        models = available_models()
    best = None
    for m in models:
        if m.failure is not None or not m.domain.is_range or not m.domain.contains(scene.q0, scene.p0):
            continue
        if not math.isclose(scene.a, m.domain.a, rel_tol=1e-6):
            continue
        where = first_bow_outside(m, scene)
        if where and where[0] > 0 and (best is None or where[0] > best[1]):
            best = (m, where[0])
    return best


class NumpyOperator:
    """The trained network's weights as float32 numpy arrays (the precision it was trained in), laid out for the
    rollout loops (numpy here, compiled in `kernels`)."""

    def __init__(self, model: OperatorModel):
        w = model.weights
        self.cfg = cfg = model.cfg
        self._w = w
        f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
        g = lambda name: (f32(w[f"branch.{name}.weight"].T), f32(w[f"branch.{name}.bias"]))  # noqa: E731
        rest = [g(f"hidden.{i}") for i in range(1, cfg.depth)]
        width = cfg.width
        self.ff = np.ascontiguousarray(2 * np.pi * w["branch.ff.B"].astype(np.float64))
        gates = [g(name) for name in ("U", "V", "hidden.0")]  # one product for the three (kernels.roll_voices)
        self.weights = (f32(np.hstack([m for m, _ in gates])), f32(np.concatenate([b for _, b in gates])),
                        f32(np.array([m for m, _ in rest]).reshape(-1, width, width)),
                        f32(np.array([b for _, b in rest]).reshape(-1, width)), *g("out"))
        d64 = lambda name: w[name].astype(np.float64)  # noqa: E731
        self.center, self.halfrange = d64("center"), d64("halfrange")
        self.corr_scale, self.window, self.bias = d64("corr_scale"), float(w["window"]), d64("bias")
        self.lin = tuple(float(v) for v in w["lin"]) if cfg.rest_linear else None  # (d, q_s), see NetConfig

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
        """The trunk features (M, 2, k) at each array of window fractions in s_list, float64.

        Up to TRUNK_GRID points in all, evaluated directly; beyond, by cubic interpolation from TRUNK_GRID points
        evaluated once (a score at 100 pitches needs ~33,000 points: evaluating them took ~10x longer). The trunk is
        smooth in s (Fourier features of scale sigma_trunk): measured interpolation error below 1e-9 of the features'
        size, far below float32 rounding (tests/test_kernels.py checks it).
        """
        if sum(len(a) for a in s_list) <= TRUNK_GRID:
            f = npnet.trunk_features(self._w, self.cfg, np.concatenate(s_list))
            return np.split(f, np.cumsum([len(a) for a in s_list])[:-1])
        h = max(a.max() for a in s_list) / (TRUNK_GRID - 3)
        grid = npnet.trunk_features(self._w, self.cfg, (np.arange(TRUNK_GRID) - 1) * h).reshape(TRUNK_GRID, -1)
        out = []
        for s in s_list:  # cubic Lagrange interpolation on the uniform grid (nodes i - 1 .. i + 2)
            u = s / h + 1
            i = np.clip(np.floor(u).astype(np.int64), 1, TRUNK_GRID - 3)
            t = u - i
            w = np.stack([-t * (t - 1) * (t - 2) / 6, (t + 1) * (t - 1) * (t - 2) / 2,
                          -(t + 1) * t * (t - 2) / 2, (t + 1) * t * (t - 1) / 6], axis=1)
            f = np.einsum("mj,mjc->mc", w, grid[i[:, None] + np.arange(-1, 3)])
            out.append(f.reshape(len(s), 2, -1))
        return out

    def samples_per_window(self, dtau: float) -> float:
        spw = self.window / dtau
        if abs(spw - round(spw)) < 1e-9 * spw:  # a whole number of samples, up to rounding: every window alike
            spw = float(round(spw))
        return spw

    def window_basis(self, dtau: float, tf: np.ndarray | None = None):
        """The output side of the windows of a render whose samples are dtau apart in tau.

        A window holds n_lo = floor(T / dtau) or n_hi = ceil(T / dtau) samples (kernels.window_end: window w starts
        at the sample nearest w T; at a pitch where T / dtau is not a whole number, windows of n_lo samples alone
        would start ever earlier than the states the model trained on, measured 2.6x the error at 200 Hz). A window
        of n_hi samples runs past T by less than one sample spacing.
        Returns spw = T / dtau, n_lo; Bq, Bp (k + 3, n_hi) float32: the trunk features times s c at the sample
        offsets, then cos, sin and the bias term (see kernels.roll_voices); for the end state after n_lo and after
        n_hi samples, in float64, the features endb (2, 2, k) and endlin (2, 6) = (m11, m12, bias_q, bias_p, m22,
        -m21) of the linear flow M (the rotation: cos, sin, ..., cos, sin; see physics.flow_coefficients).
        The trunk is evaluated in numpy, float64 (once per render and pitch); tf: its features at the offsets
        j dtau / T, j <= n_hi, if already computed (trunk_features).
        """
        spw = self.samples_per_window(dtau)
        n_lo, n_hi = math.floor(spw), math.ceil(spw)
        tau = np.arange(n_hi + 1) * dtau
        s = tau / self.window
        if tf is None or len(tf) != n_hi + 1:
            tf = self.trunk_features([s])[0]  # (n_hi+1, 2, k)
        basis = np.transpose(tf, (1, 2, 0)) * (s * self.corr_scale[:, None])[:, None, :]  # (2, k, n_hi+1)
        bias = self.bias[:, None] * self.corr_scale[:, None] * s[None, :]  # (2, n_hi+1)
        m11, m12, m21, m22, kq, kp = npnet.linear_part(self.cfg, tau, self.lin)
        # q rows act on (q0, p0), p rows on (p0, -q0) (kernels._samples); the flow's constant joins the bias row
        # (a point model's gain is 1)
        bias = bias + np.stack([kq, kp])
        lin = ((m11, m12), (m22, -m21))
        rows = lambda i: np.ascontiguousarray(  # noqa: E731
            np.vstack([basis[i, :, :n_hi], lin[i][0][:n_hi], lin[i][1][:n_hi], bias[i, :n_hi]]), dtype=np.float32)
        ends = (n_lo, n_hi)
        endb = np.ascontiguousarray(np.stack([basis[:, :, e] for e in ends]))
        endlin = np.array([[m11[e], m12[e], bias[0, e], bias[1, e], m22[e], -m21[e]] for e in ends])
        return spw, n_lo, rows(0), rows(1), endb, endlin


def _operator(model: OperatorModel) -> NumpyOperator:
    op = model.__dict__.get("_numpy_op")
    if op is None:  # weights don't change after loading: convert once per model
        op = model.__dict__["_numpy_op"] = NumpyOperator(model)
    return op


def _bases(model: OperatorModel, dtaus: np.ndarray):
    """The window bases (NumpyOperator.window_basis) of the distinct sample spacings `dtaus`, stacked and padded to
    the longest window: spw (P,), n_lo (P,), Bq, Bp (P, k + 3, n_max), endb (P, 2, 2, k), endlin (P, 2, 6).
    Cached per model: the last stack, and each spacing's basis."""
    key = tuple(float(d) for d in dtaus)
    last = model.__dict__.get("_stack")
    if last is not None and last[0] == key:
        return last[1]
    op = _operator(model)
    cache = model.__dict__.setdefault("_basis_cache", {})
    new = [d for d in key if d not in cache]
    if new:  # one trunk evaluation for every new pitch
        offsets = [np.arange(math.ceil(op.samples_per_window(d)) + 1) * d / op.window for d in new]
        for d, tf in zip(new, op.trunk_features(offsets)):
            cache[d] = op.window_basis(d, tf)
    parts = [cache[d] for d in key]
    if min(p[1] for p in parts) < 1:
        raise DomainError(f"the model's window ({op.window:.3g} in tau) is shorter than one sample")
    n_max = max(p[2].shape[1] for p in parts)
    k3 = parts[0][2].shape[0]
    Bq = np.zeros((len(parts), k3, n_max), np.float32)
    Bp = np.zeros((len(parts), k3, n_max), np.float32)
    for i, p in enumerate(parts):
        Bq[i, :, :p[2].shape[1]] = p[2]
        Bp[i, :, :p[3].shape[1]] = p[3]
    stack = (np.array([p[0] for p in parts]), np.array([p[1] for p in parts], np.int64), Bq, Bp,
             np.ascontiguousarray(np.stack([p[4] for p in parts])), np.ascontiguousarray(np.stack([p[5] for p in parts])))
    model.__dict__["_stack"] = (key, stack)
    return stack


TRUNK_GRID = 4096
BATCH_FROM = 8  # compiled loops: from this many voices on, the window-at-a-time loop with BLAS products is faster
# numba costs ~0.3 s to import and ~0.5 s more on the first call of a cached loop in a process (typing machinery and
# the cache's code loaded; measured at load ~4-5 on the shared 2-core machine), more than the whole numpy rollout of
# most renders (a 5 s note at 100 Hz: 0.044 s in numpy, ~0.01 s compiled; 100 voices x 5 s at 100 pitches: 0.81 s in
# numpy, 0.58 s compiled). So the compiled loops run only where the numpy loop's estimated time exceeds
# NUMBA_PAYS_FROM, or once numba is imported (a process that ran the FDM: a notebook, training's validation, bench,
# where the first call's 0.5 s is repaid by every later render). docs/BENCHMARKS.md, issue 12.
NUMBA_PAYS_FROM = 1.0


def _numpy_seconds(rounds: int, voice_windows: int, voice_samples: int) -> float:
    """Estimated time of `_roll_numpy` (fitted on the shared machine at load ~5: 1 voice x 5 s 0.044 s, 100 voices
    at 100 pitches x 1 s 0.16 s, x 5 s 0.81 s; importing numba and loading the loops took 0.39 s there)."""
    return 80e-6 * rounds + 6e-6 * voice_windows + 15e-9 * voice_samples


def numba_loaded() -> bool:
    """Has this process already paid numba's import (the FDM ran, or a compiled rollout)? Then compiled loops cost
    only their own cache load (~10 ms), and every later render or release repays it."""
    return "numba" in sys.modules


def choose_loop(model: OperatorModel, n_samples: int, dtau) -> str:
    """'numba' when numba is already imported or the numpy loop's estimated time repays loading it, else 'numpy'."""
    if numba_loaded():
        return "numba"
    spw = _operator(model).window / np.atleast_1d(np.asarray(dtau, dtype=float))
    slow = _numpy_seconds(int(n_samples / spw.min()) + 1, int(np.sum(n_samples / spw)) + len(spw), n_samples * len(spw))
    return "numba" if slow > NUMBA_PAYS_FROM else "numpy"


def max_windows(n_samples: int, spw) -> int:
    """Enough windows of spw samples (kernels.window_end) to pass n_samples, at the shortest spacing given."""
    return int(np.ceil((n_samples + 0.5) / np.min(spw))) + 1


def window_bounds(spw: float, n_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """(starts, ends) in samples of the windows that cover n_samples at spw samples per window (kernels.window_end)."""
    W = max_windows(n_samples, spw)
    ends = np.floor(np.arange(1, W + 1) * spw + 0.5).astype(np.int64)
    keep = int(np.searchsorted(ends, n_samples)) + 1  # the first window that reaches n_samples is the last
    ends = ends[:keep]
    return np.concatenate([[0], ends[:-1]]).astype(np.int64), ends


def scene_bows(scene: Scene, spw: float, n_samples: int | None = None) -> np.ndarray:
    """The bow (beta, v_B) the operator applies in each window of a render of the scene: the controls at the
    window's middle (held over the window: second order in the window length; held at its start the error of a
    crescendo is 200x larger, shared/GUIDE.md 8). (W, 2)."""
    starts, ends = window_bounds(spw, scene.n_samples if n_samples is None else n_samples)
    t = 0.5 * (starts + ends) / scene.sample_rate
    return np.stack([scene.fb_at(t) / scene.omega, scene.vb_at(t)], axis=1)


def applied_controls(scene: Scene, spw: float, bows: np.ndarray) -> dict:
    """Per output sample, the controls the operator applied (Render.controls): fb (m/s^2) and vb, piecewise constant
    per window."""
    n = scene.n_samples
    starts, ends = window_bounds(spw, n)
    lens = np.minimum(ends, n) - starts
    rep = lambda v: np.repeat(v[:len(lens)], lens)[:n]  # noqa: E731
    return {"fb": rep(bows[:, 0] * scene.omega), "vb": rep(bows[:, 1])}


def _window_bows(model: OperatorModel, B: int, W: int, params) -> np.ndarray:
    """params as (B, W, 2) bows per window: None (a range model's own centre; ignored by a point model), one bow for
    all, one per voice (B, 2), or per voice and window (B, W', 2), padded with each voice's last."""
    d = model.domain
    if params is None:
        params = [d.beta, d.vb]
    par = np.asarray(params, float)
    if par.ndim == 1:
        par = np.broadcast_to(par, (B, 2))
    if par.ndim == 2:
        par = np.broadcast_to(par[:, None, :], (B, W, 2))
    if par.shape[1] < W:
        par = np.concatenate([par, np.repeat(par[:, -1:], W - par.shape[1], axis=1)], axis=1)
    return par[:, :W]


def rollout_states(model: OperatorModel, x0: np.ndarray, n_samples: int, dtau, check_domain: bool = True,
                   loop: str = "auto", params=None):
    """Roll the operator from states x0 (B, 2) for n_samples samples spaced dtau in tau (one spacing for all voices,
    or one per voice: voices at different pitches roll in one batch).

    loop: 'numpy', 'numba' (the compiled loops of `kernels`), or 'auto' (numba when it is already imported or the
    work is long enough to repay importing it).
    Returns q, p (B, n_samples) float32 and fail (B, 2) int: per voice the first sample of the window where the
    rollout left the model's domain or went non-finite, and the reason (a key of FAILURES), or (-1, 0). A failed
    voice stops there (its later samples are NaN); the other voices go on.
    params: a range model's bows (beta, v_B): one (2,), per voice (B, 2) or per voice and window (B, W, 2) (see
    scene_bows); None plays the model's own (centre) bow. They are not checked against the model's box here.
    """
    x = np.array(x0, dtype=float).reshape(-1, 2)
    B = len(x)
    dt = np.broadcast_to(np.asarray(dtau, dtype=float), (B,))
    uniq, vidx = np.unique(dt, return_inverse=True)
    spw, n_lo, Bq, Bp, endb, endlin = _bases(model, uniq)
    vidx = np.ascontiguousarray(vidx, dtype=np.int64)
    op = _operator(model)
    q = np.empty((B, n_samples), np.float32)
    p = np.empty((B, n_samples), np.float32)
    fail = np.tile(np.array([-1, 0], np.int64), (B, 1))  # the loops write only the voices that fail
    d = model.domain
    W = max_windows(n_samples, spw)  # as many windows as the loops may start
    pin, gain, center, halfrange = op.window_inputs(_window_bows(model, B, W, params))
    args = (x, n_samples, spw, n_lo, vidx, Bq, Bp, endb, endlin, center, halfrange, op.ff, pin, gain, *op.weights,
            np.array([d.q_lo, d.q_hi, d.p_lo, d.p_hi]), np.ascontiguousarray(d.mask), bool(check_domain), q, p, fail)
    if loop == "auto":
        loop = choose_loop(model, n_samples, dt)
    if loop == "numba":
        from . import kernels

        (kernels.roll_batch if B >= BATCH_FROM else kernels.roll_voices)(*args)
    elif loop == "numpy":
        _roll_numpy(*args)
    else:
        raise ValueError(f"loop must be auto, numpy or numba, got {loop!r}")
    for b in np.flatnonzero(fail[:, 0] >= 0):
        q[b, fail[b, 0]:] = np.nan
        p[b, fail[b, 0]:] = np.nan
    return q, p, fail


BLOCK = 256  # windows per pass of the two-pass loops: bounds the stored branch outputs (B x BLOCK x 2k floats)


def _roll_numpy(x0, n_samples, spw, n_lo, vidx, Bq, Bp, endb, endlin, center, halfrange, ff, pin, gain, Gw, Gb, Hw,
                Hb, Ow, Ob, box, mask, check, q_out, p_out, fail):
    """kernels.roll_batch in numpy (same arguments, same float32 arithmetic up to rounding), in two passes per block
    of BLOCK windows.

    First the chain: every running voice one window at a time, the branch as matrix products over the voices, the
    end state from the window's last offset only (endb, endlin), keeping each window's start state and branch
    output. Then the samples, voice by voice: all of a voice's windows of the block in one matrix product with its
    pitch's basis. Writing samples inside the chain touches every pitch's basis once per window (23 MB for 100
    pitches: memory-bound), and per window numpy's call overhead outweighs a small product.
    """
    B = x0.shape[0]
    k = endb.shape[-1]
    width = Hw.shape[-1]
    n_hi = np.ceil(spw).astype(np.int64)
    sp, nl = spw[vidx], n_lo[vidx]
    W = max_windows(n_samples, sp)
    ends = np.floor(np.arange(1, W + 1)[None, :] * sp[:, None] + 0.5).astype(np.int64)  # kernels.window_end
    starts = np.concatenate([np.zeros((B, 1), np.int64), ends[:, :-1]], axis=1)
    jlen = ends - starts - nl[:, None]  # 0: a window of n_lo samples, 1: of n_hi
    n_run = (starts < n_samples).sum(axis=1)  # windows each voice needs
    # per window as few numpy calls as possible (each costs microseconds): the features' scaling folded into ff,
    # and the end state as one product of [o_q, o_p, q0, p0, 1] with E[pitch, length] (float64, kernels._end_state)
    # (the scaling varies per window only for a bow-scaled range model: then it is applied per window)
    per_window = not (np.all(center == center[:1, :1]) and np.all(halfrange == halfrange[:1, :1]))
    c0, h0 = (center[0, 0], halfrange[0, 0]) if center.size else (np.zeros(2), np.ones(2))
    ffs, off = ff[:2] / h0[:, None], (c0 / h0) @ ff[:2]
    ffp = ff[2:]  # a range model's bow inputs (pin) enter the same features
    last_w = pin.shape[1] - 1
    E = np.zeros((len(spw), 2, 2 * k + 3, 2))
    E[:, :, :k, 0], E[:, :, k:2 * k, 1] = endb[:, :, 0], endb[:, :, 1]
    E[:, :, 2 * k, 0], E[:, :, 2 * k + 1, 0], E[:, :, 2 * k + 2, 0] = endlin[..., 0], endlin[..., 1], endlin[..., 2]
    E[:, :, 2 * k, 1], E[:, :, 2 * k + 1, 1], E[:, :, 2 * k + 2, 1] = -endlin[..., 5], endlin[..., 4], endlin[..., 3]
    lo, span = np.array([box[0], box[2]]), np.array([box[1] - box[0], box[3] - box[2]])
    g = mask.shape[0]
    done = np.zeros(B, np.int64)  # windows computed per voice (the last one may be where it failed)
    x = x0.astype(np.float64).copy()
    alive = np.ones(B, bool)
    rows = np.arange(B)
    pm = np.array([1, -1], np.float32)
    for w0 in range(0, W, BLOCK):
        w1 = min(w0 + BLOCK, W)
        O_blk = np.empty((B, w1 - w0, 2 * k), np.float32)
        X_blk = np.empty((B, w1 - w0, 2), np.float64)
        G_blk = np.empty((B, w1 - w0), np.float64)
        act = rows
        for win in range(w0, w1):
            if win >= n_run.min() or not alive.all():
                act = rows[alive & (win < n_run)]
                if not act.size:
                    break
            xa = x[act]
            X_blk[act, win - w0] = xa
            wi = min(win, last_w)
            if per_window:
                z = ((xa - center[act, wi]) / halfrange[act, wi]) @ ff[:2]
            else:
                z = xa @ ffs - off
            if ffp.shape[0]:
                z += pin[act, wi] @ ffp
            ga = gain[act, wi]
            h = np.concatenate([np.cos(z), np.sin(z)], axis=1).astype(np.float32)
            T = np.tanh(h @ Gw + Gb)
            V = T[:, width:2 * width]
            U = T[:, :width] - V  # modified MLP: h = v + tanh(z) (u - v); U is kept as u - v
            hh = V + T[:, 2 * width:] * U
            for layer in range(Hw.shape[0]):
                hh = V + np.tanh(hh @ Hw[layer] + Hb[layer]) * U
            O = (hh @ Ow + Ob) * ga[:, None].astype(np.float32)  # (A, 2k)
            O_blk[act, win - w0] = O
            G_blk[act, win - w0] = ga
            done[act] = win + 1
            nx = np.einsum("ai,aij->aj", np.concatenate([O, xa, ga[:, None]], axis=1),
                           E[vidx[act], jlen[act, win]])
            ok = np.isfinite(nx).all(axis=1)
            if check:
                cell = (nx - lo) / span
                inside = ok & (cell >= 0).all(axis=1) & (cell <= 1).all(axis=1)
                ij = np.minimum((np.where(inside[:, None], cell, 0) * g).astype(np.int64), g - 1)
                ok_dom = inside & mask[ij[:, 0], ij[:, 1]]
                last = ends[act, win] >= n_samples  # no window follows: nothing to check
                stop = ~ok | ~(ok_dom | last)
            else:
                stop = ~ok
            if stop.any():
                bad, out = ~ok, stop & ok
                fail[act[bad], 0], fail[act[bad], 1] = starts[act[bad], win], FAIL_NONFINITE
                fail[act[out], 0], fail[act[out], 1] = ends[act[out], win], FAIL_DOMAIN
                alive[act[stop]] = False
            x[act] = nx
        for b in range(B):
            wb = min(w1, int(done[b]))
            if wb <= w0:
                continue
            nw, nh = wb - w0, n_hi[vidx[b]]
            xf = X_blk[b, :nw].astype(np.float32)
            ones = G_blk[b, :nw, None].astype(np.float32)  # the bias rows take the gain
            # (nw, n_hi): one row per window, this pitch's columns only (the stack is padded to the longest window)
            Tq = np.concatenate([O_blk[b, :nw, :k], xf, ones], axis=1) @ Bq[vidx[b], :, :nh]
            Tp = np.concatenate([O_blk[b, :nw, k:], xf[:, ::-1] * pm, ones], axis=1) @ Bp[vidx[b], :, :nh]
            # sample i lies in window w at offset i - starts[w]
            first, last = int(starts[b, w0]), min(int(ends[b, wb - 1]), n_samples)
            lens = np.minimum(ends[b, w0:wb], last) - starts[b, w0:wb]
            flat = np.repeat(np.arange(nw) * nh - (starts[b, w0:wb] - first), lens) + np.arange(last - first)
            q_out[b, first:last] = Tq.ravel()[flat]
            p_out[b, first:last] = Tp.ravel()[flat]


def _resolve(scene: Scene, model, models: list[OperatorModel] | None = None, fallback: str = "none"):
    if model is None:
        try:
            return find_model(scene, models)
        except DomainError:
            part = partial_model(scene, models) if fallback == "fdm" else None
            if part is None:
                raise
            return part[0]
    model = as_model(model)
    why = model.domain.mismatch(scene)
    where = first_bow_outside(model, scene) if why and model.domain.is_range else None
    if where and where[0] > 0 and fallback == "fdm" and model.domain.contains(scene.q0, scene.p0):
        return model  # it plays the opening; the FDM the rest
    if where:  # name the parameter, its value and the time it leaves the range
        why = [f"{where[1]} leaves its {model.domain.describe_bows()}"] + [
            w for w in why if not w.startswith(("F_B", "v_B"))]
    if why:
        raise DomainError(f"model {model.path or model.meta.name} does not cover this scene: {'; '.join(why)}. "
                          f"Train one with `{train_hint(scene)}`, or render with --method fdm")
    return model


def _finish(scene: Scene, q, p, fail, fallback: str, voice: str = "") -> list[str]:
    """A voice whose rollout stopped: finish it with the FDM from its last good sample (fallback 'fdm', in place;
    returns the note to show) or raise DomainError."""
    at, code = int(fail[0]), int(fail[1])
    if at < 0 or at >= scene.n_samples:  # a shorter voice of a batch may fail after its own end
        return []
    why = f"{FAILURES[code]} at t = {at / scene.sample_rate:.4f} s"
    if code == FAIL_BOW and len(fail) > 2 and fail[2]:
        why = f"{FAILURES[code]}: {fail[2]}"
    if fallback != "fdm":
        raise DomainError(f"{voice}{why}; the render was stopped (use --fallback "
                          f"fdm to finish with the FDM, or --method fdm)")
    from .fdm import render_fdm

    start = max(at - 1, 0)
    q0, p0 = (float(q[start]), float(p[start])) if at else (scene.q0, scene.p0)
    # the FDM goes on from sample `start` with the curves as they stand there
    rest = render_fdm(scene.after(start / scene.sample_rate, duration=(scene.n_samples - start) / scene.sample_rate,
                                  q0=q0, p0=p0))
    q[start:], p[start:] = rest.q[:scene.n_samples - start], rest.p[:scene.n_samples - start]
    return [f"note: {voice}{why}; finished with the FDM from there"]


def _physics_notes(m: OperatorModel) -> list[str]:
    """Check a model read from a file against the physics its metadata claims (check_physics). A model that passed
    its validation must pass: else ModelFileError. One whose validation failed (never picked by default, so it was
    asked for by name) renders with a note instead. Models built in memory (the trainer's) are not checked here."""
    if not m.from_file:
        return []
    err = check_physics(m)
    if err <= PHYSICS_MAX_ERROR:  # NaN fails too
        return []
    d = m.domain
    what = (f"its first {CHECK_WINDOWS} windows differ from the physics it claims (F_B / w = {d.beta:.4g}, "
            f"v_B = {d.vb:g}, a = {d.a:g}) by {err:.3g} (relative mean square; the limit is {PHYSICS_MAX_ERROR:g})")
    if m.failure is None and math.isfinite(err):
        honest, b_alt, v_alt = claim_fits_best(m, err)
        if honest:  # an inaccuracy, not a lie: the claimed bow is still the one the weights play
            return [f"note: model {m.path or m.meta.name}: {what}, but they fit the claimed bow {MISLABEL_MARGIN:g}x "
                    f"better than bows 10 % away: an inaccurate onset, not a mislabelled file"]
        raise ModelFileError(f"model {m.path or m.meta.name} does not do what it claims: {what}, and they fit "
                             f"F_B / w = {b_alt:.4g}, v_B = {v_alt:.4g} as well or better: its metadata does not "
                             f"describe its weights. Retrain it, or render with --method fdm")
    if m.failure is None:
        raise ModelFileError(f"model {m.path or m.meta.name} does not do what it claims: {what}; its metadata does "
                             f"not describe its weights. Retrain it, or render with --method fdm")
    return [f"note: model {m.path or m.meta.name} is not validated ({m.failure}) and {what}: expect a poor render"]


def render_operator(scene, model=None, fallback: str = "none"):
    """Render one scene (or a list of scenes, batched in one rollout) with a trained operator.

    model: an OperatorModel, a path, or None to pick the best validated model that covers the scene (see
    find_model). A range model follows the scene's bow curves window by window (scene_bows); a point model plays
    scenes of its one bow. fallback='fdm' finishes a rollout that leaves the model's domain, or a bow that leaves
    every model's range, with the FDM (and says so in info['notes']); 'none' raises DomainError. Every render first
    checks the model's physics (check_physics) and raises ModelFileError if the model does not do what its metadata
    claims. The arrays of an operator render are float32, the network's precision.
    """
    if fallback not in ("none", "fdm"):
        raise UsageError(f"fallback must be none or fdm, got {fallback!r}")
    if isinstance(scene, (list, tuple)):
        return render_operator_batch(list(scene), model=model, fallback=fallback)
    return render_operator_batch([scene], model=model, fallback=fallback, _single=True)[0]


def _voice_bows(m: OperatorModel, scenes: list[Scene]):
    """Per voice: the bows of its windows (padded to a common length) and where the bow first leaves the model's
    range ((sample, what) or None: only a --fallback fdm render gets here with one)."""
    op = _operator(m)
    rows, leave = [], []
    for sc in scenes:
        spw = op.samples_per_window(sc.dtau)
        bows = scene_bows(sc, spw)
        out = None
        if m.domain.is_range:
            exit_ = _bow_exit(m, sc, spw, bows)
            if exit_ is not None:
                out = exit_[1:]
                lo_b, hi_b, lo_v, hi_v = m.domain.box
                bows = np.stack([np.clip(bows[:, 0], lo_b, hi_b), np.clip(bows[:, 1], lo_v, hi_v)], axis=1)
        rows.append(bows)
        leave.append(out)
    W = max(len(r) for r in rows)
    par = np.stack([np.concatenate([r, np.repeat(r[-1:], W - len(r), axis=0)]) for r in rows])
    return par, rows, leave


def render_operator_batch(scenes: list[Scene], model=None, fallback: str = "none", _single: bool = False) -> list[Render]:
    """Many voices in one batched rollout. Voices sharing a model roll together, at any mix of pitches, sample
    rates and bow curves; a voice that leaves its model's domain (or its bow the model's range) is finished with the
    FDM (fallback 'fdm') or stops the render (DomainError)."""
    t_setup = time.perf_counter()
    # load each model file once: the voices must share model objects to be grouped into one rollout
    model = None if model is None else as_model(model)
    models = available_models() if model is None else None
    groups: dict = {}
    out: list = [None] * len(scenes)
    for i, sc in enumerate(scenes):
        if sc.pitch_varies:  # a pitch curve: per window its own sample spacing (the live engine's voice loop)
            from .live.stream import render_curve

            out[i] = render_curve(sc, _resolve(sc, model, models, fallback))
            continue
        m = _resolve(sc, model, models, fallback)
        groups.setdefault(id(m), (m, []))[1].append(i)
    for m, idx in groups.values():
        checked = _physics_notes(m) + (unreadable_notes() if model is None else [])
        group = [scenes[i] for i in idx]
        n = max(sc.n_samples for sc in group)
        x0 = np.array([[sc.q0, sc.p0] for sc in group])
        dtau = np.array([sc.dtau for sc in group])
        par, bows, leave = _voice_bows(m, group)
        loop = choose_loop(m, n, dtau)
        # warm-up: converts the weights, computes the trunk features at these sample offsets and loads the compiled
        # loop if it is used, so that `seconds` measures the rollout itself (start-up: info["setup_seconds"])
        rollout_states(m, x0, 1, dtau, loop=loop, params=par[:, :1])
        t0 = time.perf_counter()
        q, p, fail = rollout_states(m, x0, n, dtau, loop=loop, params=par)
        fails = [list(f) for f in fail]
        for row, lv in enumerate(leave):
            if lv is not None and (fails[row][0] < 0 or lv[0] < fails[row][0]):
                fails[row] = [lv[0], FAIL_BOW, lv[1]]
                q[row, lv[0]:] = np.nan
                p[row, lv[0]:] = np.nan
        notes = {i: _finish(scenes[i], q[row, :scenes[i].n_samples], p[row, :scenes[i].n_samples], fails[row],
                            fallback, voice="" if _single else f"voice {i + 1}: ") + checked
                 for row, i in enumerate(idx)}
        secs = (time.perf_counter() - t0) / len(idx)
        op = _operator(m)
        t_all = {}  # one time axis per sample rate, shared (views) by the voices that use it
        for row, i in enumerate(idx):
            sc = scenes[i]
            ns = sc.n_samples
            if sc.sample_rate not in t_all:
                t_all[sc.sample_rate] = np.arange(n) / sc.sample_rate
            info = {"model_id": m.id, "model_path": str(m.path) if m.path else None, "notes": notes[i], "loop": loop,
                    "setup_seconds": t0 - t_setup}
            if not _single:
                info["batched"] = len(idx)
            if m.domain.is_range:  # a range model is not equally good everywhere in its box: say how good
                v = m.meta.validation or {}
                info["range_validation"] = {k: v.get(k) for k in ("nmse", "nmse_max", "grid")}
            ctrl = None
            if sc.varying:  # else the scene's own constant controls (Render's lazy default) are what ran
                ctrl = applied_controls(sc, op.samples_per_window(sc.dtau), bows[row])
                if leave[row] is not None:  # the FDM played the rest: its controls are the curves themselves
                    at = leave[row][0]
                    tt = np.arange(at, ns) / sc.sample_rate
                    ctrl["fb"][at:], ctrl["vb"][at:] = sc.fb_at(tt), sc.vb_at(tt)
            out[i] = Render(sc, t_all[sc.sample_rate][:ns], q[row, :ns], p[row, :ns],
                            method="operator" + ("+fdm" if len(notes[i]) > len(checked) else ""), seconds=secs,
                            info=info, **({"controls": ctrl} if ctrl is not None else {}))
    return out


# The physics check. The dynamics in tau depend on (beta, v_B, a) and the initial state only, so a model is checked
# once per process, whatever the pitch: its first CHECK_WINDOWS windows from the initial state of the scene it was
# trained (and validated) for, on a grid of CHECK_STEPS samples per window, against a classical RK4 integration of the
# claimed ODE (physics.rhs_tau) with steps short enough for the friction's stiffness. The error is the mean square
# difference over both state variables relative to the mean square of what friction adds to the exact linear flow
# (x_ref - R(tau) x0): a model rendering other physics than its metadata claims is off by the order of that
# correction. From rest the bow's onset separates forces well; from a state in a stick phase (F_B 1000) two windows
# of another force can look the same, so the check does not use the render's own initial state.
# Measured (benchmarks/physics_check.py, docs/BENCHMARKS.md): the shipped models score 3.8e-7, 3.7e-6 and 5.1e-5;
# their files edited to claim 1.5x or 2x the bow force 0.14 to 1.1, 1.1x 0.008 to 0.23. Cost 2-7 ms once per model
# (shared machine).
CHECK_WINDOWS = 2
CHECK_STEPS = 128  # 256 gave the same errors to 3 digits, at twice the cost
RK4_STIFF = 1.0  # RK4 steps h with h * stiffness <= this (stable to 2.8); 0.5 gave the same errors to 3 digits
PHYSICS_MAX_ERROR = 5e-3  # ~100x the worst shipped model
# The normaliser is at least (CHECK_FLOOR c)^2, c the model's own correction scale (the RMS of what friction adds
# over a window on its band): from rest at a slow onset (scratch-g2, v_B 0.3) friction adds 4.5e-7 c^2 over the two
# windows, so an error of 1e-4 of the playing amplitude read as 0.12-0.18 "relative" for models that validate at 1 s.
# Below the floor two windows carry too little friction to tell physics apart; the shipped paper models' starts carry
# 6e-3 to 0.34 c^2, where it does not bind.
CHECK_FLOOR = 0.01


def reference_tau(q0: float, p0: float, beta: float, vb: float, a: float, dtau: float, n: int):
    """q, p at tau = j dtau, j < n, by RK4 on the dimensionless ODE (pure Python floats: no compiler to load)."""
    stiff = 1.0 + beta * math.sqrt(2.0 * a) * physics.E_HALF  # largest |d p' / d p| (phi' peaks at eta = 0)
    sub = max(1, math.ceil(dtau * stiff / RK4_STIFF))
    h = dtau / sub
    f = physics.rhs_tau
    q, p = float(q0), float(p0)
    qs, ps = [q], [p]
    for _ in range(n - 1):
        for _ in range(sub):
            k1q, k1p = f(q, p, beta, vb, a)
            k2q, k2p = f(q + 0.5 * h * k1q, p + 0.5 * h * k1p, beta, vb, a)
            k3q, k3p = f(q + 0.5 * h * k2q, p + 0.5 * h * k2p, beta, vb, a)
            k4q, k4p = f(q + h * k3q, p + h * k3p, beta, vb, a)
            q += h / 6.0 * (k1q + 2.0 * (k2q + k3q) + k4q)
            p += h / 6.0 * (k1p + 2.0 * (k2p + k3p) + k4p)
        qs.append(q)
        ps.append(p)
    return np.array(qs), np.array(ps)


def physics_error(model: OperatorModel, q0: float, p0: float, beta: float | None = None,
                  vb: float | None = None) -> float:
    """The model's error over its first CHECK_WINDOWS windows from (q0, p0) against the physics its metadata claims
    (or at another bow, beta and vb; relative mean square, see above); inf if the rollout turns non-finite."""
    d = model.domain
    beta = d.beta if beta is None else beta
    vb = d.vb if vb is None else vb
    op = _operator(model)
    dtau = op.window / CHECK_STEPS
    n = CHECK_WINDOWS * CHECK_STEPS
    q, p, fail = rollout_states(model, [[q0, p0]], n, dtau, check_domain=False, loop="numpy")
    if fail[0, 0] >= 0:
        return math.inf
    rq, rp = reference_tau(q0, p0, beta, vb, d.a, dtau, n)
    m11, m12, m21, m22, kq, kp = npnet.linear_part(op.cfg, np.arange(n) * dtau)
    lq, lp = m11 * q0 + m12 * p0 + kq, m21 * q0 + m22 * p0 + kp
    corr = max(np.mean((rq - lq) ** 2 + (rp - lp) ** 2), CHECK_FLOOR ** 2 * float(np.sum(op.corr_scale ** 2)))
    return float(np.mean((q[0] - rq) ** 2 + (p[0] - rp) ** 2) / max(corr, 1e-30))


# A model over the limit may be honest but inaccurate (a range model's onset from rest at its box's centre) or
# mislabelled. The claimed bow must then fit the model's windows at least MISLABEL_MARGIN times better than the bows
# NEIGHBOURS away (F_B / w x/ 1.1, v_B x/ 1.05): measured, every shipped model and an honest range model over the
# limit (0.0053) fit their claim 5-100x better than any neighbour; a file claiming another bow fits that bow best.
NEIGHBOURS = ((1 / 1.1, 1.0), (1.1, 1.0), (1.0, 1 / 1.05), (1.0, 1.05))
MISLABEL_MARGIN = 2.0


def claim_fits_best(model: OperatorModel, err: float) -> tuple[bool, float, float]:
    """Does the claimed bow fit the model's first windows MISLABEL_MARGIN times better than its NEIGHBOURS? Returns
    (verdict, the best neighbour's F_B / w and v_B)."""
    sc = model.meta.scene or {}
    q0, p0 = float(sc.get("q0", 0.0)), float(sc.get("p0", 0.0))
    d = model.domain
    errs = [(physics_error(model, q0, p0, d.beta * fb, d.vb * fv), d.beta * fb, d.vb * fv) for fb, fv in NEIGHBOURS]
    best = min(errs)
    return bool(err * MISLABEL_MARGIN < best[0]), best[1], best[2]


def check_physics(model: OperatorModel) -> float:
    """physics_error from the initial state of the model's training scene, once per model object."""
    if "_physics_error" not in model.__dict__:
        sc = model.meta.scene or {}
        model.__dict__["_physics_error"] = physics_error(model, float(sc.get("q0", 0.0)), float(sc.get("p0", 0.0)))
    return model.__dict__["_physics_error"]
