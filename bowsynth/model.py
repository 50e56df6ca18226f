"""Model files: safetensors weights + JSON metadata (no pickle) bound together by a digest, and the domain a model
covers. Reading a model needs numpy only (no torch).

A model is trained for one dimensionless scene (beta = F_B / w, v_B, a) over a window of T in tau, on the band of
states a render visits. The domain records that band as a box plus an occupancy mask on a grid over the box.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from . import __version__, physics
from .controls import Curve
from .errors import ModelFileError
from .npnet import NetConfig, weight_shapes
from .scene import Scene

FORMAT = "bowsynth-operator"
FORMAT_VERSION = 2  # 2: a digest binds the metadata to the weights
RANGE_VERSION = 3  # 3: a range model (its domain has a box of bows, its branch takes them); point models stay 2
READ_VERSIONS = (1, 2, 3)
META_KEY = "bowsynth"
REL_TOL = 1e-6  # beta, v_B, a must match the training scene this closely: the network does not take them as input

# A model whose validation NMSE(p) (1 s from the training scene's initial state against a x100 FDM) is above this is
# not picked by default: the shipped models score 1e-7 to 3e-4; 0.1 is a note visibly off in phase or pitch.
MAX_VALIDATION_NMSE = 0.1


MAX_BETA = 1e3  # F_B / w: the playing space ends at 2, the FDM's uniqueness bound at audio rate near 16
MAX_A = 1e6
MAX_WINDOW = 100 * math.pi  # 50 free periods, as TrainConfig.validate allows


def within(x, lo: float, hi: float, rel_tol: float = REL_TOL) -> np.ndarray:
    """Elementwise lo <= x <= hi up to rel_tol of the larger end (a box's side, or a point when lo == hi): the one
    test of a bow against a range, for model files (Domain) and training boxes (ParamBox) alike."""
    x = np.asarray(x, float)
    if lo == hi:
        return np.isclose(x, lo, rtol=rel_tol, atol=1e-12)
    tol = rel_tol * max(abs(hi), 1e-12)
    return (x >= lo - tol) & (x <= hi + tol)


@dataclass
class Domain:
    """Where a model is valid: its dimensionless physics, window, and the states it was trained on."""

    beta: float
    vb: float
    a: float
    window: float  # T in tau
    q_lo: float
    q_hi: float
    p_lo: float
    p_hi: float
    mask: np.ndarray = field(repr=False, default=None)  # (G, G) bool over the box: cells near training states
    # a range model: [beta_lo, beta_hi, vb_lo, vb_hi], the bows it plays (beta, vb above: the box's centre, where the
    # render-time physics check runs); None: a point model, which plays (beta, vb) only
    box: list | None = None
    # a range model whose correction is scaled by beta / beta_ref (npnet.gain) plays bows below its box's bottom down
    # to F_B = 0 (a bow lifted, an attack from rest): what friction adds over a window is first order in beta, so the
    # branch's bow input is held at the bottom (npnet.param_inputs) and the gain carries beta to 0, where the flow is
    # exactly the free rotation. Set from the network's settings (OperatorModel), not stored in files.
    plays_below: bool = field(default=False, repr=False, compare=False)

    @property
    def is_range(self) -> bool:
        return self.box is not None

    def check(self) -> None:
        """Refuse a domain no trainer writes (ValueError, one line): every later use (the physics check's RK4 steps
        grow with beta and the window, the mask is indexed by cell) stays bounded and in range."""
        nums = {"beta": self.beta, "vb": self.vb, "a": self.a, "window": self.window, "q_lo": self.q_lo,
                "q_hi": self.q_hi, "p_lo": self.p_lo, "p_hi": self.p_hi}
        for k, v in nums.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"domain.{k} is {v!r}, not a finite number")
        if not (0 <= self.beta <= MAX_BETA and 0 < self.a <= MAX_A and 0 < self.window <= MAX_WINDOW):
            raise ValueError(f"domain beta {self.beta:g}, a {self.a:g}, window {self.window:g} are outside what a "
                             f"model can be trained for (0..{MAX_BETA:g}, 0..{MAX_A:g}, 0..{MAX_WINDOW:.4g})")
        if not (self.q_lo < self.q_hi and self.p_lo < self.p_hi):
            raise ValueError("domain state box is empty")
        m = self.mask
        if m is not None and not (m.ndim == 2 and m.shape[0] == m.shape[1] and 1 <= m.shape[0] <= 4096 and m.any()):
            raise ValueError(f"domain.mask has shape {m.shape} and {int(m.sum())} cells: an empty or odd grid")
        if self.box is not None:
            b = self.box
            if not (isinstance(b, list) and len(b) == 4 and all(isinstance(x, (int, float)) and math.isfinite(x)
                                                                 for x in b)
                    and 0 <= b[0] <= b[1] <= MAX_BETA and b[2] <= b[3]):
                raise ValueError(f"domain.box {b!r} is not [beta_lo, beta_hi, vb_lo, vb_hi]")

    def beta_in(self, beta) -> np.ndarray:
        """Elementwise: is F_B / w inside this model's box (a point model: equal to its own)?"""
        return within(beta, self.beta, self.beta) if self.box is None else within(beta, *self.box[:2])

    def vb_in(self, vb) -> np.ndarray:
        """Elementwise: is v_B inside this model's box (a point model: equal to its own)?"""
        return within(vb, self.vb, self.vb) if self.box is None else within(vb, *self.box[2:])

    def beta_plays(self, beta) -> np.ndarray:
        """Elementwise: does the model play F_B / w: inside its box, or below it down to 0 (plays_below)?"""
        inside = self.beta_in(beta)
        if not self.plays_below:
            return inside
        return inside | ((np.asarray(beta, float) >= 0) & (np.asarray(beta, float) <= self.box[0]))

    def box_contains(self, beta, vb) -> np.ndarray:
        """Elementwise: does the model play the bow (beta, v_B) (a point model: equal to its point; a range model:
        inside its box, or below it in beta, beta_plays)?"""
        return self.beta_plays(beta) & self.vb_in(vb)

    def describe_bows(self) -> str:
        if self.box is None:
            return f"F_B / w {self.beta:.4g}, v_B {self.vb:g}"
        b0, b1, v0, v1 = self.box
        return f"F_B / w {b0:.4g}..{b1:.4g}, v_B {v0:g}..{v1:g}"

    def contains(self, q, p) -> np.ndarray:
        """Elementwise: is the state (q, p) inside the box and on a cell of the mask?"""
        q, p = np.asarray(q, float), np.asarray(p, float)
        inside = (q >= self.q_lo) & (q <= self.q_hi) & (p >= self.p_lo) & (p <= self.p_hi)
        if self.mask is None:
            return inside
        i, j = self.cell(q, p, self.mask.shape[0])
        return inside & self.mask[i, j]

    def cell(self, q, p, grid: int):
        """Indices (i, j) of the cells of a grid x grid partition of the box holding the states (clipped to it)."""
        with np.errstate(invalid="ignore"):
            i = ((np.asarray(q, float) - self.q_lo) / (self.q_hi - self.q_lo) * grid).astype(int, casting="unsafe")
            j = ((np.asarray(p, float) - self.p_lo) / (self.p_hi - self.p_lo) * grid).astype(int, casting="unsafe")
        return np.clip(i, 0, grid - 1), np.clip(j, 0, grid - 1)

    def physics_mismatch(self, scene: Scene) -> list[str]:
        """Reasons the scene's dimensionless physics differs from the model's (empty when it matches). A range model
        covers a scene whose bow stays in its box all the time (the curves are linear between breakpoints, so their
        extremes are breakpoint values)."""
        out = []
        if not math.isclose(scene.a, self.a, rel_tol=REL_TOL, abs_tol=1e-12):
            out.append(f"a = {scene.a:.6g}, model has {self.a:.6g}")
        if self.box is None:
            # a pitch curve whose force follows it (F_B / w held, as a MIDI note's) is still one bow
            (blo, bhi), vb_moves = scene.beta_range, isinstance(scene.vb, Curve)
            if blo != bhi and not math.isclose(blo, bhi, rel_tol=1e-9) or vb_moves:
                out.append(f"the bow changes during the scene; this model plays one bow ({self.describe_bows()})")
                return out
            for name, have, want in (("F_B / w", blo, self.beta), ("v_B", scene.vb, self.vb)):
                if not math.isclose(have, want, rel_tol=REL_TOL, abs_tol=1e-12):
                    out.insert(0, f"{name} = {have:.6g}, model has {want:.6g}")
            return out
        b0, b1, v0, v1 = self.box
        (blo, bhi), (vlo, vhi) = scene.beta_range, scene.vb_range
        if not (self.beta_plays(blo) and self.beta_plays(bhi)):
            out.append(f"F_B / w {_span(blo, bhi)} leaves the model's {0 if self.plays_below else b0:.4g}..{b1:.4g}")
        if not (self.vb_in(vlo) and self.vb_in(vhi)):
            out.append(f"v_B {_span(vlo, vhi, '.4g')} leaves the model's {v0:g}..{v1:g}")
        return out

    def mismatch(self, scene: Scene) -> list[str]:
        """Reasons this model cannot render the scene (empty when it can)."""
        out = self.physics_mismatch(scene)
        if not self.contains(scene.q0, scene.p0):
            out.append(f"initial state (q0, p0) = ({scene.q0:g}, {scene.p0:g}) is outside the trained states "
                       f"(q in [{self.q_lo:.3g}, {self.q_hi:.3g}], p in [{self.p_lo:.3g}, {self.p_hi:.3g}], on its band)")
        if self.window / physics.dtau(scene.f0_max, scene.sample_rate) < 1:
            out.append(f"the window ({self.window:.3g} in tau) holds no sample at {scene.sample_rate} Hz, f0 "
                       f"{scene.f0_max:g}")
        return out

    def to_json(self) -> dict:
        d = asdict(self)
        d.pop("mask")
        d.pop("plays_below")
        return d


def _span(lo: float, hi: float, fmt: str = ".4g") -> str:
    return f"{lo:{fmt}}" if lo == hi else f"{lo:{fmt}}..{hi:{fmt}}"


@dataclass
class ModelMeta:
    """Everything in a model file besides the weights."""

    name: str
    domain: Domain
    net: dict
    training: dict
    validation: dict
    scene: dict  # the scene it was trained for (f0, fb, ... ), for messages and `bowsynth train` hints
    version: str = __version__
    format: str = FORMAT
    format_version: int = FORMAT_VERSION
    id: str = ""
    digest: str = ""  # format 2: see `digest`

    def to_json(self) -> str:
        d = asdict(self)
        d["domain"] = self.domain.to_json()
        return json.dumps(d)


def model_id(name: str, tensors: dict) -> str:
    h = hashlib.sha256()
    for k in sorted(tensors):
        h.update(k.encode())
        h.update(np.ascontiguousarray(tensors[k]).tobytes())
    return f"{name}@{h.hexdigest()[:10]}"


def digest(meta: dict, tensors: dict) -> str:
    """What binds a file's metadata to its weights: sha256 over the canonical metadata JSON (sorted keys, without the
    digest itself) and every tensor's name, dtype, shape and bytes. An edit to either no longer matches."""
    h = hashlib.sha256()
    h.update(json.dumps({k: v for k, v in meta.items() if k != "digest"}, sort_keys=True,
                        separators=(",", ":")).encode())
    for k in sorted(tensors):
        a = np.ascontiguousarray(tensors[k])
        h.update(f"\0{k}\0{a.dtype.str}\0{a.shape}\0".encode())
        h.update(a.tobytes())
    return "sha256:" + h.hexdigest()


def validation_failure(meta: ModelMeta) -> str | None:
    """Why a model's validation rollout disqualifies it from being picked by default (None when it passed): it
    failed, has no finite NMSE(p), or its NMSE(p) exceeds MAX_VALIDATION_NMSE."""
    v = meta.validation or {}
    if v.get("error"):
        return f"validation failed: {v['error']}"
    n = v.get("nmse")
    if not isinstance(n, (int, float)) or isinstance(n, bool) or not math.isfinite(n):
        return "no validation score"
    if n > MAX_VALIDATION_NMSE:
        return f"validation NMSE(p) {n:.3g} > {MAX_VALIDATION_NMSE:g}"
    return None


class OperatorModel:
    """A trained operator: its weights and metadata.

    Built from a torch DeepONet (the trainer) or, by `load_model`, from the numpy weights of a file: a render reads
    only `weights` (float32 numpy arrays), and `net`, the torch network, is built on first use.
    """

    def __init__(self, net, meta: ModelMeta, path: Path | None = None, weights: dict | None = None):
        if net is None and weights is None:
            raise ValueError("an OperatorModel needs a torch network or its weights")
        self._net = net.eval() if net is not None else None
        self._weights = weights
        # read from a file (load_model): its metadata are claims about its weights, checked at render time
        self.from_file = net is None
        self.meta = meta
        self.path = path
        meta.domain.plays_below = bool(meta.domain.is_range and NetConfig(**meta.net).corr_beta)

    @property
    def net(self):
        """The torch DeepONet (built from the weights on first use: importing torch takes seconds)."""
        if self._net is None:
            import torch

            from .network import DeepONet

            net = DeepONet(NetConfig(**self.meta.net))
            net.load_state_dict({k: torch.from_numpy(v.copy()) for k, v in self._weights.items()}, strict=True)
            self._net = net.eval()
        return self._net

    @property
    def weights(self) -> dict:
        """The network's tensors as float32 numpy arrays (state_dict names); a snapshot when built from a net."""
        if self._net is not None:  # the trainer's net may still change: read it afresh
            return {k: v.detach().cpu().float().contiguous().numpy().copy() for k, v in self._net.state_dict().items()}
        return self._weights

    @property
    def cfg(self) -> NetConfig:
        return NetConfig(**self.meta.net)

    @property
    def domain(self) -> Domain:
        return self.meta.domain

    @property
    def id(self) -> str:
        return self.meta.id

    @property
    def failure(self) -> str | None:
        """Why this model is not picked by default (see validation_failure), or None."""
        return validation_failure(self.meta)

    def covers(self, scene: Scene) -> bool:
        return not self.domain.mismatch(scene)

    def save(self, path, force: bool = False) -> Path:
        """Write the model (format version FORMAT_VERSION, with its digest); sets meta.id and meta.digest."""
        from safetensors.numpy import save_file

        from .wav import atomic_write

        path = Path(path)
        tensors = dict(self.weights)
        tensors["domain.mask"] = np.ascontiguousarray(self.domain.mask, dtype=np.uint8)
        self.meta.id = model_id(self.meta.name, tensors)
        self.meta.format_version = RANGE_VERSION if self.domain.is_range else FORMAT_VERSION
        self.meta.digest = ""
        self.meta.digest = digest(json.loads(self.meta.to_json()), tensors)
        try:  # without force the file is placed by a link, which refuses a name taken even a moment ago
            atomic_write(path, lambda tmp: save_file(tensors, tmp, metadata={META_KEY: self.meta.to_json()}),
                         exclusive=not force)
        except FileExistsError:
            raise ModelExistsError(f"{path} exists; pass --force to overwrite it") from None
        self.path = path
        return path


def _check_regular(path: Path) -> None:
    """A model file is a regular file: say what it is instead (never open a FIFO, which blocks, or a device such as
    /dev/zero, which never ends)."""
    import errno
    import stat

    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise ModelFileError(f"model file {path} not found" + (" (a symlink to nothing)" if path.is_symlink()
                                                                else "")) from None
    except OSError as e:
        why = "is a symlink loop" if e.errno == errno.ELOOP else f"cannot be read ({e.strerror})"
        raise ModelFileError(f"model file {path} {why}") from None
    if stat.S_ISDIR(st.st_mode):
        raise ModelFileError(f"model file {path} is a directory, not a model file")
    if not stat.S_ISREG(st.st_mode):
        kind = "a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(
            st.st_mode) else "not a regular file"
        raise ModelFileError(f"model file {path} is {kind}" + (f" (the target of a symlink: {os.path.realpath(path)})"
                                                              if path.is_symlink() else "") + ", not a model file")


