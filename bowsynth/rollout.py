"""Rolling render: the operator applied window to window, each window seeded by the previous window's end state.

The audio samples sit at fixed offsets tau_j = j w / sr inside every window, so the trunk features there are
computed once per render; a window then costs one branch evaluation and a small matmul. The loop is compiled with
numba for a few voices and runs as numpy calls for many (vectorised tanh and BLAS win there; see
docs/BENCHMARKS.md).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numba
import numpy as np

from .errors import DomainError, ModelFileError, UsageError
from .model import OperatorModel, load_model
from .render import Render
from .scene import Scene

SHIPPED_DIR = Path(__file__).resolve().parent.parent / "models"


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
    """The trained network's weights as float64 numpy arrays, for the compiled rollout."""

    def __init__(self, model: OperatorModel):
        net = model.net
        self.k = net.cfg.k
        sd = {k: v.detach().double().numpy() for k, v in net.state_dict().items()}
        g = lambda name: (np.ascontiguousarray(sd[f"branch.{name}.weight"].T), sd[f"branch.{name}.bias"].copy())  # noqa: E731
        n_hidden = sum(1 for k in sd if k.startswith("branch.hidden.") and k.endswith(".weight"))
        self.ff = np.ascontiguousarray(2 * np.pi * sd["branch.ff.B"])
        self.U, self.V = g("U"), g("V")
        self.H0 = g("hidden.0")
        rest = [g(f"hidden.{i}") for i in range(1, n_hidden)]
        width = self.U[0].shape[1]
        self.Hw = np.ascontiguousarray(np.array([w for w, _ in rest]).reshape(-1, width, width))
        self.Hb = np.ascontiguousarray(np.array([b for _, b in rest]).reshape(-1, width))
        self.out = g("out")
        self.center, self.halfrange = sd["center"], sd["halfrange"]
        self.corr_scale, self.window, self.bias = sd["corr_scale"], float(sd["window"]), sd["bias"]
        self.net = net

    def window_basis(self, dtau: float):
        """For samples at tau_j = j dtau, j = 0..n (n = samples per window): cos, sin of the rotation, the trunk
        features already multiplied by s c as (2, k, n+1), and the bias term s c b as (2, n+1)."""
        import torch

        n = int(math.floor(self.window / dtau + 1e-9))
        tau = np.arange(n + 1) * dtau
        s = tau / self.window
        with torch.inference_mode():
            tf = self.net.trunk_features(torch.tensor(s, dtype=torch.float32)).double().numpy()  # (n+1, 2, k)
        # float32: the rollout multiplies the correction term in float32 (see _rollout_kernel)
        basis = np.ascontiguousarray(np.transpose(tf, (1, 2, 0)) * (s * self.corr_scale[:, None])[:, None, :],
                                     dtype=np.float32)
        bias = np.ascontiguousarray(self.bias[:, None] * self.corr_scale[:, None] * s[None, :])
        if not self.net.cfg.linear_flow:  # ablation models: the output carries x0, not R(tau) x0
            return n, np.ones_like(tau), np.zeros_like(tau), basis, bias
        return n, np.cos(tau), np.sin(tau), basis, bias


