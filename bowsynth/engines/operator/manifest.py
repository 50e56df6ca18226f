"""The shipped catalogue's manifest: each shipped model file's name, size and digest, as the build checked them.

A listed file is looked up from its header alone; its weights are checked against its digest when a render first
reads them (`modelfile._read_weights`), so a new install's first render hashes the one model it plays, not the whole
catalogue (84 files: ~0.2 s of a cold process). `make models` writes it (`python -m bowsynth.training.manifest`).
"""

from __future__ import annotations

import functools
import json
import os
from pathlib import Path
from ... import shipped

MANIFEST = shipped("models") / "MANIFEST.json"
FORMAT = "bowsynth-manifest"


@functools.cache
def _listed() -> dict:
    try:
        with open(MANIFEST, "rb") as f:
            d = json.loads(f.read(1 << 20))
    except (OSError, ValueError, RecursionError):
        return {}
    models = d.get("models") if isinstance(d, dict) and d.get("format") == FORMAT else None
    return models if isinstance(models, dict) else {}


@functools.lru_cache(maxsize=64)
def _real_dir(directory: str) -> str:
    """A folder's real path, once per folder a process reads (a lookup reads every model file of it)."""
    return os.path.realpath(directory)


def in_manifest(path: Path, size: int, claimed) -> bool:
    """Whether `path` is a file of the shipped directory listed in the manifest with this size and claimed digest."""
    path = os.fspath(path)
    if not isinstance(claimed, str) or os.path.islink(path):
        return False
    if _real_dir(os.path.dirname(os.path.abspath(path))) != str(MANIFEST.parent):
        return False
    entry = _listed().get(os.path.basename(path))
    return isinstance(entry, dict) and entry.get("size") == size and entry.get("digest") == claimed
