"""Rolling render: the operator applied window to window, each window seeded by the previous window's end state.

The audio samples sit at fixed offsets tau_j = j w / sr inside every window, so the trunk features there are
computed once per render; a window then costs one branch evaluation and a small matmul. The evaluation runs in
numpy (measured faster than torch for these small matrices; see docs/BENCHMARKS.md).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

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


def find_model(scene: Scene) -> OperatorModel:
    """The first model (./models, then the shipped ones) that covers the scene, else a DomainError that says
    which models come nearest and how to train one that covers it."""
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
    """The trained network's weights as numpy arrays, for fast inference without autograd."""

    def __init__(self, model: OperatorModel):
        net = model.net
        self.k = net.cfg.k
        sd = {k: v.detach().double().numpy() for k, v in net.state_dict().items()}
        self.branch = self._mlp(sd, "branch")
        self.center, self.halfrange = sd["center"], sd["halfrange"]
        self.corr_scale, self.window, self.bias = sd["corr_scale"], float(sd["window"]), sd["bias"]
        self.net = net

    @staticmethod
    def _mlp(sd, pre):
        n = 0
        while f"{pre}.hidden.{n}.weight" in sd:
            n += 1
        g = lambda name: (sd[f"{pre}.{name}.weight"].T.copy(), sd[f"{pre}.{name}.bias"])  # noqa: E731
        return {"B": 2 * np.pi * sd[f"{pre}.ff.B"], "U": g("U"), "V": g("V"),
                "hidden": [g(f"hidden.{i}") for i in range(n)], "out": g("out")}

    def branch_features(self, x0: np.ndarray) -> np.ndarray:
        m = self.branch
        z = ((x0 - self.center) / self.halfrange) @ m["B"]
        h = np.concatenate([np.cos(z), np.sin(z)], axis=-1)
        u = np.tanh(h @ m["U"][0] + m["U"][1])
        v = np.tanh(h @ m["V"][0] + m["V"][1])
        for w, b in m["hidden"]:
            z = np.tanh(h @ w + b)
            h = v + z * (u - v)
        return (h @ m["out"][0] + m["out"][1]).reshape(-1, 2, self.k)

    def window_basis(self, dtau: float):
        """For samples at tau_j = j dtau, j = 0..n (n = samples per window): the trunk part of the output,
        already multiplied by s c, as (2, k, n+1), with the rotation cos/sin and the s c bias term."""
        import torch

        n = int(math.floor(self.window / dtau + 1e-9))
        tau = np.arange(n + 1) * dtau
        s = tau / self.window
        with torch.inference_mode():
            tf = self.net.trunk_features(torch.tensor(s, dtype=torch.float32)).double().numpy()  # (n+1, 2, k)
        basis = np.transpose(tf, (1, 2, 0)) * (s * self.corr_scale[:, None])[:, None, :]  # (2, k, n+1)
        bias = self.bias[:, None] * self.corr_scale[:, None] * s[None, :]  # (2, n+1)
        return n, np.cos(tau), np.sin(tau), basis, bias


def rollout_states(model: OperatorModel, x0: np.ndarray, n_samples: int, dtau: float, check_domain: bool = True):
    """Roll the operator from states x0 (B, 2) for n_samples samples spaced dtau in tau.

    Returns q, p (B, n_samples) and, if the rollout left the domain or went non-finite, the index of the first
    sample of the failing window and a reason; otherwise (q, p, None, None).
    """
    op = NumpyOperator(model)
    n, c, s, basis, bias = op.window_basis(dtau)
    if n < 1:
        raise DomainError(f"the model's window ({op.window:.3g} in tau) is shorter than one sample")
    x = np.array(x0, dtype=float).reshape(-1, 2)
    B = len(x)
    q = np.empty((B, n_samples))
    p = np.empty((B, n_samples))
    bq, bp = basis[0], basis[1]
    for start in range(0, n_samples, n):
        bf = op.branch_features(x)  # (B, 2, k)
        traj_q = np.outer(x[:, 0], c) + np.outer(x[:, 1], s) + bf[:, 0] @ bq + bias[0]
        traj_p = np.outer(x[:, 1], c) - np.outer(x[:, 0], s) + bf[:, 1] @ bp + bias[1]
        m = min(n, n_samples - start)
        q[:, start:start + m] = traj_q[:, :m]
        p[:, start:start + m] = traj_p[:, :m]
        x = np.stack([traj_q[:, n], traj_p[:, n]], axis=1)
        if not np.all(np.isfinite(traj_q)) or not np.all(np.isfinite(traj_p)):
            return q, p, start, "the rollout turned non-finite"
        if check_domain and start + n < n_samples and not np.all(model.domain.contains(x[:, 0], x[:, 1])):
            return q, p, start + n, "the rollout left the model's trained states"
    return q, p, None, None


def _resolve(scene: Scene, model) -> OperatorModel:
    if model is None:
        return find_model(scene)
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
    t0 = time.perf_counter()
    dtau = scene.omega / scene.sample_rate
    q, p, fail, why = rollout_states(m, np.array([[scene.q0, scene.p0]]), scene.n_samples, dtau)
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
                  info={"model_id": m.id, "model_path": str(m.path) if m.path else None, "notes": notes})


def render_operator_batch(scenes: list[Scene], model=None) -> list[Render]:
    """Many voices in one batched rollout. Voices sharing a model and a sample spacing in tau roll together."""
    groups: dict = {}
    for i, sc in enumerate(scenes):
        m = _resolve(sc, model)
        key = (id(m), sc.omega / sc.sample_rate)
        groups.setdefault(key, (m, []))[1].append(i)
    out: list = [None] * len(scenes)
    for (_, dtau), (m, idx) in groups.items():
        t0 = time.perf_counter()
        n = max(scenes[i].n_samples for i in idx)
        x0 = np.array([[scenes[i].q0, scenes[i].p0] for i in idx])
        q, p, fail, why = rollout_states(m, x0, n, dtau)
        if fail is not None:
            raise DomainError(f"{why} at t = {fail / scenes[idx[0]].sample_rate:.4f} s in a batched rollout")
        secs = (time.perf_counter() - t0) / len(idx)
        for row, i in enumerate(idx):
            sc = scenes[i]
            ns = sc.n_samples
            out[i] = Render(sc, np.arange(ns) / sc.sample_rate, q[row, :ns].copy(), p[row, :ns].copy(),
                            method="operator", seconds=secs, info={"model_id": m.id, "batched": len(idx)})
    return out
