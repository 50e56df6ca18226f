"""Model files: safetensors weights + JSON metadata (no pickle) bound together by a digest, and the domain a model
covers. Reading a model needs numpy only (no torch).

A model is trained for one dimensionless scene (beta = F_B / w, v_B, a) over a window of T in tau, on the band of
states a render visits. The domain records that band as a box plus an occupancy mask on a grid over the box.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ... import __version__, physics
from ...errors import ModelFileError
from ...io.infile import regular_file
from ...scene import Scene
from .claims import claims_error
from .domain import PLAYS_BELOW_STIFFNESS, Domain
from .manifest import in_manifest
from .npnet import NetConfig, weight_shapes

FORMAT = "bowsynth-operator"
FORMAT_VERSION = 2  # 2: a digest binds the metadata to the weights
RANGE_VERSION = 3  # 3: a range model (its domain has a box of bows, its branch takes them); point models stay 2
READ_VERSIONS = (1, 2, 3)
META_KEY = "bowsynth"

# A point model whose validation NMSE(p) (1 s from the training scene's initial state against a x100 FDM) is above
# this is not picked by default: the shipped models score 1e-7 to 3e-4; 0.1 is a note visibly off in phase or pitch.
MAX_VALIDATION_NMSE = 0.1
# A range model is judged by what a listener hears over its validation grid (NMSE from rest would ask for the bow to
# 1e-4): not picked by default where the grid's median harmonic error is above MAX_VALIDATION_HARM_DB or a bow's pitch
# is off by more than MAX_VALIDATION_CENTS (failed stick-slip tiles are tens to hundreds of cents off).
MAX_VALIDATION_HARM_DB = 1.0
MAX_VALIDATION_CENTS = 10.0


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


def is_finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def grid_rests(v: dict) -> bool:
    """Whether a range model's validation record (training.selection.validate_range) is that of a box where the bow
    damps the mass at every grid bow and the model rests at each: no pitch or NMSE to judge, only that."""
    return v.get("speaking") == 0 and v.get("silent_sounding") == 0 and bool(v.get("resting"))


def validation_failure(meta: ModelMeta) -> str | None:
    """Why a model's validation rollout disqualifies it from being picked by default (None when it passed): it
    failed; a range model sounds at a grid bow where the truth rests; one with listener errors on record (its grid's
    median harmonic dB and worst |cents|) exceeds MAX_VALIDATION_HARM_DB or MAX_VALIDATION_CENTS; one whose grid
    all rests passes; any other has no finite NMSE(p) or exceeds MAX_VALIDATION_NMSE."""
    v = meta.validation or {}
    if v.get("error"):
        return f"validation failed: {v['error']}"
    if v.get("silent_sounding"):
        return f"validation: it sounds at {v['silent_sounding']} grid bow(s) where the truth rests"
    harm, cents = v.get("harm_db_median"), v.get("cents_abs_max")
    if v.get("points") is not None and is_finite(harm) and is_finite(cents):
        if harm > MAX_VALIDATION_HARM_DB:
            return f"validation harmonics {harm:.3g} dB (median) > {MAX_VALIDATION_HARM_DB:g}"
        if cents > MAX_VALIDATION_CENTS:
            return f"validation pitch {cents:.3g} cents (worst) > {MAX_VALIDATION_CENTS:g}"
        return None
    if grid_rests(v):
        return None  # a box where every grid bow damps the mass (the heavy bow stops' corner): it rests at each
    n = v.get("nmse")
    if not is_finite(n):
        return "no validation score"
    if n > MAX_VALIDATION_NMSE:
        return f"validation NMSE(p) {n:.3g} > {MAX_VALIDATION_NMSE:g}"
    return None


def missed_by_ear(meta: ModelMeta) -> bool:
    """Whether a range model failed its validation by a listener error at some grid bow alone (harmonics or pitch over
    their limits; not an error, a sound where the truth rests, or no score). Such a model is never picked; it plays
    only with --model."""
    v = meta.validation or {}
    listened = v.get("points") is not None and is_finite(v.get("harm_db_median")) and is_finite(v.get("cents_abs_max"))
    return listened and not v.get("error") and not v.get("silent_sounding") and validation_failure(meta) is not None


def unpicked_text(meta: ModelMeta) -> str:
    """What a failed validation means for a model's use, for the listings (`bowsynth models`, the report)."""
    return "not picked by default (only with --model)"