class ModelExistsError(ModelFileError, FileExistsError):
    """A model file would replace an existing file without force."""


def load_model(path) -> OperatorModel:
    """Load a model file (numpy only: no torch); any problem (missing, corrupt, foreign, other version, metadata that
    does not match the weights) raises ModelFileError."""
    from safetensors import safe_open

    path = Path(path)
    _check_regular(path)
    try:
        with safe_open(str(path), framework="numpy") as f:
            raw = (f.metadata() or {}).get(META_KEY)
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:  # safetensors raises several types for bad headers and truncation
        raise ModelFileError(f"{path} is not a readable model file ({type(e).__name__}: {e})") from None
    if raw is None:
        raise ModelFileError(f"{path} is a safetensors file but not a bowsynth model (no '{META_KEY}' metadata)")
    try:
        d = json.loads(raw)
        if not isinstance(d, dict):
            raise ValueError("the metadata is not a JSON object")
        if d.get("format") != FORMAT:
            raise ModelFileError(f"{path} is not a bowsynth operator (format {d.get('format')!r})")
        if d.get("format_version") not in READ_VERSIONS:
            raise ModelFileError(f"{path} has model format version {d.get('format_version')}, this bowsynth reads "
                                 f"versions {', '.join(map(str, READ_VERSIONS))}; retrain it with `bowsynth train`")
        # version 1 files carry no digest: the physics check at render time (rollout.check_physics) still catches
        # metadata that lies about the weights
        if d["format_version"] >= 2 and d.get("digest") != digest(d, tensors):
            raise ModelFileError(f"{path}: metadata does not match the weights: the file was edited (digest mismatch)")
        mask = tensors.pop("domain.mask").astype(bool)
        dom = Domain(**d["domain"], mask=mask)
        dom.check()
        meta = ModelMeta(**{**d, "domain": dom})
        cfg = NetConfig(**d["net"])
        want = weight_shapes(cfg)
        if set(tensors) != set(want):
            missing, extra = sorted(set(want) - set(tensors)), sorted(set(tensors) - set(want))
            raise ValueError(f"tensors missing {missing[:3]}, unexpected {extra[:3]}")
        for k, shape in want.items():
            if tensors[k].shape != shape or tensors[k].dtype != np.float32:
                raise ValueError(f"{k} is {tensors[k].dtype} {tensors[k].shape}, expected float32 {shape}")
        if not math.isclose(float(tensors["window"]), dom.window, rel_tol=1e-6):
            raise ValueError(f"the window tensor ({float(tensors['window']):g}) is not the domain's ({dom.window:g})")
        for k in ("halfrange", "corr_scale"):
            if not np.all(tensors[k] > 0):
                raise ValueError(f"{k} must be positive, got {tensors[k]}")
    except ModelFileError:
        raise
    except Exception as e:
        raise ModelFileError(f"{path} has damaged bowsynth metadata or weights ({type(e).__name__}: {e})") from None
    for k, v in tensors.items():
        if not np.all(np.isfinite(v)):
            raise ModelFileError(f"{path} holds non-finite weights ({k})")
    return OperatorModel(None, meta, path, weights=tensors)
