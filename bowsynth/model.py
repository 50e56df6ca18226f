"""Model files: safetensors weights + JSON metadata (no pickle), and the domain a model covers.

A model is trained for one dimensionless scene (beta = F_B / w, v_B, a) over a window of T in tau, on the band of
states a render visits. The domain records that band as a box plus an occupancy mask on a grid over the box.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .errors import ModelFileError
from .scene import Scene

FORMAT = "bowsynth-operator"
FORMAT_VERSION = 1
META_KEY = "bowsynth"
REL_TOL = 1e-6  # beta, v_B, a must match the training scene this closely: the network does not take them as input


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
        """Reasons the scene's dimensionless physics differs from the model's (empty when it matches)."""
        out = []
        for name, have, want in (("F_B / w", scene.beta, self.beta), ("v_B", scene.vb, self.vb), ("a", scene.a, self.a)):
            if not math.isclose(have, want, rel_tol=REL_TOL, abs_tol=1e-12):
                out.append(f"{name} = {have:.6g}, model has {want:.6g}")
        return out

    def mismatch(self, scene: Scene) -> list[str]:
        """Reasons this model cannot render the scene (empty when it can)."""
        out = self.physics_mismatch(scene)
        if not self.contains(scene.q0, scene.p0):
            out.append(f"initial state (q0, p0) = ({scene.q0:g}, {scene.p0:g}) is outside the trained states "
                       f"(q in [{self.q_lo:.3g}, {self.q_hi:.3g}], p in [{self.p_lo:.3g}, {self.p_hi:.3g}], on its band)")
        if self.window / (scene.omega / scene.sample_rate) < 1:
            out.append(f"the window ({self.window:.3g} in tau) holds no sample at {scene.sample_rate} Hz, f0 {scene.f0:g}")
        return out

    def to_json(self) -> dict:
        d = asdict(self)
        d.pop("mask")
        return d


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

    def to_json(self) -> str:
        d = asdict(self)
        d["domain"] = self.domain.to_json()
        return json.dumps(d)


def model_id(name: str, tensors: dict) -> str:
    h = hashlib.sha256()
    for k in sorted(tensors):
        h.update(k.encode())
        h.update(tensors[k].detach().cpu().contiguous().numpy().tobytes())
    return f"{name}@{h.hexdigest()[:10]}"


class OperatorModel:
    """A loaded operator: the network in evaluation mode and its metadata."""

    def __init__(self, net, meta: ModelMeta, path: Path | None = None):
        self.net = net.eval()
        self.meta = meta
        self.path = path

    @property
    def domain(self) -> Domain:
        return self.meta.domain

    @property
    def id(self) -> str:
        return self.meta.id

    def covers(self, scene: Scene) -> bool:
        return not self.domain.mismatch(scene)

    def save(self, path, force: bool = False) -> Path:
        from safetensors.torch import save_file

        from .wav import atomic_write

        path = Path(path)
        if path.exists() and not force:
            raise ModelFileError(f"{path} exists; pass --force to overwrite it")
        import torch

        tensors = {k: v.detach().contiguous() for k, v in self.net.state_dict().items()}
        tensors["domain.mask"] = torch.from_numpy(self.domain.mask.astype(np.uint8))
        self.meta.id = model_id(self.meta.name, tensors)
        atomic_write(path, lambda tmp: save_file(tensors, tmp, metadata={META_KEY: self.meta.to_json()}))
        self.path = path
        return path


def load_model(path) -> OperatorModel:
    """Load a model file; any problem (missing, corrupt, foreign, other version) raises ModelFileError."""
    import torch
    from safetensors import safe_open

    from .network import DeepONet, NetConfig

    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"model file {path} not found")
    try:
        with safe_open(str(path), framework="pt") as f:
            raw = (f.metadata() or {}).get(META_KEY)
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:  # safetensors raises several types for bad headers and truncation
        raise ModelFileError(f"{path} is not a readable model file ({type(e).__name__}: {e})") from None
    if raw is None:
        raise ModelFileError(f"{path} is a safetensors file but not a bowsynth model (no '{META_KEY}' metadata)")
    try:
        d = json.loads(raw)
        if d.get("format") != FORMAT:
            raise ModelFileError(f"{path} is not a bowsynth operator (format {d.get('format')!r})")
        if d.get("format_version") != FORMAT_VERSION:
            raise ModelFileError(f"{path} has model format version {d.get('format_version')}, this bowsynth reads "
                                 f"version {FORMAT_VERSION}; retrain it with `bowsynth train`")
        mask = tensors.pop("domain.mask").numpy().astype(bool)
        dom = Domain(**d["domain"], mask=mask)
        meta = ModelMeta(**{**d, "domain": dom})
        net = DeepONet(NetConfig(**d["net"]))
        net.load_state_dict(tensors, strict=True)
    except ModelFileError:
        raise
    except Exception as e:
        raise ModelFileError(f"{path} has damaged bowsynth metadata or weights ({type(e).__name__}: {e})") from None
    for k, v in net.state_dict().items():
        if not torch.isfinite(v).all():
            raise ModelFileError(f"{path} holds non-finite weights ({k})")
    return OperatorModel(net, meta, path)
