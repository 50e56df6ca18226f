"""Writes the shipped catalogue's manifest (engines.operator.manifest): each model file checked whole, then listed.

    python -m bowsynth.training.manifest        # `make models` runs it after training
"""

from __future__ import annotations

import json
from pathlib import Path

from ..engines.operator import manifest
from ..engines.operator.modelfile import load_model
from ..io.outfile import atomic_write


def write_manifest(directory: Path | None = None) -> Path:
    """List every model file of the shipped directory (manifest.MANIFEST's) with its size and digest, each loaded
    and its weights hashed against its digest first."""
    directory = manifest.MANIFEST.parent if directory is None else Path(directory)
    models = {}
    for p in sorted(directory.glob("*.safetensors")):
        m = load_model(p)
        _ = m.weights  # read whole: the digest checked
        models[p.name] = {"digest": m.meta.digest, "size": p.stat().st_size}
    text = json.dumps({"format": manifest.FORMAT, "version": 1, "models": models}, indent=1, sort_keys=True) + "\n"
    atomic_write(manifest.MANIFEST, lambda tmp: Path(tmp).write_text(text))
    manifest._listed.cache_clear()
    return manifest.MANIFEST


if __name__ == "__main__":
    print(write_manifest())