class OperatorModel:
    """A trained operator: its weights and metadata.

    Built from a torch DeepONet (the trainer) or, by `load_model`, from the numpy weights of a file: a render reads
    only `weights` (float32 numpy arrays), and `net`, the torch network, is built on first use.
    """

    def __init__(self, net, meta: ModelMeta, path: Path | None = None, weights: dict | None = None,
                 identity: str | None = None, unhashed: dict | None = None):
        if net is None and weights is None and identity is None:
            raise ValueError("an OperatorModel needs a torch network, its weights or the file to read them from")
        self._net = net.eval() if net is not None else None
        self._weights = weights
        self._identity = identity  # weights=None: read from path on first use, if the file is still this one
        self._unhashed = unhashed  # a manifest's file: the metadata whose digest its weights must match when read
        # read from a file (load_model): its metadata are claims about its weights, checked at render time
        self.from_file = net is None
        self.meta = meta
        self.path = path
        d = meta.domain
        d.plays_below = bool(d.is_range and NetConfig(**meta.net).corr_beta
                             and physics.stiffness(d.box[0], d.a) <= PLAYS_BELOW_STIFFNESS)

    @property
    def net(self):
        """The torch DeepONet (built from the weights on first use: importing torch takes seconds)."""
        if self._net is None:
            import torch

            from .network import DeepONet

            net = DeepONet(NetConfig(**self.meta.net))
            net.load_state_dict({k: torch.from_numpy(v.copy()) for k, v in self.weights.items()}, strict=True)
            self._net = net.eval()
        return self._net

    @property
    def weights(self) -> dict:
        """The network's tensors as float32 numpy arrays (state_dict names); a snapshot when built from a net."""
        if self._net is not None:  # the trainer's net may still change: read it afresh
            return {k: v.detach().cpu().float().contiguous().numpy().copy() for k, v in self._net.state_dict().items()}
        if self._weights is None:
            self._weights = _read_weights(self.path, self._identity, self._unhashed)
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
    def key(self) -> str:
        """What this model's measurements are kept under on disk (auto windows' scores, its sounding ratios): its id,
        or for a model not saved (a training's, validated before it has an id) a digest of what it plays by, hashed
        at each call since a trainer changes its weights. Keyed by an empty id, every unsaved model of a box shared
        one answer: the second training of a box was validated in the windows chosen for the first."""
        if self.meta.id:
            return self.meta.id
        plays_by = {"name": self.meta.name, "domain": self.domain.to_json(), "net": self.meta.net}
        return f"unsaved@{digest(plays_by, self._file_tensors())[:16]}"

    def _file_tensors(self) -> dict:
        """What a model file holds beside its metadata: the weights and the domain's mask."""
        return dict(self.weights, **{"domain.mask": np.ascontiguousarray(self.domain.mask, dtype=np.uint8)})

    @property
    def failure(self) -> str | None:
        """Why this model is not picked by default (see validation_failure), or None. Kept while its metadata and
        their validation are the same objects (the trainer assigns a new validation; the lookup asks this of every
        model for every note)."""
        hit = self.__dict__.get("_failure")
        if hit is None or hit[0] is not self.meta or hit[1] is not self.meta.validation:
            hit = self.__dict__["_failure"] = (self.meta, self.meta.validation, validation_failure(self.meta))
        return hit[2]

    def covers(self, scene: Scene) -> bool:
        return _covers(self, scene)

    def save(self, path, force: bool = False) -> Path:
        """Write the model (format version FORMAT_VERSION, with its digest); sets meta.id and meta.digest."""
        from safetensors.numpy import save_file

        from ...io.audio import atomic_write

        path = Path(path)
        tensors = self._file_tensors()
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


# What decides whether a file's weights are its metadata's is never taken from the cache: a file of ./models is hashed
# whole when it is read; a shipped file the build listed in the manifest (its name, size and digest) is read by its
# header, and its weights are hashed against the digest when a render first reads them (_read_weights).
def _identity(st: os.stat_result) -> str:
    return f"{st.st_dev}:{st.st_ino}:{st.st_size}:{st.st_mtime_ns}:{st.st_ctime_ns}"


class ModelExistsError(ModelFileError, FileExistsError):
    """A model file would replace an existing file without force."""


