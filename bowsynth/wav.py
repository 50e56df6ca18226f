"""WAV files with the render's own description inside, so `compare` needs nothing but the file.

32-bit float samples (quantisation far below any error we measure), peak-normalised; the gain, the scene, the
method, the model id and the render time go into the RIFF INFO comment as JSON.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import soundfile as sf

from .errors import UsageError
from .render import Render
from .scene import Scene

META_KEY = "bowsynth"
META_VERSION = 1
PEAK = 0.891  # -1 dBFS


@dataclass
class WavInfo:
    """What a WAV holds: the signal in physical units (samples / gain) and its metadata, if bowsynth wrote it."""

    path: Path
    samples: np.ndarray  # as stored, normalised
    sample_rate: int
    meta: dict | None

    @property
    def gain(self) -> float:
        return float(self.meta["gain"]) if self.meta else 1.0

    @property
    def physical(self) -> np.ndarray:
        """The signal in its own units (m for u, m/s for p), undoing the normalisation."""
        return self.samples / self.gain

    @property
    def scene(self) -> Scene | None:
        return Scene.from_dict(self.meta["scene"]) if self.meta else None


def check_output_path(path: str | os.PathLike, force: bool = True) -> Path:
    """Fail early, before any work, when an output path can't be written."""
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if p.is_dir():
        raise UsageError(f"output path {p} is a directory; give a file name")
    if not parent.is_dir():
        raise UsageError(f"output directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise UsageError(f"output directory {parent} is not writable")
    if p.exists() and not force:
        raise UsageError(f"{p} exists; pass --force to overwrite it")
    return p


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def atomic_write(path: Path, write) -> None:
    """Call write(tmp_path) on a temp file beside `path`, then rename it over `path`: never a half-written file."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent or ".")
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual permissions
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_wav(path, render: Render, signal: str = "u") -> dict:
    """Write the render's `signal` ('u' or 'p') to `path`; returns the metadata written."""
    x = render.signal(signal)
    if not np.all(np.isfinite(x)):
        raise ValueError("refusing to write non-finite samples")
    peak = float(np.max(np.abs(x))) if x.size else 0.0
    gain = PEAK / peak if peak > 0 else 1.0
    meta = {
        META_KEY: META_VERSION,
        "scene": render.scene.to_dict(),
        "method": render.method,
        "signal": signal,
        "gain": gain,
        "render_seconds": render.seconds,
        "model": render.info.get("model_id"),
    }
    write_float_wav(path, x * gain, render.scene.sample_rate, meta)
    return meta


def write_float_wav(path, x: np.ndarray, sample_rate: int, meta: dict) -> None:
    """Atomically write samples (already scaled to +-1) as 32-bit float WAV with `meta` as JSON in the comment."""
    if not np.all(np.isfinite(x)):
        raise ValueError("refusing to write non-finite samples")
    text = json.dumps(meta, separators=(",", ":"))
    if len(text) > 2000:  # libsndfile keeps INFO strings up to about this length
        raise ValueError("WAV metadata too long")

    def _write(tmp):
        with sf.SoundFile(tmp, "w", sample_rate, 1, subtype="FLOAT", format="WAV") as f:
            f.comment = text
            f.software = "bowsynth"
            f.write(np.asarray(x, dtype=np.float32))

    atomic_write(Path(path), _write)


def read_wav(path) -> WavInfo:
    """Read any mono WAV; `meta` is None when bowsynth did not write it."""
    p = Path(path)
    if not p.is_file():
        raise UsageError(f"WAV file {p} not found")
    try:
        with sf.SoundFile(str(p)) as f:
            data = f.read(dtype="float64", always_2d=True)
            rate = f.samplerate
            comment = f.comment
    except (sf.LibsndfileError, RuntimeError) as e:
        raise UsageError(f"{p} is not a readable audio file ({e})") from None
    if data.shape[1] != 1:
        data = data.mean(axis=1, keepdims=True)
    meta = None
    try:
        m = json.loads(comment) if comment else None
        if isinstance(m, dict) and m.get(META_KEY) == META_VERSION:
            meta = m
            Scene.from_dict(meta["scene"])
            if not (math.isfinite(float(meta["gain"])) and float(meta["gain"]) > 0):
                raise ValueError("bad gain")
    except (ValueError, KeyError, TypeError):
        raise UsageError(f"{p} has damaged bowsynth metadata; pass the scene with --fb/--vb/... flags") from None
    return WavInfo(p, data[:, 0], rate, meta)
