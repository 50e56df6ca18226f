"""Training settings: the only place their defaults live (the CLI and `api.train` read them from here)."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..engines.operator.domain import MAX_WINDOW
from ..engines.operator.npnet import NetConfig  # torch-free: model files are read without torch
from ..errors import UsageError

MAX_MINUTES = 24 * 60  # a budget beyond a day is a typo (or `inf`), not a plan
MAX_STEPS = 10_000_000
# a range's band at 30 s: 320 runs of 30 s at 44.1 kHz, every 4th state kept, ~3.4 GB of states
MAX_BAND_SECONDS = 30.0
MAX_WEIGHT = 100.0  # an added term's weight (deriv: 0.02-0.1 measured; rollout); beyond 100 it is the whole loss


@dataclass
class TrainConfig:
    minutes: float | None = 5.0
    steps: int | None = None
    seed: int = 0
    # auto: the GPU where torch sees one (CUDA), else the CPU. The models are the same kind either way; the device
    # that trained one is recorded in its metadata (training.device_used)
    device: str = "auto"
    optimizer: str = "soap"  # soap | adam (measured: SOAP 5-10x lower rollout error at equal time, BENCHMARKS.md)
    lr: float = 3e-3
    lr_final: float = 2e-5
    refine_lr: float = 1e-3  # the starting rate when refining a trained range model (train --from)
    lbfgs_fraction: float = 0.0  # share of the budget for an L-BFGS finish on a fixed batch
    hybrid: bool = True
    window: float | None = None  # in tau; None picks one period of the free oscillator, 2 pi
    sampling: str = "scene"  # scene (the band a render visits) | box (the whole bounding box)
    # the renders from rest (and gestures) that make the data last this long at the recipe's f0; a range model's
    # weight selection and validation roll out as long (judge_seconds). Longer for bows whose notes grow for many
    # seconds: at F_B / w 0.02, v_B 0.28 a note from rest reaches its limit cycle after ~9 s at f0 100 (2 s at 440 Hz)
    band_seconds: float = 1.0
    margin: float = 0.05  # of the band's range, around the band
    n_data: int = 4096
    start_share: float = 0.125  # share of the data windows that start where a render's windows start (data.py)
    data_times: int = 64
    data_oversample: int = 40  # FDM data rate, as a multiple of the scene's audio rate
    batch_states: int = 1024
    batch_times: int = 64
    weights: dict | None = None  # None: chosen from the scene's stiffness (losses.default_weights)
    # the derivative term's weight (losses: deriv); None: losses.DERIV_WEIGHT for range models, none for point models
    deriv: float | None = None
    # the rollout term's weight (losses: roll; 0: none): chains of rollout_windows windows from FDM states, each window
    # started from the network's own end state, against the FDM's. The pitch of a held note is the composition of
    # many windows; a one-window loss sees a window's small phase error, not what it adds up to
    rollout: float = 0.0
    rollout_windows: int = 16
    rollout_chains: int = 1024
    rollout_batch: int = 128
    checkpoint_seconds: float = 60.0
    # keep the weights that roll out best: from this share of the budget on, every select_every seconds (0: off)
    select_every: float = 15.0
    select_from: float = 0.5
    # range models (train --fb lo:hi / --vb lo:hi / --score): renders from rest at range_points bows (Latin
    # hypercube) and range_gestures straight-line gestures make the band; range_n_data FDM windows from it
    range_points: int = 256
    range_gestures: int = 64
    range_stops: int = 64  # bow stops (ranges.stop_runs), for boxes that reach below physics.vb_stop
    range_band_stride: int = 4
    range_n_data: int = 16384
    range_corr_beta: bool = True  # the correction scaled by beta / beta_ref (npnet.NetConfig.corr_beta)
    # the state scaled per bow (npnet.NetConfig.bow_scaled). Measured, not a default and not a CLI flag: no gain on
    # the stick-slip box, 3.6x worse median on the soft ablation box (docs/BENCHMARKS.md; benchmarks/range_ablation.py)
    range_bow_scaled: bool = False
    range_select_points: int = 4  # held-out bows the weight selection rolls out from rest
    # point models: the linear part linearised at the rest state (npnet.NetConfig.rest_linear), for notes that start
    # slowly (v_B near where the bow stops driving the mass: scratch-g2); measured in docs/BENCHMARKS.md
    rest_linear: bool = False
    net: NetConfig = field(default_factory=NetConfig)

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def judge_seconds(self) -> float:
        """How long a range model's selection and validation roll out from rest: the band's length, at least 1 s."""
        return max(1.0, self.band_seconds)

    def validate(self) -> "TrainConfig":
        """Refuse settings that cannot train (one line each); returns self."""
        if self.optimizer not in ("adam", "soap"):
            raise UsageError(f"--optimizer must be adam or soap, got {self.optimizer!r}")
        if self.device not in ("auto", "cpu", "cuda"):
            raise UsageError(f"--device must be auto, cpu or cuda, got {self.device!r}")
        if not 1 <= self.batch_states <= 1_000_000:
            raise UsageError(f"--batch must be in [1, 1000000], got {self.batch_states}")
        if self.sampling not in ("scene", "box"):
            raise UsageError(f"sampling must be scene or box, got {self.sampling!r}")
        if self.minutes is not None and not (0 < self.minutes <= MAX_MINUTES):
            raise UsageError(f"--minutes must be > 0 and at most {MAX_MINUTES} (a day), got {self.minutes:g}")
        if self.steps is not None and not (1 <= self.steps <= MAX_STEPS):
            raise UsageError(f"--steps must be >= 1 and at most {MAX_STEPS}, got {self.steps}")
        if not (self.minutes or self.steps):
            raise UsageError("give a budget: --minutes or --steps")
        if not 0 <= self.lbfgs_fraction <= 0.9:
            raise UsageError(f"--lbfgs must be in [0, 0.9], got {self.lbfgs_fraction:g}")
        if self.window is not None and not (math.isfinite(self.window) and 0 < self.window <= MAX_WINDOW):
            raise UsageError(f"the window must be > 0 and at most 50 periods, got {self.window:g} in tau")
        if not (1 <= self.net.width <= 1024 and 1 <= self.net.depth <= 32):
            raise UsageError(f"--width must be in [1, 1024] and --depth in [1, 32], got {self.net.width}, "
                             f"{self.net.depth}")
        if not 0 <= self.seed < 2**32:  # numpy refuses negative seeds, torch ones past 2^64: an internal error
            raise UsageError(f"--seed must be in [0, 2^32), got {self.seed}")
        if not 16 <= self.n_data <= 1_000_000:
            raise UsageError(f"--n-data must be in [16, 1000000], got {self.n_data}")
        if not 16 <= self.range_n_data <= 1_000_000:
            raise UsageError(f"--n-data must be in [16, 1000000], got {self.range_n_data}")
        if not (1 <= self.range_points <= 100_000 and 0 <= self.range_gestures <= 100_000):
            raise UsageError(f"range points must be in [1, 100000], gestures in [0, 100000], got "
                             f"{self.range_points}, {self.range_gestures}")
        if not (math.isfinite(self.band_seconds) and 0 < self.band_seconds <= MAX_BAND_SECONDS):
            raise UsageError(f"--band-seconds must be > 0 and at most {MAX_BAND_SECONDS:g}, got {self.band_seconds:g}")
        if self.deriv is not None and not (math.isfinite(self.deriv) and 0 <= self.deriv <= MAX_WEIGHT):
            raise UsageError(f"--deriv must be in [0, {MAX_WEIGHT:g}], got {self.deriv:g}")
        if not (math.isfinite(self.rollout) and 0 <= self.rollout <= MAX_WEIGHT):
            raise UsageError(f"--rollout must be in [0, {MAX_WEIGHT:g}], got {self.rollout:g}")
        if not (1 <= self.rollout_windows <= 256 and 16 <= self.rollout_chains <= 1_000_000
                and 1 <= self.rollout_batch <= self.rollout_chains):
            raise UsageError(f"rollout chains: windows in [1, 256], chains in [16, 1000000], a batch in [1, chains], "
                             f"got {self.rollout_windows}, {self.rollout_chains}, {self.rollout_batch}")
        if not (math.isfinite(self.checkpoint_seconds) and self.checkpoint_seconds > 0):
            raise UsageError(f"--checkpoint-every must be > 0 s, got {self.checkpoint_seconds:g}")
        return self


def resolve_device(name: str) -> str:
    """The torch device a training runs on: auto takes CUDA where torch sees a GPU. Asking for cuda where there is
    none is refused in one line (not torch's traceback)."""
    import torch

    if name == "cpu" or (name == "auto" and not torch.cuda.is_available()):
        return "cpu"
    if not torch.cuda.is_available():
        raise UsageError("--device cuda: torch sees no CUDA GPU here (this torch is "
                         f"{torch.__version__}); use --device cpu or auto")
    return "cuda"


def check_net_options(cfg: TrainConfig, scene, box=None) -> None:
    """The network options only where they apply (one line each): range_bow_scaled for a range model; --rest-linear for
    a point model whose bow's linearisation at rest is underdamped (|F_B / w phi'(-v_B)| <
    physics.MAX_REST_DAMPING). Runs before anything loads or renders."""
    from .. import physics

    if cfg.range_bow_scaled and (box is None or box.is_point):
        raise UsageError("range_bow_scaled is for range models (a box of bows, not one bow)")
    if not cfg.rest_linear:
        return
    if box is not None and not box.is_point:
        raise UsageError("--rest-linear is for point models (a range model's rest state moves with the bow)")
    d, _ = physics.rest_linearisation(scene.beta, scene.vb, scene.a)
    if not abs(d) < physics.MAX_REST_DAMPING:
        raise UsageError(f"--rest-linear: the bow's linearisation at rest is too strongly damped or driven "
                         f"(F_B / w phi'(-v_B) = {d:.3g}, at most {physics.MAX_REST_DAMPING:g} in size): train "
                         f"without it")


def check_refine(init, cfg: TrainConfig, scene, box) -> None:
    """train --from MODEL (one line each): MODEL is a range model, at the scene's a, whose box holds the bows to train,
    and the network options it fixes are not given again."""
    import math

    from ..engines.operator.domain import REL_TOL

    what = init.path or init.meta.name
    if not init.domain.is_range:
        raise UsageError(f"--from takes a range model; {what} plays one bow ({init.domain.describe_bows()})")
    if not math.isclose(init.domain.a, scene.a, rel_tol=REL_TOL):
        raise UsageError(f"--from {what} has a = {init.domain.a:g}; this scene has a = {scene.a:g}")
    given = [name for name, on in (("--rest-linear", cfg.rest_linear), ("range_bow_scaled", cfg.range_bow_scaled)) if on]
    if given:
        raise UsageError(f"--from keeps the network of the model it refines: drop {' and '.join(given)}")
    d = init.domain
    if not (d.beta_in(box.beta_lo) and d.beta_in(box.beta_hi) and d.vb_in(box.vb_lo) and d.vb_in(box.vb_hi)):
        raise UsageError(f"--from {what} plays {d.describe_bows()}; the bows to train ({box.describe()}) must lie "
                         f"inside it")


def checkpoint_path(out) -> Path:
    """Where the checkpoint of the model file `out` lives (beside it)."""
    out = Path(out)
    return out.with_name(out.name.removesuffix(".safetensors") + ".ckpt.safetensors")


def default_model_name(scene) -> str:
    return f"fb{scene.fb:g}_f0{scene.f0:g}_vb{scene.vb:g}_a{scene.a:g}"
