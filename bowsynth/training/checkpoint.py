"""Checkpoints without pickle: tensors in safetensors, everything else (optimiser structure, RNG, history) as JSON."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from ..errors import UsageError, held

META_KEY = "bowsynth_checkpoint"


def _flatten(obj, prefix, tensors):
    if isinstance(obj, torch.Tensor):
        tensors[prefix] = obj.detach().cpu().contiguous().clone()  # a GPU's optimiser state too
        return {"__tensor__": prefix}
    if isinstance(obj, dict):
        return {"__dict__": [[_flatten(k, f"{prefix}.k{i}", tensors), _flatten(v, f"{prefix}.{i}", tensors)]
                             for i, (k, v) in enumerate(obj.items())]}
    if isinstance(obj, (list, tuple)):
        return {"__list__": [_flatten(v, f"{prefix}.{i}", tensors) for i, v in enumerate(obj)],
                "tuple": isinstance(obj, tuple)}
    return obj


def _unflatten(obj, tensors):
    if isinstance(obj, dict) and "__tensor__" in obj:
        return tensors[obj["__tensor__"]]
    if isinstance(obj, dict) and "__dict__" in obj:
        return {_unflatten(k, tensors): _unflatten(v, tensors) for k, v in obj["__dict__"]}
    if isinstance(obj, dict) and "__list__" in obj:
        items = [_unflatten(v, tensors) for v in obj["__list__"]]
        return tuple(items) if obj.get("tuple") else items
    return obj


def save(path: Path, state: dict) -> None:
    """state: {"tensors": {name: tensor}, "optimizer": opt.state_dict(), "meta": JSON-able dict}."""
    from safetensors.torch import save_file

    from ..io.audio import atomic_write

    with held():
        tensors = dict(state["tensors"])
        meta = {**state["meta"], "opt": _flatten(state["optimizer"], "opt", tensors)}
        tensors["torch_rng"] = torch.get_rng_state()
        atomic_write(path, lambda tmp: save_file(tensors, tmp, metadata={META_KEY: json.dumps(meta)}))


def load(path: Path) -> tuple[dict, dict, dict]:
    """(tensors, optimizer state, meta) of a checkpoint; restores torch's RNG. A bad file (not a regular file: a FIFO
    would block the read; unreadable; a record of the wrong types; a tensor missing or not finite) is a UsageError."""
    from safetensors import safe_open

    from ..io.infile import regular_file

    regular_file(path, "checkpoint", "a checkpoint file")
    bad = f"checkpoint {path} is damaged or forged ({{}}); delete it to start afresh"
    try:
        with safe_open(str(path), framework="pt") as f:
            meta = json.loads(f.metadata()[META_KEY])
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:
        raise UsageError(f"checkpoint {path} is unreadable ({type(e).__name__}); delete it to start afresh") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("opt"), dict):
        raise UsageError(bad.format("its record is not a checkpoint's"))
    rng = tensors.pop("torch_rng", None)
    if rng is None or rng.dtype != torch.uint8 or rng.dim() != 1:
        raise UsageError(bad.format("torch's random state is missing or of the wrong type"))
    for k, t in tensors.items():
        if t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise UsageError(bad.format(f"{k} is not finite"))
    try:
        opt = _unflatten(meta.pop("opt"), tensors)
        torch.set_rng_state(rng)
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        raise UsageError(bad.format(f"{type(e).__name__}: {str(e)[:80]}")) from None
    return tensors, opt, meta
