"""Rolling render: the operator applied window to window, each window seeded by the previous window's end state.

The audio samples sit at fixed offsets tau_j = j w / sr inside every window, so the trunk features there are
computed once per render; a window then costs one branch evaluation and a small matmul (the compiled loops are in
`kernels`).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from . import kernels
from .errors import DomainError, ModelFileError, UsageError
from .model import OperatorModel, load_model
from .render import Render
from .scene import Scene

SHIPPED_DIR = Path(__file__).resolve().parent / "models"  # inside the package: a wheel carries them


def model_dirs() -> list[Path]:
    dirs = [Path.cwd() / "models", SHIPPED_DIR]
    out = []
    for d in dirs:
        if d.is_dir() and d.resolve() not in [o.resolve() for o in out]:
            out.append(d)
    return out


def available_models() -> list[OperatorModel]:
    found = []
    for d in model_dirs():
        for p in sorted(d.glob("*.safetensors")):
            if p.name.endswith(".ckpt.safetensors"):
                continue
            try:
                found.append(load_model(p))
            except ModelFileError:
                continue
    return found


def train_hint(scene: Scene) -> str:
    return (f"bowsynth train --fb {scene.fb:g} --f0 {scene.f0:g} --vb {scene.vb:g} --a {scene.a:g}"
            + (f" --q0 {scene.q0:g} --p0 {scene.p0:g}" if scene.q0 or scene.p0 else ""))


def find_model(scene: Scene, models: list[OperatorModel] | None = None) -> OperatorModel:
    """The first model (./models, then the shipped ones, or the given list) that covers the scene, else a
    DomainError that says which models come nearest and how to train one that covers it."""
    if models is None:
        models = available_models()
    for m in models:
        if m.covers(scene):
            return m
    def dist(m):
        d = m.domain
        return abs(math.log(max(scene.beta, 1e-9) / max(d.beta, 1e-9))) + abs(scene.vb - d.vb) + abs(math.log(scene.a / d.a))
    near = sorted(models, key=dist)[:3]
    lines = "; ".join(f"{m.path.name} ({', '.join(m.domain.mismatch(scene))})" for m in near) or "none found"
    raise DomainError(f"no model covers this scene (F_B / w = {scene.beta:.4g}, v_B = {scene.vb:g}, a = {scene.a:g}); "
                      f"nearest: {lines}. Train one with `{train_hint(scene)}`, or render with --method fdm")


class NumpyOperator:
    """The trained network's weights as float32 numpy arrays (the precision it was trained in), for the compiled
    rollout in `kernels`."""

    def __init__(self, model: OperatorModel):
        net = model.net
        sd = {k: v.detach().double().numpy() for k, v in net.state_dict().items()}
        f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32)  # noqa: E731
        g = lambda name: (f32(sd[f"branch.{name}.weight"].T), f32(sd[f"branch.{name}.bias"]))  # noqa: E731
        n_hidden = sum(1 for k in sd if k.startswith("branch.hidden.") and k.endswith(".weight"))
        rest = [g(f"hidden.{i}") for i in range(1, n_hidden)]
        width = net.cfg.width
        self.ff = np.ascontiguousarray(2 * np.pi * sd["branch.ff.B"])
        gates = [g(name) for name in ("U", "V", "hidden.0")]  # one product for the three (kernels.roll_voices)
        self.weights = (f32(np.hstack([w for w, _ in gates])), f32(np.concatenate([b for _, b in gates])),
                        f32(np.array([w for w, _ in rest]).reshape(-1, width, width)),
                        f32(np.array([b for _, b in rest]).reshape(-1, width)), *g("out"))
        self.center, self.halfrange = sd["center"], sd["halfrange"]
        self.corr_scale, self.window, self.bias = sd["corr_scale"], float(sd["window"]), sd["bias"]
        self.net = net

    def window_basis(self, dtau: float):
        """The output side of the windows of a render whose samples are dtau apart in tau.

        A window holds n_lo = floor(T / dtau) or n_hi = ceil(T / dtau) samples (kernels.window_end: window w starts
        at the sample nearest w T; at a pitch where T / dtau is not a whole number, windows of n_lo samples alone
        would start ever earlier than the states the model trained on, measured 2.6x the error at 200 Hz). A window
        of n_hi samples runs past T by less than one sample spacing.
        Returns spw = T / dtau, n_lo; Bq, Bp (k + 3, n_hi) float32: the trunk features times s c at the sample
        offsets, then cos, sin and the bias term (see kernels.roll_voices); for the end state after n_lo and after
        n_hi samples, in float64, the features endb (2, 2, k) and endlin (2, 4) = (cos, sin, bias_q, bias_p).
        """
        import torch

        spw = self.window / dtau
        if abs(spw - round(spw)) < 1e-9 * spw:  # a whole number of samples, up to rounding: every window alike
            spw = float(round(spw))
        n_lo, n_hi = math.floor(spw), math.ceil(spw)
        tau = np.arange(n_hi + 1) * dtau
        s = tau / self.window
        with torch.inference_mode():
            tf = self.net.trunk_features(torch.tensor(s, dtype=torch.float32)).double().numpy()  # (n_hi+1, 2, k)
        basis = np.transpose(tf, (1, 2, 0)) * (s * self.corr_scale[:, None])[:, None, :]  # (2, k, n_hi+1)
        bias = self.bias[:, None] * self.corr_scale[:, None] * s[None, :]  # (2, n_hi+1)
        if self.net.cfg.linear_flow:
            c, sn = np.cos(tau), np.sin(tau)
        else:  # ablation models: the output carries x0, not R(tau) x0
            c, sn = np.ones_like(tau), np.zeros_like(tau)
        rows = lambda i: np.ascontiguousarray(  # noqa: E731
            np.vstack([basis[i, :, :n_hi], c[:n_hi], sn[:n_hi], bias[i, :n_hi]]), dtype=np.float32)
        ends = (n_lo, n_hi)
        endb = np.ascontiguousarray(np.stack([basis[:, :, e] for e in ends]))
        endlin = np.array([[c[e], sn[e], bias[0, e], bias[1, e]] for e in ends])
        return spw, n_lo, rows(0), rows(1), endb, endlin


BATCH_FROM = 8  # from this many voices on, the window-at-a-time loop with BLAS products is the faster (measured)
FAILURES = {kernels.FAIL_NONFINITE: "the rollout turned non-finite",
            kernels.FAIL_DOMAIN: "the rollout left the model's trained states"}


def rollout_states(model: OperatorModel, x0: np.ndarray, n_samples: int, dtau: float, check_domain: bool = True):
    """Roll the operator from states x0 (B, 2) for n_samples samples spaced dtau in tau.

    Returns q, p (B, n_samples) float32 and fail (B, 2) int: per voice the first sample of the window where the
    rollout left the model's domain or went non-finite, and the reason (a key of FAILURES), or (-1, 0). A failed
    voice stops there (its later samples are NaN); the other voices go on.
    """
    op = model.__dict__.get("_numpy_op")
    if op is None:  # weights don't change after loading: convert once per model
        op = model.__dict__["_numpy_op"] = NumpyOperator(model)
    cache = model.__dict__.setdefault("_basis_cache", {})
    if dtau not in cache:
        cache[dtau] = op.window_basis(dtau)
    spw, n_lo, Bq, Bp, endb, endlin = cache[dtau]
    if n_lo < 1:
        raise DomainError(f"the model's window ({op.window:.3g} in tau) is shorter than one sample")
    x = np.array(x0, dtype=float).reshape(-1, 2)
    q = np.empty((len(x), n_samples), np.float32)
    p = np.empty((len(x), n_samples), np.float32)
    fail = np.tile(np.array([-1, 0], np.int64), (len(x), 1))  # the loops write only the voices that fail
    d = model.domain
    loop = kernels.roll_batch if len(x) >= BATCH_FROM else kernels.roll_voices
    loop(x, n_samples, spw, n_lo, Bq, Bp, endb, endlin, op.center, op.halfrange, op.ff, *op.weights,
         np.array([d.q_lo, d.q_hi, d.p_lo, d.p_hi]), np.ascontiguousarray(d.mask), bool(check_domain), q, p, fail)
    for b in np.flatnonzero(fail[:, 0] >= 0):
        q[b, fail[b, 0]:] = np.nan
        p[b, fail[b, 0]:] = np.nan
    return q, p, fail


def _resolve(scene: Scene, model, models: list[OperatorModel] | None = None) -> OperatorModel:
    if model is None:
        return find_model(scene, models)
    if not isinstance(model, OperatorModel):
        model = load_model(model)
    why = model.domain.mismatch(scene)
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
    why = FAILURES[code]
    if fallback != "fdm":
        raise DomainError(f"{voice}{why} at t = {at / scene.sample_rate:.4f} s; the render was stopped (use --fallback "
                          f"fdm to finish with the FDM, or --method fdm)")
    from .fdm import render_fdm

    start = max(at - 1, 0)
    q0, p0 = (float(q[start]), float(p[start])) if at else (scene.q0, scene.p0)
    rest = render_fdm(scene.replace(duration=(scene.n_samples - start) / scene.sample_rate, q0=q0, p0=p0))
    q[start:], p[start:] = rest.q[:scene.n_samples - start], rest.p[:scene.n_samples - start]
    return [f"note: {voice}{why} at t = {at / scene.sample_rate:.4f} s; finished with the FDM from there"]


def render_operator(scene, model=None, fallback: str = "none"):
    """Render one scene (or a list of scenes, batched in one rollout) with a trained operator.

    model: an OperatorModel, a path, or None to pick the model that covers the scene. fallback='fdm' finishes a
    rollout that leaves the model's domain with the FDM (and says so in info['notes']); 'none' raises DomainError.
    The arrays of an operator render are float32, the network's precision.
    """
    if fallback not in ("none", "fdm"):
        raise UsageError(f"fallback must be none or fdm, got {fallback!r}")
    if isinstance(scene, (list, tuple)):
        return render_operator_batch(list(scene), model=model, fallback=fallback)
    m = _resolve(scene, model)
    dtau = scene.omega / scene.sample_rate
    x0 = np.array([[scene.q0, scene.p0]])
    # one-sample warm-up: converts the weights, computes the trunk features at this render's sample offsets and
    # loads the compiled loop, so that `seconds` measures the rollout itself (start-up is in info["setup_seconds"])
    t_setup = time.perf_counter()
    rollout_states(m, x0, 1, dtau)
    t0 = time.perf_counter()
    q, p, fail = rollout_states(m, x0, scene.n_samples, dtau)
    q, p = q[0], p[0]
    notes = _finish(scene, q, p, fail[0], fallback)
    secs = time.perf_counter() - t0
    t = np.arange(scene.n_samples) / scene.sample_rate
    return Render(scene, t, q, p, method="operator" + ("+fdm" if notes else ""), seconds=secs,
                  info={"model_id": m.id, "model_path": str(m.path) if m.path else None, "notes": notes,
                        "setup_seconds": t0 - t_setup})


def render_operator_batch(scenes: list[Scene], model=None, fallback: str = "none") -> list[Render]:
    """Many voices in one batched rollout. Voices sharing a model and a sample spacing in tau roll together; a voice
    that leaves its model's domain is finished with the FDM (fallback 'fdm') or stops the render (DomainError)."""
    # load each model file once: the voices must share model objects to be grouped into one rollout
    if model is not None and not isinstance(model, OperatorModel):
        model = load_model(model)
    models = available_models() if model is None else None
    groups: dict = {}
    for i, sc in enumerate(scenes):
        m = _resolve(sc, model, models)
        key = (id(m), sc.omega / sc.sample_rate)
        groups.setdefault(key, (m, []))[1].append(i)
    out: list = [None] * len(scenes)
    for (_, dtau), (m, idx) in groups.items():
        n = max(scenes[i].n_samples for i in idx)
        x0 = np.array([[scenes[i].q0, scenes[i].p0] for i in idx])
        rollout_states(m, x0, 1, dtau)  # warm-up, as in render_operator
        t0 = time.perf_counter()
        q, p, fail = rollout_states(m, x0, n, dtau)
        notes = {i: _finish(scenes[i], q[row, :scenes[i].n_samples], p[row, :scenes[i].n_samples], fail[row],
                            fallback, voice=f"voice {i + 1}: ") for row, i in enumerate(idx)}
        secs = (time.perf_counter() - t0) / len(idx)
        t_all = {}  # one time axis per sample rate, shared (views) by the voices that use it
        for row, i in enumerate(idx):
            sc = scenes[i]
            ns = sc.n_samples
            if sc.sample_rate not in t_all:
                t_all[sc.sample_rate] = np.arange(n) / sc.sample_rate
            out[i] = Render(sc, t_all[sc.sample_rate][:ns], q[row, :ns], p[row, :ns],
                            method="operator" + ("+fdm" if notes[i] else ""), seconds=secs,
                            info={"model_id": m.id, "batched": len(idx), "notes": notes[i]})
    return out