@numba.njit(cache=True)
def _rollout_kernel(x0, n_samples, n, cosv, sinv, bq, bp, biasq, biasp, center, halfrange, ff, Uw, Ub, Vw, Vb,
                    H0w, H0b, Hw, Hb, Ow, Ob, k, box, mask, check, q_out, p_out):
    """The whole rollout compiled: per window one branch evaluation and one matmul per state variable.
    Returns (-1, 0) on success, else (first sample of the failing window, 1 non-finite | 2 left the domain)."""
    B = x0.shape[0]
    x = x0.copy()
    g = mask.shape[0]
    for start in range(0, n_samples, n):
        z = ((x - center) / halfrange) @ ff
        h = np.concatenate((np.cos(z), np.sin(z)), axis=1)
        u = np.tanh(h @ Uw + Ub)
        v = np.tanh(h @ Vw + Vb)
        zz = np.tanh(h @ H0w + H0b)
        h = v + zz * (u - v)
        for layer in range(Hw.shape[0]):
            zz = np.tanh(h @ Hw[layer] + Hb[layer])
            h = v + zz * (u - v)
        o = (h @ Ow + Ob).astype(np.float32)
        # the correction term in float32 (its relative error 1e-7 is far below any model's), the rest in float64
        tq = np.ascontiguousarray(o[:, :k]) @ bq
        tp = np.ascontiguousarray(o[:, k:]) @ bp
        m = min(n, n_samples - start)
        for b in range(B):
            q0 = x[b, 0]
            p0 = x[b, 1]
            for j in range(m):
                q_out[b, start + j] = tq[b, j] + (q0 * cosv[j] + p0 * sinv[j] + biasq[j])
                p_out[b, start + j] = tp[b, j] + (p0 * cosv[j] - q0 * sinv[j] + biasp[j])
            x[b, 0] = tq[b, n] + (q0 * cosv[n] + p0 * sinv[n] + biasq[n])
            x[b, 1] = tp[b, n] + (p0 * cosv[n] - q0 * sinv[n] + biasp[n])
        # NaN and inf propagate into sums: one check per window instead of one per sample
        if not (np.isfinite(tq.sum()) and np.isfinite(tp.sum()) and np.isfinite(x.sum())):
            return start, 1
        if check and start + n < n_samples:
            for b in range(B):
                qq, pp = x[b, 0], x[b, 1]
                if not (box[0] <= qq <= box[1] and box[2] <= pp <= box[3]):
                    return start + n, 2
                i = min(max(int((qq - box[0]) / (box[1] - box[0]) * g), 0), g - 1)
                jj = min(max(int((pp - box[2]) / (box[3] - box[2]) * g), 0), g - 1)
                if not mask[i, jj]:
                    return start + n, 2
    return -1, 0


NUMPY_BATCH = 8  # from this many voices on, numpy's vectorised tanh and BLAS beat the compiled loop (measured)


def _rollout_numpy(op, x, n_samples, n, c, s, basis, bias, d, check, q_out, p_out):
    """The same rollout as `_rollout_kernel`, one numpy call per layer: faster for many voices at once."""
    bq, bp = basis[0], basis[1]
    k = op.k
    for start in range(0, n_samples, n):
        z = ((x - op.center) / op.halfrange) @ op.ff
        h = np.concatenate((np.cos(z), np.sin(z)), axis=1)
        u = np.tanh(h @ op.U[0] + op.U[1])
        v = np.tanh(h @ op.V[0] + op.V[1])
        h = v + np.tanh(h @ op.H0[0] + op.H0[1]) * (u - v)
        for w, b in zip(op.Hw, op.Hb):
            h = v + np.tanh(h @ w + b) * (u - v)
        o = (h @ op.out[0] + op.out[1]).astype(np.float32)
        tq = (o[:, :k] @ bq) + (np.outer(x[:, 0], c) + np.outer(x[:, 1], s) + bias[0])
        tp = (o[:, k:] @ bp) + (np.outer(x[:, 1], c) - np.outer(x[:, 0], s) + bias[1])
        m = min(n, n_samples - start)
        q_out[:, start:start + m] = tq[:, :m]
        p_out[:, start:start + m] = tp[:, :m]
        x = np.stack([tq[:, n], tp[:, n]], axis=1)
        if not (np.isfinite(tq.sum()) and np.isfinite(tp.sum())):
            return start, 1
        if check and start + n < n_samples and not np.all(d.contains(x[:, 0], x[:, 1])):
            return start + n, 2
    return -1, 0