def load_model(path) -> OperatorModel:
    """Load a model file (numpy only: no torch); any problem (missing, corrupt, foreign, other version, metadata that
    does not match the weights) raises ModelFileError."""
    from safetensors import safe_open

    path = Path(path)
    # a regular file or one line saying what it is: a FIFO (which blocks) or a device (/dev/zero never ends) is never
    # opened
    st = regular_file(path, "model file", "a model file", ModelFileError)
    ident = _identity(st)
    try:
        with safe_open(str(path), framework="numpy") as f:
            raw = (f.metadata() or {}).get(META_KEY)
            d = _json_object(raw)  # None where missing or not a JSON object: refused below, with the reason
            # a shipped file the build listed: its header and the tensors the checks below read now, the weights
            # (hashed against the digest) when a render first needs them (_read_weights)
            listed = d is not None and in_manifest(path, st.st_size, d.get("digest"))
            tensors = {k: f.get_tensor(k) for k in f.keys() if not listed or k in HEADER_TENSORS}
            shapes = {k: (tuple(sl.get_shape()), sl.get_dtype()) for k in f.keys() for sl in [f.get_slice(k)]}
    except Exception as e:  # safetensors raises several types for bad headers and truncation
        raise ModelFileError(f"{path} is not a readable model file ({type(e).__name__}: {e})") from None
    if raw is None:
        raise ModelFileError(f"{path} is a safetensors file but not a bowsynth model (no '{META_KEY}' metadata)")
    try:
        if d is None:
            json.loads(raw)  # broken JSON: the parser's own message
            raise ValueError("the metadata is not a JSON object")
        if d.get("format") != FORMAT:
            raise ModelFileError(f"{path} is not a bowsynth operator (format {d.get('format')!r})")
        if d.get("format_version") not in READ_VERSIONS:
            raise ModelFileError(f"{path} has model format version {d.get('format_version')}, this bowsynth reads "
                                 f"versions {', '.join(map(str, READ_VERSIONS))}; retrain it with `bowsynth train`")
        # version 1 files carry no digest: the physics check at render time (operator.check) still catches
        # metadata that lies about the weights
        claimed = d.get("digest")
        if d["format_version"] >= 2 and not listed and claimed != digest(d, tensors):
            raise ModelFileError(f"{path}: metadata does not match the weights: the file was edited (digest "
                                 "mismatch)")
        mask = tensors.pop("domain.mask").astype(bool)
        dom = Domain(**d["domain"], mask=mask)
        dom.check()
        meta = ModelMeta(**{**d, "domain": dom})
        cfg = NetConfig(**d["net"])
        want = weight_shapes(cfg)
        names = set(shapes) - {"domain.mask"}
        if names != set(want):
            missing, extra = sorted(set(want) - names), sorted(names - set(want))
            raise ValueError(f"tensors missing {missing[:3]}, unexpected {extra[:3]}")
        for k, shape in want.items():
            if shapes[k] != (tuple(shape), "F32"):
                raise ValueError(f"{k} is {shapes[k][1]} {shapes[k][0]}, expected F32 {tuple(shape)}")
        if not math.isclose(float(tensors["window"]), dom.window, rel_tol=1e-6):
            raise ValueError(f"the window tensor ({float(tensors['window']):g}) is not the domain's ({dom.window:g})")
        for k in ("halfrange", "corr_scale") + (("pscale",) if cfg.params and not listed else ()):
            if not np.all(tensors[k] > 0):
                raise ValueError(f"{k} must be positive, got {tensors[k]}")
        for k, v in tensors.items():
            if not np.all(np.isfinite(v)):
                raise ModelFileError(f"{path} holds non-finite weights ({k})")
        # a listed file's claims are the build's, bound to its weights by the manifest's digest (checked when they
        # are read); any other file's are held to the scalings its weights were trained with
        why = None if listed else claims_error(dom, cfg, tensors)
        if why:
            raise ModelFileError(f"{path} claims more than its weights were trained for: {why}")
    except ModelFileError:
        raise
    except Exception as e:
        raise ModelFileError(f"{path} has damaged bowsynth metadata or weights ({type(e).__name__}: {e})") from None
    if listed:
        return OperatorModel(None, meta, path, identity=ident, unhashed=d)
    return OperatorModel(None, meta, path, weights=tensors)


# What load_model reads of a listed shipped file: the domain's mask and the tensors its checks read. The rest (the
# networks' weights) waits for a render: a process that looks up a model reads every model file's header.
HEADER_TENSORS = frozenset({"domain.mask", "window", "halfrange", "corr_scale"})


def _json_object(raw) -> dict | None:
    """The metadata parsed once (it is ~6 KB a file, every file a lookup reads), or None if it is not a JSON object."""
    try:
        d = json.loads(raw)
    except (TypeError, ValueError, RecursionError):
        return None
    return d if isinstance(d, dict) else None


def _read_weights(path: Path, identity: str, unhashed: dict | None = None) -> dict:
    """The weights of a model file load_model read the header of, if the file is still the one it read (the same
    identity, fstat of the open file, before and after reading) and, `unhashed` (a manifest's file not hashed yet: its
    metadata), its digest matches; else ModelFileError."""
    from safetensors.numpy import load

    changed = ModelFileError(f"model file {path} changed since bowsynth read it; run the command again")
    try:
        # O_NONBLOCK: a FIFO put in the file's place must not block the open (its identity then refuses it)
        with os.fdopen(os.open(path, os.O_RDONLY | os.O_NONBLOCK), "rb") as fh:
            if _identity(os.fstat(fh.fileno())) != identity:
                raise changed
            data = fh.read()
            if _identity(os.fstat(fh.fileno())) != identity:
                raise changed
        tensors = load(data)
    except ModelFileError:
        raise
    except Exception as e:
        raise ModelFileError(f"{path} is not a readable model file ({type(e).__name__}: {e})") from None
    if unhashed is not None and digest(unhashed, tensors) != unhashed.get("digest"):
        raise ModelFileError(f"{path}: metadata does not match the weights: the file was edited after the build "
                             f"listed it (digest mismatch); `make models` rebuilds it")
    tensors.pop("domain.mask", None)
    for k, v in tensors.items():
        if not np.all(np.isfinite(v)):
            raise ModelFileError(f"{path} holds non-finite weights ({k})")
    return tensors


@functools.lru_cache(maxsize=8192)
def _covers(model: OperatorModel, scene: Scene) -> bool:
    # a score asks this of every model for every note several times (choice, coverage, releases: 688 calls for a
    # 172-note chorale, 1.7 s); models and scenes do not change once made (a model by identity, a Scene frozen)
    d = model.domain
    if d.box is not None and not all(d.spans_played(scene)):  # most models fail here: no reasons composed
        return False
    return not d.mismatch(scene)
