"""The training loop: SOAP/Adam steps on batches of the data, budgets, checkpoints, weight selection, packaging."""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ..engines.operator.modelfile import ModelMeta, OperatorModel
from ..engines.operator.network import DeepONet, NetConfig
from ..errors import UsageError
from ..scene import Scene
from ..io.text import jsonable
from . import checkpoint
from .config import TrainConfig, check_net_options, resolve_device
from .data import add_chains, build, build_range
from .losses import default_weights, loss_terms, weighted
from .selection import RangeSelector, Selector, selection_scene

MAX_STEPS = 10**9  # a checkpoint further on than this is not a run's


@dataclass
class TrainResult:
    model: OperatorModel
    path: Path | None
    history: list = field(default_factory=list)


class Trainer:
    """Trains a point model for `scene`, or a range model for the bows of `box` (a ParamBox that is not a point; the
    scene then gives the pitch, rate and a at which the band is rendered, its bow the box's centre)."""

    def __init__(self, scene: Scene, cfg: TrainConfig, name: str, on_progress=None, box=None, init=None):
        cfg.validate()
        self.device = torch.device(resolve_device(cfg.device))
        # init: a trained range model (OperatorModel) to refine: its network, scalings and window are kept, and it
        # trains on this box's data (a box of zero width too: a point refined from the range)
        self.init = init
        self.box = box if box is not None and (init is not None or not box.is_point) else None
        check_net_options(cfg, scene, self.box)
        if init is not None:
            cfg.net = NetConfig(**init.cfg.to_dict())
            cfg.window = float(init.domain.window)
        elif self.box is not None:
            cfg.net = dataclasses.replace(cfg.net, params=2, corr_beta=cfg.range_corr_beta,
                                          bow_scaled=cfg.range_bow_scaled)
        if cfg.rest_linear:
            cfg.net = dataclasses.replace(cfg.net, rest_linear=True)
        self.scene, self.cfg, self.name = scene, cfg, name
        self.weights = cfg.weights or default_weights(scene, cfg.hybrid,
                                                      beta_max=None if self.box is None else self.box.beta_hi,
                                                      deriv=cfg.deriv, rollout=cfg.rollout)
        self.window = cfg.window or 2 * math.pi
        self.rng = np.random.default_rng(cfg.seed)
        torch.manual_seed(cfg.seed)
        if self.box is None:
            self.data = build(scene, cfg, self.window, self.rng, on_progress=on_progress)
        else:
            self.data = build_range(scene, self.box, cfg, self.window, self.rng, on_progress=on_progress)
        self.data = add_chains(self.data, scene, cfg, self.window, on_progress=on_progress)
        self.domain, self.sampler = self.data.domain, self.data.sampler
        d = self.domain
        self.net = DeepONet(cfg.net, seed=cfg.seed)
        if init is not None:  # the parent's weights and every scaling buffer: the function it learned, unchanged
            self.net.load_state_dict(init.net.state_dict())
        else:
            self.net.set_scales([(d.q_lo + d.q_hi) / 2, (d.p_lo + d.p_hi) / 2],
                                [(d.q_hi - d.q_lo) / 2, (d.p_hi - d.p_lo) / 2], self.data.corr_scale, self.window)
            if self.box is not None:
                self.net.set_box(self.box)
                if cfg.net.bow_scaled:
                    self._fit_bow_scaling()
            if cfg.net.rest_linear:
                self.net.set_rest_linear(scene.beta, scene.vb, scene.a)
        self.net.to(self.device)  # after the scalings, which are fitted in numpy
        self.data_x0, self.data_x, self.data_tau = (self._tensor(v) for v in (self.data.x0, self.data.x, self.data.tau))
        self.data_par = None if self.data.par is None else self._tensor(self.data.par)
        self.chain_x, self.chain_par = (None if v is None else self._tensor(v)
                                        for v in (self.data.chain_x, self.data.chain_par))
        self.opt = self._make_optimizer()
        self.step = 0
        self.elapsed = 0.0
        self.history: list[dict] = []
        if self.box is None:
            self.selector = Selector(selection_scene(scene, self.data.band, self.window, d.contains))
        else:
            self.selector = RangeSelector(scene, self.box, cfg.range_select_points, seed=cfg.seed + 1,
                                          seconds=cfg.judge_seconds)

    def _fit_bow_scaling(self):
        from .ranges import fit_bow_scaling

        ext = self.data.extents
        pin = self.net.param_inputs(torch.tensor(ext[:, :2], dtype=torch.float64)).double().numpy()
        fit = fit_bow_scaling(ext, pin, self.cfg.margin)
        if fit is None:  # too few renders spoke to fit: the box's scaling, the same for every bow
            return
        self.net.set_bow_scaling(*fit)

    @property
    def best(self) -> dict:
        return self.selector.best

    @property
    def lr(self) -> float:
        """The starting learning rate: a refinement starts lower (TrainConfig.refine_lr), not to throw away what the
        parent learned in its first steps."""
        return self.cfg.refine_lr if self.init is not None else self.cfg.lr

    def _make_optimizer(self):
        params = self.net.parameters()
        if self.cfg.optimizer == "soap":
            from pytorch_optimizer import SOAP

            return SOAP(params, lr=self.lr, betas=(0.95, 0.95), precondition_frequency=10)
        return torch.optim.Adam(params, lr=self.lr, fused=True)

    def _tensor(self, a):
        return torch.as_tensor(np.asarray(a, dtype=np.float32)).to(self.device)

    def batch(self, n_states: int | None = None) -> dict:
        # drawn by numpy on the CPU whatever the device, so a seed draws the same batches on either
        cfg = self.cfg
        n = n_states or cfg.batch_states
        idx = torch.from_numpy(self.rng.integers(0, len(self.data_x0), n)).to(self.device)
        out = {"data_x0": self.data_x0[idx], "data_x": self.data_x[idx], "data_tau": self.data_tau,
               "phys_tau": self._tensor(self.rng.uniform(0, self.window, cfg.batch_times))}
        if self.box is None:
            out["phys_x0"] = self._tensor(self.sampler(n))
        else:
            x0, par = self.sampler(n)
            out.update(phys_x0=self._tensor(x0), phys_par=self._tensor(par), data_par=self.data_par[idx])
        if self.chain_x is not None:
            ci = torch.from_numpy(self.rng.integers(0, len(self.chain_x), cfg.rollout_batch)).to(self.device)
            out["chain_x"] = self.chain_x[ci]
            if self.chain_par is not None:
                out["chain_par"] = self.chain_par[ci]
        return out

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
        lr = self.lr * (self.cfg.lr_final / self.lr) ** min(frac, 1.0)
        for g in self.opt.param_groups:
            g["lr"] = lr
        terms = loss_terms(self.net, self.batch(), self.scene, self.weights)
        loss = weighted(terms, self.weights)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        self.opt.step()
        self.step += 1
        return {"loss": float(loss.detach()), "lr": lr, **{k: float(v.detach()) for k, v in terms.items()}}

    def lbfgs_finish(self, seconds: float, on_step=None):
        """L-BFGS on one fixed large batch (strong Wolfe), until the time is spent."""
        opt = torch.optim.LBFGS(self.net.parameters(), lr=1.0, max_iter=20, history_size=50,
                                line_search_fn="strong_wolfe")
        batch = self.batch(min(4 * self.cfg.batch_states, len(self.data_x0)))

        def closure():
            opt.zero_grad(set_to_none=True)
            loss = weighted(loss_terms(self.net, batch, self.scene, self.weights), self.weights)
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

    def save_checkpoint(self, path: Path):
        tensors = {f"net.{k}": v.detach().cpu().contiguous().clone() for k, v in self.net.state_dict().items()}
        if self.best["state"] is not None:
            tensors.update({f"best.{k}": v.cpu().contiguous() for k, v in self.best["state"].items()})
        meta = {"step": self.step, "elapsed": self.elapsed, "rng": self.rng.bit_generator.state,
                "scene": self.scene.to_dict(), "box": self._box_json(), "config": self.cfg.to_dict(),
                "init": self._init_id(), "history": self.history[-200:],
                "best": {"score": jsonable(self.best["score"]), "step": self.best["step"],
                         "scored": self.best["scored"]}}
        checkpoint.save(path, {"tensors": tensors, "optimizer": self.opt.state_dict(), "meta": meta})

    def load_checkpoint(self, path: Path):
        tensors, opt_state, meta = checkpoint.load(path)
        try:
            self._restore(path, tensors, opt_state, meta)
        except (KeyError, TypeError, ValueError, RuntimeError, IndexError) as e:
            raise UsageError(f"checkpoint {path} is damaged or forged ({type(e).__name__}: {str(e)[:100]}); delete it "
                             f"to start afresh") from None

    def _restore(self, path: Path, tensors: dict, opt_state, meta: dict):
        step, elapsed = meta.get("step"), meta.get("elapsed")
        if (not isinstance(step, int) or isinstance(step, bool) or not 0 <= step <= MAX_STEPS
                or not isinstance(elapsed, (int, float)) or not math.isfinite(elapsed) or not 0 <= elapsed <= 1e7
                or not isinstance(meta.get("history"), list) or not isinstance(meta.get("rng"), dict)):
            raise ValueError(f"step {step!r}, elapsed {elapsed!r}: not a run's")
        if meta["scene"] != self.scene.to_dict() or meta.get("box") != self._box_json():
            raise UsageError(f"checkpoint {path} is for another scene; delete it or pick another --out")
        if meta.get("init") != self._init_id():
            was = meta.get("init")
            raise UsageError(f"checkpoint {path} was made " + (f"refining model {was}: resume with the same --from"
                                                                if was else "without --from: resume without it"))
        self.net.load_state_dict({k[4:]: v for k, v in tensors.items() if k.startswith("net.")})
        best = meta.get("best") or {}
        state = {k[5:]: v for k, v in tensors.items() if k.startswith("best.")}
        self.best.update(score=math.inf if best.get("score") is None else best["score"], step=best.get("step"),
                         state=state or None, scored=best.get("scored", 0))
        self.opt.load_state_dict(opt_state)
        self.rng.bit_generator.state = meta["rng"]
        self.step, self.elapsed, self.history = meta["step"], meta["elapsed"], meta["history"]

    def _init_id(self):
        return None if self.init is None else self.init.id

    def _box_json(self):
        return None if self.box is None else self.box.to_json()

    def done(self) -> bool:
        return self.progress() >= 1.0 - self.cfg.lbfgs_fraction if self.cfg.lbfgs_fraction else self.progress() >= 1.0

    def _consider(self):
        self.selector.consider(self.model(), self.step, self.net.state_dict())

    def run(self, ckpt: Path | None = None, on_step=None):
        """SOAP/Adam until the budget (less the L-BFGS share) is spent, checkpointing as it goes; then the weights
        that rolled out best (see selection.py) among those scored in the budget's last part."""
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
        self.net.to("cpu")  # the model and its validation run on the CPU, as renders do

    def device_name(self) -> str:
        if self.device.type == "cuda":
            return f"cuda: {torch.cuda.get_device_name(self.device)}"
        return f"cpu: {torch.get_num_threads()} threads"

    def model(self) -> OperatorModel:
        meta = ModelMeta(name=self.name, domain=self.domain, net=self.cfg.net.to_dict(),
                         training={**{k: v for k, v in self.cfg.to_dict().items() if k != "net"},
                                   "weights": self.weights, "steps_done": self.step,
                                   "seconds": round(self.elapsed, 1), "device_used": self.device_name(),
                                   "final_loss": self.history[-1]["loss"] if self.history else None,
                                   "selected": self.selector.record(), "box": self._box_json(),
                                   "refined_from": self._init_id()},
                         validation={}, scene=self.scene.to_dict())
        return OperatorModel(self.net, meta)