def rollout_states(model: OperatorModel, x0: np.ndarray, n_samples: int, dtau: float, check_domain: bool = True):
    """Roll the operator from states x0 (B, 2) for n_samples samples spaced dtau in tau.

    Returns q, p (B, n_samples) and, if the rollout left the domain or went non-finite, the index of the first
    sample of the failing window and a reason; otherwise (q, p, None, None).
    """
    op = model.__dict__.get("_numpy_op")
    if op is None:  # weights don't change after loading: convert once per model
        op = model.__dict__["_numpy_op"] = NumpyOperator(model)
    cache = model.__dict__.setdefault("_basis_cache", {})
    if dtau not in cache:
        cache[dtau] = op.window_basis(dtau)
    n, c, s, basis, bias = cache[dtau]
    if n < 1:
        raise DomainError(f"the model's window ({op.window:.3g} in tau) is shorter than one sample")
    x = np.array(x0, dtype=float).reshape(-1, 2)
    q = np.empty((len(x), n_samples))
    p = np.empty((len(x), n_samples))
    d = model.domain
    if len(x) >= NUMPY_BATCH:
        fail, code = _rollout_numpy(op, x, n_samples, n, c, s, basis, bias, d, check_domain, q, p)
    else:
        fail, code = _rollout_kernel(
            x, n_samples, n, c, s, basis[0], basis[1], bias[0].copy(),
            bias[1].copy(), op.center, op.halfrange, op.ff, op.U[0], op.U[1], op.V[0], op.V[1], op.H0[0], op.H0[1],
            op.Hw, op.Hb, op.out[0], op.out[1], op.k, np.array([d.q_lo, d.q_hi, d.p_lo, d.p_hi]),
            np.ascontiguousarray(d.mask), bool(check_domain), q, p)
    if fail < 0:
        return q, p, None, None
    return q, p, fail, ("the rollout turned non-finite" if code == 1 else "the rollout left the model's trained states")


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


def render_operator(scene, model=None, fallback: str = "none"):
    """Render one scene (or a list of scenes, batched in one rollout) with a trained operator.

    model: an OperatorModel, a path, or None to pick the model that covers the scene. fallback='fdm' finishes a
    rollout that leaves the model's domain with the FDM (and says so in info['notes']); 'none' raises DomainError.
    """
    if fallback not in ("none", "fdm"):
        raise UsageError(f"fallback must be none or fdm, got {fallback!r}")
    if isinstance(scene, (list, tuple)):
        return render_operator_batch(list(scene), model=model)
    m = _resolve(scene, model)
    dtau = scene.omega / scene.sample_rate
    x0 = np.array([[scene.q0, scene.p0]])
    # one-sample warm-up: converts the weights, computes the trunk features at this render's sample offsets and
    # loads the compiled loop, so that `seconds` measures the rollout itself (start-up is in info["setup_seconds"])
    t_setup = time.perf_counter()
    rollout_states(m, x0, 1, dtau)
    t0 = time.perf_counter()
    q, p, fail, why = rollout_states(m, x0, scene.n_samples, dtau)
    q, p = q[0], p[0]
    notes = []
    if fail is not None:
        t_fail = fail / scene.sample_rate
        if fallback != "fdm" or not np.isfinite(q[fail - 1] if fail else scene.q0):
            raise DomainError(f"{why} at t = {t_fail:.4f} s; the render was stopped (use --fallback fdm to finish "
                              f"with the FDM, or --method fdm)")
        from .fdm import render_fdm

        start = max(fail - 1, 0)
        rest = render_fdm(scene.replace(duration=(scene.n_samples - start) / scene.sample_rate,
                                        q0=float(q[start]), p0=float(p[start])))
        q[start:], p[start:] = rest.q[:scene.n_samples - start], rest.p[:scene.n_samples - start]
        notes.append(f"note: {why} at t = {t_fail:.4f} s; finished with the FDM from there")
    secs = time.perf_counter() - t0
    t = np.arange(scene.n_samples) / scene.sample_rate
    return Render(scene, t, q, p, method="operator" + ("+fdm" if notes else ""), seconds=secs,
                  info={"model_id": m.id, "model_path": str(m.path) if m.path else None, "notes": notes,
                        "setup_seconds": t0 - t_setup})


def render_operator_batch(scenes: list[Scene], model=None) -> list[Render]:
    """Many voices in one batched rollout. Voices sharing a model and a sample spacing in tau roll together."""
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
        q, p, fail, why = rollout_states(m, x0, n, dtau)
        if fail is not None:
            raise DomainError(f"{why} at t = {fail / scenes[idx[0]].sample_rate:.4f} s in a batched rollout")
        secs = (time.perf_counter() - t0) / len(idx)
        t_all = {}  # one time axis per sample rate, shared (views) by the voices that use it
        for row, i in enumerate(idx):
            sc = scenes[i]
            ns = sc.n_samples
            if sc.sample_rate not in t_all:
                t_all[sc.sample_rate] = np.arange(n) / sc.sample_rate
            out[i] = Render(sc, t_all[sc.sample_rate][:ns], q[row, :ns], p[row, :ns], method="operator",
                            seconds=secs, info={"model_id": m.id, "batched": len(idx)})
    return out
