"""Checkpoints without pickle: tensors in safetensors, everything else (optimiser structure, RNG, history) as JSON."""

from __future__ import annotations

import json
import signal
import threading
from contextlib import contextmanager
from pathlib import Path

import torch

from ..errors import UsageError
from .config import checkpoint_path  # noqa: F401

META_KEY = "bowsynth_checkpoint"


def _flatten(obj, prefix, tensors):
    if isinstance(obj, torch.Tensor):
        tensors[prefix] = obj.detach().contiguous().clone()
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


@contextmanager
def signals_held():
    """Ctrl-C and SIGTERM wait until the block is done, then act as they would have: a checkpoint is written whole
    or not at all, and the save that an interruption makes is not itself cut short by a second Ctrl-C. Done with the
    Python handlers (a blocked signal mask would not do: the kernel hands a process's signal to any thread that does
    not block it, and torch's threads do not)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending = []
    old = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        h = signal.getsignal(sig)
        if h is not signal.SIG_IGN and h is not None:
            old[sig] = signal.signal(sig, lambda signum, frame: pending.append(signum))
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
        if pending:
            h = old[pending[0]]
            if callable(h):
                h(pending[0], None)  # raises, as the handler would have (KeyboardInterrupt, errors.Terminated)
            else:
                signal.raise_signal(pending[0])


def save(path: Path, state: dict) -> None:
    """state: {"tensors": {name: tensor}, "optimizer": opt.state_dict(), "meta": JSON-able dict}."""
    from safetensors.torch import save_file

    from ..wav import atomic_write

    with signals_held():
        tensors = dict(state["tensors"])
        meta = {**state["meta"], "opt": _flatten(state["optimizer"], "opt", tensors)}
        tensors["torch_rng"] = torch.get_rng_state()
        atomic_write(path, lambda tmp: save_file(tensors, tmp, metadata={META_KEY: json.dumps(meta)}))


def load(path: Path) -> tuple[dict, dict, dict]:
    """(tensors, optimizer state, meta) of a checkpoint; restores torch's RNG. A bad file is a UsageError."""
    from safetensors import safe_open

    try:
        with safe_open(str(path), framework="pt") as f:
            meta = json.loads(f.metadata()[META_KEY])
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:
        raise UsageError(f"checkpoint {path} is unreadable ({type(e).__name__}); delete it to start afresh") from None
    torch.set_rng_state(tensors.pop("torch_rng"))
    return tensors, _unflatten(meta.pop("opt"), tensors), meta
