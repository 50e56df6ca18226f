"""Training the PI-DeepONet for one scene: data on the scene's band of states, physics and FDM losses, budgets,
checkpoints and resume, validation by a rollout against a high-rate FDM.

Losses are a dict of named terms (each normalised to O(1) by the correction scale c):
  data  - trajectories against a high-rate batch FDM from band states (hybrid only)
  end   - the window's end state against the FDM (it seeds the next window, so its error compounds)
  kin   - kinematic residual q' - p
  fric  - friction residual p' + q + beta phi(p - v_B); stiff at high force, where it fights the data
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy import ndimage

from . import physics
from .errors import UsageError
from .fdm import fdm_batch, render_fdm
from .model import Domain, ModelMeta, OperatorModel
from .network import DeepONet, NetConfig
from .scene import Scene

STIFF = 10.0  # beta sqrt(2a) e^1/2 above this: the friction residual is dropped from the hybrid loss by default
GRID = 64  # domain mask resolution
FRIC_WEIGHT = 0.03  # hybrid, non-stiff: fb 100, 3 min SOAP: 0.3 -> 2.3e-3, 0.1 -> 3.8e-4, 0.03 -> 3.5e-5 NMSE(p) 1 s


@dataclass
class TrainConfig:
    minutes: float | None = 5.0
    steps: int | None = None
    seed: int = 0
    optimizer: str = "soap"  # soap | adam (measured: SOAP 5-10x lower rollout error at equal time, BENCHMARKS.md)
    lr: float = 3e-3
    lr_final: float = 2e-5
    lbfgs_fraction: float = 0.0  # share of the budget for an L-BFGS finish on a fixed batch
    hybrid: bool = True
    window: float | None = None  # in tau; None picks one period of the free oscillator, 2 pi
    sampling: str = "scene"  # scene (the band a render visits) | box (the whole bounding box)
    band_seconds: float = 1.0
    margin: float = 0.05  # of the band's range, around the band
    n_data: int = 4096
    start_share: float = 0.125  # share of the data windows that start where a render's windows start (see below)
    data_times: int = 64
    data_oversample: int = 40  # FDM data rate, as a multiple of the scene's audio rate
    batch_states: int = 1024
    batch_times: int = 64
    weights: dict | None = None  # None: chosen from the scene's stiffness (see default_weights)
    checkpoint_seconds: float = 60.0
    # keep the weights that roll out best: from this share of the budget on, every select_every seconds (0: off)
    select_every: float = 15.0
    select_from: float = 0.5
    net: NetConfig = field(default_factory=NetConfig)

    def to_dict(self) -> dict:
        return asdict(self)


def _json_number(x: float):
    """x for JSON metadata: inf and NaN (no score) become null."""
    return x if math.isfinite(x) else None


def stiffness(scene: Scene) -> float:
    """Friction slope at rest in dimensionless time: beta sqrt(2a) e^{1/2}."""
    return scene.beta * math.sqrt(2 * scene.a) * physics.E_HALF


def default_weights(scene: Scene, hybrid: bool) -> dict:
    if not hybrid:
        return {"kin": 1.0, "fric": 1.0}
    w = {"data": 1.0, "end": 1.0, "kin": 1.0}
    if stiffness(scene) < STIFF:
        w["fric"] = FRIC_WEIGHT
    return w


# --- the scene's band of states -------------------------------------------------------------------------------

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

    def __call__(self, n: int) -> np.ndarray:
        out = np.empty((0, 2))
        while len(out) < n:
            if self.box:
                d = self.domain
                x = self.rng.uniform([d.q_lo, d.p_lo], [d.q_hi, d.p_hi], size=(2 * n, 2))
            else:
                idx = np.minimum(np.searchsorted(self.cdf, self.rng.random(2 * n)), len(self.band) - 1)
                x = self.band[idx] + self.rng.normal(0, 1, (2 * n, 2)) * self.sd
            x = x[self.domain.contains(x[:, 0], x[:, 1])]
            out = np.concatenate([out, x])
        return out[:n]


def fdm_windows(scene: Scene, x0: np.ndarray, window: float, n_times: int, oversample: int):
    """High-rate FDM trajectories over one window from each state: (tau (M+1,), x (B, M+1, 2))."""
    w = scene.omega
    k_audio_tau = w / scene.sample_rate
    stride = max(1, math.ceil(window / n_times / (k_audio_tau / oversample)))
    k = window / (n_times * stride) / w  # seconds
    if k >= physics.max_stable_step(scene.fb, scene.a):
        stride = math.ceil(window / n_times / (0.9 * physics.max_stable_step(scene.fb, scene.a) * w))
        k = window / (n_times * stride) / w
    q, p = fdm_batch(x0[:, 0], x0[:, 1], n_times + 1, stride, k, w, scene.fb, scene.vb, scene.a)
    tau = np.arange(n_times + 1) * window / n_times
    return tau, np.stack([q, p], axis=-1)


# --- losses ---------------------------------------------------------------------------------------------------

def residuals(net: DeepONet, x, dx, b: float, vb: float, a: float):
    """Dimensionless ODE residuals (kinematic, friction) of trajectories x with derivatives dx, scaled by c / T."""
    q, p = x[..., 0], x[..., 1]
    dq_ref, dp_ref = physics.rhs_tau(q, p, b, vb, a)
    scale = net.corr_scale / net.window
    return (dx[..., 0] - dq_ref) / scale[0], (dx[..., 1] - dp_ref) / scale[1]


def loss_terms(net, batch: dict, scene: Scene, weights: dict) -> dict:
    """The named loss terms. Branch and trunk run once each on the data and physics points together: on a CPU
    these small networks cost mostly per-call overhead."""
    use_data = "data" in weights or "end" in weights
    use_phys = "kin" in weights or "fric" in weights
    x0s = [batch["data_x0"]] * use_data + [batch["phys_x0"]] * use_phys
    taus = [batch["data_tau"]] * use_data + [batch["phys_tau"]] * use_phys
    bf = net.branch_features(torch.cat(x0s))
    tau_all = torch.cat(taus)
    if use_phys:
        tf, dtf = net.trunk_features_jvp(tau_all / net.window)
    else:
        tf, dtf = net.trunk_features(tau_all / net.window), None
    terms = {}
    nb, nm = (len(batch["data_x0"]), len(batch["data_tau"])) if use_data else (0, 0)
    if use_data:
        pred = net.assemble(batch["data_x0"], batch["data_tau"], bf[:nb], tf[:nm])
        err = (pred - batch["data_x"]) / net.corr_scale
        if "data" in weights:
            terms["data"] = err.square().mean()
        if "end" in weights:
            terms["end"] = err[:, -1].square().mean()
    if use_phys:
        x, dx = net.assemble(batch["phys_x0"], batch["phys_tau"], bf[nb:], tf[nm:], dtf[nm:])
        rk, rf = residuals(net, x, dx, scene.beta, scene.vb, scene.a)
        if "kin" in weights:
            terms["kin"] = rk.square().mean()
        if "fric" in weights:
            terms["fric"] = rf.square().mean()
    return terms


# --- checkpoints (no pickle: tensors in safetensors, the rest as JSON) ----------------------------------------

def _flatten_state(obj, prefix, tensors):
    if isinstance(obj, torch.Tensor):
        tensors[prefix] = obj.detach().contiguous().clone()
        return {"__tensor__": prefix}
    if isinstance(obj, dict):
        return {"__dict__": [[_flatten_state(k, f"{prefix}.k{i}", tensors), _flatten_state(v, f"{prefix}.{i}", tensors)]
                             for i, (k, v) in enumerate(obj.items())]}
    if isinstance(obj, (list, tuple)):
        return {"__list__": [_flatten_state(v, f"{prefix}.{i}", tensors) for i, v in enumerate(obj)],
                "tuple": isinstance(obj, tuple)}
    return obj


def _unflatten_state(obj, tensors):
    if isinstance(obj, dict) and "__tensor__" in obj:
        return tensors[obj["__tensor__"]]
    if isinstance(obj, dict) and "__dict__" in obj:
        return {_unflatten_state(k, tensors): _unflatten_state(v, tensors) for k, v in obj["__dict__"]}
    if isinstance(obj, dict) and "__list__" in obj:
        items = [_unflatten_state(v, tensors) for v in obj["__list__"]]
        return tuple(items) if obj.get("tuple") else items
    return obj


def checkpoint_path(out: Path) -> Path:
    return out.with_name(out.name.removesuffix(".safetensors") + ".ckpt.safetensors")


# --- the trainer ----------------------------------------------------------------------------------------------

@dataclass
class TrainResult:
    model: OperatorModel
    path: Path | None
    history: list = field(default_factory=list)


class Trainer:
    def __init__(self, scene: Scene, cfg: TrainConfig, name: str):
        if cfg.optimizer not in ("adam", "soap"):
            raise UsageError(f"--optimizer must be adam or soap, got {cfg.optimizer!r}")
        if cfg.sampling not in ("scene", "box"):
            raise UsageError(f"sampling must be scene or box, got {cfg.sampling!r}")
        if not (cfg.minutes or cfg.steps):
            raise UsageError("give a budget: --minutes or --steps")
        self.scene, self.cfg, self.name = scene, cfg, name
        self.weights = cfg.weights or default_weights(scene, cfg.hybrid)
        self.window = cfg.window or 2 * math.pi
        self.rng = np.random.default_rng(cfg.seed)
        torch.manual_seed(cfg.seed)
        box = cfg.sampling == "box"
        band = scene_band(scene, cfg.band_seconds)
        self.domain = make_domain(scene, band, self.window, cfg.margin, box_only=box)
        self.sampler = StateSampler(band, self.domain, cfg.margin, box, self.rng)
        # FDM trajectories from band states: the data loss, and the correction scale c even without it
        x0 = self.sampler(cfg.n_data if cfg.hybrid else min(cfg.n_data, 512))
        if cfg.hybrid and cfg.start_share > 0:
            # A render from the scene's initial state starts its windows at exactly these band states; its onset
            # windows are visited once and were its largest error. Train on them, with a little noise so that
            # other sample rates and pitches (other window alignments) stay covered.
            n_win = max(1, int(self.window / (scene.omega / scene.sample_rate) + 1e-9))
            starts = band[::n_win]
            m = min(len(x0), int(cfg.start_share * len(x0)))
            pick = starts[np.arange(m) % len(starts)]
            jitter = self.rng.normal(0, 1, pick.shape) * self.sampler.sd * 0.2
            jitter[: len(starts)] = 0.0
            x0[:m] = pick + jitter
        tau, x = fdm_windows(scene, x0, self.window, cfg.data_times, cfg.data_oversample)
        if cfg.net.linear_flow:
            lq, lp = physics.linear_flow(x0[:, 0:1], x0[:, 1:2], tau[None, :])
        else:
            lq, lp = np.broadcast_arrays(x0[:, 0:1], x0[:, 1:2], tau[None, :])[:2]
        corr = (x - np.stack([lq, lp], -1))[:, 1:] / (tau[1:] / self.window)[None, :, None]
        c = np.sqrt(np.mean(corr ** 2, axis=(0, 1))).clip(1e-6)
        d = self.domain
        self.net = DeepONet(cfg.net, seed=cfg.seed)
        self.net.set_scales([(d.q_lo + d.q_hi) / 2, (d.p_lo + d.p_hi) / 2],
                            [(d.q_hi - d.q_lo) / 2, (d.p_hi - d.p_lo) / 2], c, self.window)
        self.data_x0 = torch.tensor(x0, dtype=torch.float32)
        self.data_x = torch.tensor(x, dtype=torch.float32)
        self.data_tau = torch.tensor(tau, dtype=torch.float32)
        self.opt = self._make_optimizer()
        self.step = 0
        self.elapsed = 0.0
        self.history: list[dict] = []
        self.best: dict = {"score": math.inf, "step": None, "state": None, "scored": 0}
        self._select_ref = None

    def _make_optimizer(self):
        params = self.net.parameters()
        if self.cfg.optimizer == "soap":
            from pytorch_optimizer import SOAP

            return SOAP(params, lr=self.cfg.lr, betas=(0.95, 0.95), precondition_frequency=10)
        return torch.optim.Adam(params, lr=self.cfg.lr, fused=True)

    def batch(self) -> dict:
        cfg = self.cfg
        idx = torch.from_numpy(self.rng.integers(0, len(self.data_x0), cfg.batch_states))
        return {
            "data_x0": self.data_x0[idx], "data_x": self.data_x[idx], "data_tau": self.data_tau,
            "phys_x0": torch.tensor(self.sampler(cfg.batch_states), dtype=torch.float32),
            "phys_tau": torch.tensor(self.rng.uniform(0, self.window, cfg.batch_times), dtype=torch.float32),
        }

    def progress(self) -> float:
        cfg = self.cfg
        fr = []
        if cfg.steps:
            fr.append(self.step / cfg.steps)
        if cfg.minutes:
            fr.append(self.elapsed / (60 * cfg.minutes))
        return min(1.0, max(fr))

    def train_step(self) -> dict:
        frac = self.progress() / max(1e-9, 1 - self.cfg.lbfgs_fraction)
        lr = self.cfg.lr * (self.cfg.lr_final / self.cfg.lr) ** min(frac, 1.0)
        for g in self.opt.param_groups:
            g["lr"] = lr
        terms = loss_terms(self.net, self.batch(), self.scene, self.weights)
        loss = sum(self.weights[k] * v for k, v in terms.items())
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        self.opt.step()
        self.step += 1
        return {"loss": float(loss.detach()), "lr": lr, **{k: float(v.detach()) for k, v in terms.items()}}

    def lbfgs_finish(self, seconds: float, on_step=None):
        """L-BFGS on one fixed large batch (strong Wolfe), until the time is spent."""
        opt = torch.optim.LBFGS(self.net.parameters(), lr=1.0, max_iter=20, history_size=50,
                                line_search_fn="strong_wolfe")
        cfg = self.cfg
        save = cfg.batch_states
        cfg.batch_states = min(4 * save, len(self.data_x0))
        batch = self.batch()
        cfg.batch_states = save

        def closure():
            opt.zero_grad(set_to_none=True)
            terms = loss_terms(self.net, batch, self.scene, self.weights)
            loss = sum(self.weights[k] * v for k, v in terms.items())
            loss.backward()
            return loss

        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            loss = opt.step(closure)
            self.step += 1
            if not math.isfinite(float(loss)):
                break
            if on_step:
                on_step({"loss": float(loss), "lbfgs": 1.0})

    # checkpoints
    def save_checkpoint(self, path: Path):
        from safetensors.torch import save_file

        from .wav import atomic_write

        tensors = {f"net.{k}": v.detach().contiguous().clone() for k, v in self.net.state_dict().items()}
        if self.best["state"] is not None:
            tensors.update({f"best.{k}": v.contiguous() for k, v in self.best["state"].items()})
        opt_state = _flatten_state(self.opt.state_dict(), "opt", tensors)
        meta = {"step": self.step, "elapsed": self.elapsed, "opt": opt_state, "rng": self.rng.bit_generator.state,
                "torch_rng": None, "scene": self.scene.to_dict(), "config": self.cfg.to_dict(),
                "history": self.history[-200:],
                "best": {"score": _json_number(self.best["score"]),
                         "step": self.best["step"], "scored": self.best["scored"]}}
        tensors["torch_rng"] = torch.get_rng_state()
        atomic_write(path, lambda tmp: save_file(tensors, tmp, metadata={"bowsynth_checkpoint": json.dumps(meta)}))

    def load_checkpoint(self, path: Path):
        from safetensors import safe_open

        try:
            with safe_open(str(path), framework="pt") as f:
                meta = json.loads(f.metadata()["bowsynth_checkpoint"])
                tensors = {k: f.get_tensor(k) for k in f.keys()}
        except Exception as e:
            raise UsageError(f"checkpoint {path} is unreadable ({type(e).__name__}); delete it to start afresh") from None
        if meta["scene"] != self.scene.to_dict():
            raise UsageError(f"checkpoint {path} is for another scene; delete it or pick another --out")
        self.net.load_state_dict({k[4:]: v for k, v in tensors.items() if k.startswith("net.")})
        best = meta.get("best") or {}
        state = {k[5:]: v for k, v in tensors.items() if k.startswith("best.")}
        self.best = {"score": math.inf if best.get("score") is None else best["score"], "step": best.get("step"),
                     "state": state or None, "scored": best.get("scored", 0)}
        self.opt.load_state_dict(_unflatten_state(meta["opt"], tensors))
        self.rng.bit_generator.state = meta["rng"]
        torch.set_rng_state(tensors["torch_rng"])
        self.step, self.elapsed, self.history = meta["step"], meta["elapsed"], meta["history"]

    def done(self) -> bool:
        return self.progress() >= 1.0 - self.cfg.lbfgs_fraction if self.cfg.lbfgs_fraction else self.progress() >= 1.0

    def selection_score(self) -> float:
        """NMSE(p) of a 1 s rollout from the scene's initial state at 1.5x its pitch (same F_B / w, so the same
        dimensionless note at other sample offsets) against a x100 FDM. The weights are chosen on it; the validation
        at the scene's own pitch stays independent of the choice."""
        import warnings

        from .errors import BowsynthError
        from .metrics import nmse
        from .rollout import render_operator

        try:
            if self._select_ref is None:
                try:
                    s = self.scene.replace(f0=1.5 * self.scene.f0, fb=1.5 * self.scene.fb, duration=1.0)
                except BowsynthError:  # 1.5x the pitch is out of range: the scene itself
                    s = self.scene.replace(duration=1.0)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    self._select_ref = (s, render_fdm(s, oversample=100).p)
            s, ref = self._select_ref
            score = float(nmse(render_operator(s, model=self.model()).p, ref))
        except BowsynthError:  # the rollout left its domain (or no reference for this scene)
            return math.inf
        return score if math.isfinite(score) else math.inf

    def _consider(self):
        score = self.selection_score()
        self.best["scored"] += 1
        if score < self.best["score"]:
            self.best.update(score=score, step=self.step,
                             state={k: v.detach().clone() for k, v in self.net.state_dict().items()})

    def run(self, ckpt: Path | None = None, on_step=None):
        """Adam/SOAP until the budget (less the L-BFGS share) is spent, checkpointing as it goes; then the weights
        that rolled out best (see selection_score) among those scored in the budget's last part."""
        last_ckpt = last_select = time.perf_counter()
        t_prev = time.perf_counter()
        select = self.cfg.select_every > 0
        while not self.done():
            rec = self.train_step()
            now = time.perf_counter()
            self.elapsed += now - t_prev
            t_prev = now
            if not math.isfinite(rec["loss"]):
                raise FloatingPointError(f"training diverged at step {self.step} (loss {rec['loss']})")
            if self.step % 50 == 0:
                self.history.append({"step": self.step, "t": round(self.elapsed, 2), **rec})
            if on_step:
                on_step(rec)
            if select and self.progress() >= self.cfg.select_from and now - last_select >= self.cfg.select_every:
                self._consider()  # its few ms count against the budget
                last_select = time.perf_counter()
            if ckpt is not None and now - last_ckpt > self.cfg.checkpoint_seconds:
                self.save_checkpoint(ckpt)
                last_ckpt = time.perf_counter()
                t_prev = last_ckpt
        if self.cfg.lbfgs_fraction and self.cfg.minutes:
            budget = 60 * self.cfg.minutes - self.elapsed
            t0 = time.perf_counter()
            self.lbfgs_finish(budget, on_step)
            self.elapsed += time.perf_counter() - t0
        if select:
            self._consider()  # the final weights compete too
            if self.best["state"] is not None and self.best["step"] != self.step:
                self.net.load_state_dict(self.best["state"])

    def model(self) -> OperatorModel:
        meta = ModelMeta(name=self.name, domain=self.domain, net=self.cfg.net.to_dict(),
                         training={**{k: v for k, v in self.cfg.to_dict().items() if k != "net"},
                                   "weights": self.weights, "steps_done": self.step,
                                   "seconds": round(self.elapsed, 1),
                                   "final_loss": self.history[-1]["loss"] if self.history else None,
                                   "selected": {"step": self.best["step"], "scored": self.best["scored"],
                                                "score_nmse_p_at_1.5_f0": _json_number(self.best["score"])}},
                         validation={}, scene=self.scene.to_dict())
        return OperatorModel(self.net, meta)


def validate(model: OperatorModel, scene: Scene, seconds: float = 1.0, ref_oversample: int = 100) -> dict:
    """NMSE etc. of a rollout from the scene's initial state against a high-rate FDM, over `seconds`."""
    from .metrics import compare_signals
    from .rollout import render_operator

    from .errors import DomainError

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
    return {k: (_json_number(v) if isinstance(v, float) else v) for k, v in m.items()}


def default_model_name(scene: Scene) -> str:
    return f"fb{scene.fb:g}_f0{scene.f0:g}_vb{scene.vb:g}_a{scene.a:g}"
