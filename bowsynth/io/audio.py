"""Audio files with the render's own description inside, so `compare` needs nothing but the file.

Formats by extension, through soundfile: .wav (32-bit float: quantisation far below any error we measure), .flac
(24-bit), .ogg (Vorbis, lossy); "-" writes WAV to standard output. Peak-normalised to -1 dBFS unless a fixed gain is
asked for. The scene, the method, the model id, the gain and what was done to the DC go into the file's comment as
JSON (RIFF INFO for WAV, a Vorbis comment for FLAC and OGG).

DC: the bowed mass sits off its rest position while it is bowed (the friction force is a static load), about 0.045
of full scale in a peak-normalised `u`; that offset is not sound. By default it is removed by `remove_dc`: the
zero-phase response of a 2nd-order Butterworth high-pass at 5 Hz run forward and backward, then the remaining mean
subtracted. Measured (tests/test_outfile.py): harmonic amplitudes of a 1 s note change by less than
0.01 dB above 20 Hz. The metadata records it ("dc": "highpass-5hz"), and `compare` applies the same filter to its
reference, so scores still measure the physics.
"""

from __future__ import annotations

import json
import math
import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import soundfile as sf

from ..errors import UsageError
from ..render import Render
from ..scene import Scene
from .infile import regular_file
from .outfile import atomic_write, check_output_path, is_stdout, resolve  # noqa: F401  (re-exported)

META_KEY = "bowsynth"
META_VERSION = 2  # 2: "dc" says whether the DC was removed; version 1 files (DC kept) are still read
READ_VERSIONS = (1, 2)
PEAK = 0.891  # -1 dBFS
DC_HZ = 5.0
TINY_PEAK = 1e-200  # below this PEAK / peak (and the float32 samples) stop being meaningful numbers
DC_MODES = ("remove", "keep")
DC_TAG = "highpass-5hz"

# extension -> (soundfile format, subtype, description)
FORMATS = {".wav": ("WAV", "FLOAT", "32-bit float WAV"), ".flac": ("FLAC", "PCM_24", "24-bit FLAC"),
           ".ogg": ("OGG", "VORBIS", "Ogg Vorbis, lossy")}
LOSSY = {"OGG"}
# libsndfile keeps RIFF INFO strings up to about 2 kB (longer ones are cut); Vorbis comments hold far more
META_LIMIT = {"WAV": 2000, "FLAC": 1_000_000, "OGG": 1_000_000}


def format_list() -> str:
    return ", ".join(f"{ext} ({d})" for ext, (_, _, d) in FORMATS.items()) + ", or - (WAV to standard output)"


def output_format(path) -> tuple[str, str]:
    """(format, subtype) for an output path, from its extension; refuses anything else, before any work.

    A FIFO or a character device without a known extension (/dev/null, a named pipe) gets WAV.
    """
    if is_stdout(path):
        return "WAV", "FLOAT"
    ext = Path(path).suffix.lower()
    if ext in FORMATS:
        return FORMATS[ext][:2]
    try:
        special = resolve(path, force=True).kind == "special"
    except UsageError:
        special = False
    if special and not ext:
        return "WAV", "FLOAT"
    raise UsageError(f"cannot write {ext or 'a file without an extension'} ({path}); bowsynth writes {format_list()}")


def check_audio_output(path, force: bool = False) -> tuple[str, str]:
    """Everything about an audio output path that can be checked before rendering: writable, known format."""
    check_output_path(path, force=force)
    return output_format(path)


@dataclass
class WavInfo:
    """What an audio file holds: the signal in physical units (samples / gain) and its metadata, if bowsynth wrote it."""

    path: Path
    samples: np.ndarray  # as stored, normalised
    sample_rate: int
    meta: dict | None
    format: str = "WAV"

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

    @property
    def dc_removed(self) -> bool:
        return bool(self.meta) and self.meta.get("dc") == DC_TAG

    @property
    def lossy(self) -> bool:
        return self.format in LOSSY


# The filter's impulse response decays with time constant 1 / (2 pi 5 Hz / sqrt 2) = 45 ms: 0.5 s is 11 of them
# (e^-11 ~ 2e-5 of the edge's transient left), and the odd reflection keeps the padded signal continuous at the ends.
DC_PAD_S = 0.5


def remove_dc(x: np.ndarray, sample_rate: float) -> np.ndarray:
    """The DC and the infrasonic drift of the onset removed (see the module docstring); a new float64 array.

    A 2nd-order Butterworth high-pass at DC_HZ run forward and backward (the compiled core's
    `highpass_zero_phase`: zero phase, |H|^2 = (f/fc)^4 / (1 + (f/fc)^4) up to the bilinear warp, 1e-8 at 5 Hz), the
    signal padded by odd reflection (DC_PAD_S at each end) so that the filter's start-up rings out before it reaches
    the signal; then the remaining mean subtracted. No scipy (0.3-0.9 s of start-up) and no FFT: the FFT of a
    23 s chorale's mix took 50-60 ms, a third of the operator's render, where the recursive filter takes ~5 ms.
    """
    from .. import compiled as core

    x = np.asarray(x, dtype=np.float64)
    if x.size < 2:
        return x - x.mean() if x.size else x.copy()
    pad = int(DC_PAD_S * sample_rate)
    # a signal shorter than the pad is reflected again and again (np.pad's rule)
    padded = odd_reflection(x, pad) if pad < x.size else np.pad(x, pad, mode="reflect", reflect_type="odd")
    core.load().highpass_zero_phase(padded, math.tan(math.pi * DC_HZ / sample_rate))
    y = padded[pad:pad + x.size]
    y -= y.mean()  # in place: a 23 s mix is 8 MB, and each fresh array of that size may stall on its pages
    return y


def odd_reflection(x: np.ndarray, pad: int) -> np.ndarray:
    """x (1-D, pad < len(x)) padded by pad samples at each end by odd reflection about its end samples:
    np.pad(x, pad, mode="reflect", reflect_type="odd"), written into one array (np.pad took 27 ms of a chorale's 1 M
    samples, this ~3 ms)."""
    n = x.size
    out = np.empty(n + 2 * pad)
    out[pad:pad + n] = x
    if pad:
        np.subtract(2 * x[0], x[pad:0:-1], out=out[:pad])
        np.subtract(2 * x[-1], x[-2:-pad - 2:-1], out=out[pad + n:])
    return out


def gain_for(x: np.ndarray, gain_db: float | None) -> float:
    """Peak normalisation to PEAK, or the fixed gain 10^(gain_db/20); a fixed gain that would clip is refused."""
    # max and -min rather than abs(x).max(): no array of the signal's size (a chorale's mix: 8 MB) to allocate
    peak = float(max(np.max(x), -np.min(x))) if x.size else 0.0
    if gain_db is None:
        if peak < TINY_PEAK:  # e.g. --fb 1e-300 moves the mass by 1e-311 m: the gain would overflow
            warnings.warn(f"the signal peaks at {peak:.3g}, too small to normalise: written as silence" if peak > 0
                          else "the signal is silent (all zeros): the bow never moved the mass")
            return 1.0
        return PEAK / peak
    if not math.isfinite(gain_db):
        raise UsageError(f"--gain must be a finite number of dB, got {gain_db}")
    g = 10.0 ** (gain_db / 20.0)
    if not (math.isfinite(g) and g > 0):
        raise UsageError(f"--gain {gain_db:g} dB is out of range")
    if peak * g > 1.0:
        fit = 20 * math.log10(PEAK / peak) if peak > 0 else 0.0
        raise UsageError(f"--gain {gain_db:g} dB would clip (peak {20 * math.log10(peak * g):+.1f} dBFS); use at most "
                         f"--gain {math.floor(fit * 10) / 10:g} for a -1 dBFS peak, or leave --gain out to normalise")
    return g


def check_gain_db(gain_db: float | None) -> None:
    if gain_db is not None and not (math.isfinite(gain_db) and -400 < gain_db < 400):
        raise UsageError(f"--gain must be a number of dB in (-400, 400), got {gain_db}")


def check_dc(dc: str) -> None:
    if dc not in DC_MODES:
        raise UsageError(f"--dc must be remove or keep, got {dc!r}")


def render_meta(scene: Scene, method: str, signal: str, gain: float, seconds: float, model, dc: str) -> dict:
    return {META_KEY: META_VERSION, "scene": scene.to_dict(), "method": method, "signal": signal, "gain": gain,
            "render_seconds": seconds, "model": model, "dc": DC_TAG if dc == "remove" else "kept"}


def check_meta_fits(meta: dict, path) -> None:
    """Refuse (before rendering, when called with a preview) metadata the chosen format cannot hold."""
    fmt = output_format(path)[0]
    size = len(json.dumps(meta, separators=(",", ":")))
    if size > META_LIMIT[fmt]:
        raise UsageError(f"the description of this render ({size} bytes of JSON) is too long for a {fmt} comment "
                         f"(at most {META_LIMIT[fmt]}); write .flac or .ogg instead")


def wav_payload(render: Render, signal: str = "u", dc: str = "remove", gain_db: float | None = None):
    """(samples scaled for the file, metadata): what write_wav writes, for a writer elsewhere (a corpus's driver
    writes what its workers rendered)."""
    check_dc(dc)
    x = render.signal(signal)
    if not np.all(np.isfinite(x)):
        raise ValueError("refusing to write non-finite samples")
    if dc == "remove":
        x = remove_dc(x, render.scene.sample_rate)
    gain = gain_for(x, gain_db)
    meta = render_meta(render.scene, render.method, signal, gain, render.seconds, render.info.model_id, dc)
    return (x * gain).astype(np.float32), meta


def write_wav(path, render: Render, signal: str = "u", dc: str = "remove", gain_db: float | None = None,
              force: bool = True) -> dict:
    """Write the render's `signal` ('u' or 'p') to `path` (format by extension); returns the metadata written."""
    x, meta = wav_payload(render, signal, dc, gain_db)
    write_float_wav(path, x, render.scene.sample_rate, meta, force=force)
    return meta


def mix_meta(names: list[str], gain: float, dc: str, **fields) -> dict:
    """A mix's metadata: the voice count, `fields` (bowsynth.music.score: notes, signal, stems) and as many voice names as
    fit in a WAV comment (a 1000-voice mix still fits)."""
    meta = {"bowsynth_mix": 1, "voices": len(names), **fields, "gain": gain, "dc": DC_TAG if dc == "remove" else "kept"}
    kept, size = [], len(json.dumps(meta)) + 40
    for n in names:
        size += len(json.dumps(n)) + 2
        if size > META_LIMIT["WAV"] - 100:
            break
        kept.append(n)
    meta["names"] = kept
    if len(kept) < len(names):
        meta["names_truncated"] = True
    return meta


def write_mix(path, x: np.ndarray, names: list[str], sample_rate: int, dc: str = "remove",
              gain_db: float | None = None, force: bool = True, **fields) -> dict:
    """Write a mix, `x` being the notes already summed at their starts (bowsynth.music.mix.mix_notes): the DC removed
    once, from the sum, then peak-normalised to PEAK (never clips) or the fixed gain `gain_db` (refused if it would
    clip)."""
    check_dc(dc)
    if not np.all(np.isfinite(x)):
        raise ValueError("refusing to write non-finite samples")
    own = dc == "remove"
    if own:
        x = remove_dc(x, sample_rate)
    gain = gain_for(x, gain_db)
    meta = mix_meta(names, gain, dc, **fields)
    if own:  # remove_dc's new array: scaled in place (a fresh 8 MB array may stall on its pages)
        x *= gain
    else:
        x = x * gain
    write_float_wav(path, x, sample_rate, meta, force=force)
    return meta


def write_float_wav(path, x: np.ndarray, sample_rate: int, meta: dict, force: bool = True) -> None:
    """Atomically write samples (already scaled to +-1) with `meta` as JSON in the comment; format by extension."""
    if not np.all(np.isfinite(x)):
        raise ValueError("refusing to write non-finite samples")
    fmt, subtype = output_format(path)
    check_meta_fits(meta, path)
    text = json.dumps(meta, separators=(",", ":"))

    def _write(tmp):
        with sf.SoundFile(tmp, "w", sample_rate, 1, subtype=subtype, format=fmt) as f:
            f.comment = text
            f.software = "bowsynth"
            f.write(np.asarray(x, dtype=np.float32))

    atomic_write(path, _write, force=force)


def _riff_shortfall(p: Path) -> tuple[int, int] | None:
    """For a RIFF/WAVE file: (bytes its data chunk declares, bytes present) when fewer are present, else None."""
    size = p.stat().st_size
    with p.open("rb") as f:
        head = f.read(12)
        if len(head) < 12 or head[:4] != b"RIFF" or head[8:12] != b"WAVE":
            return None
        pos = 12
        while pos + 8 <= size:
            f.seek(pos)
            cid, n = struct.unpack("<4sI", f.read(8))
            if cid == b"data":
                present = size - pos - 8
                return (n, present) if n != 0xFFFFFFFF and present < n else None
            pos += 8 + n + (n & 1)
    return None


def _check_fields(meta: dict) -> None:
    """The fields other than the scene that readers use, of the types render writes (ValueError if not): an edited
    comment must fail here, in one line, not as a TypeError deep in compare."""
    rs = meta.get("render_seconds")
    if rs is not None and (isinstance(rs, bool) or not isinstance(rs, (int, float)) or not math.isfinite(rs) or rs < 0):
        raise ValueError(f"render_seconds {rs!r}")
    if meta.get("signal", "u") not in ("u", "p", "q"):
        raise ValueError(f"signal {meta.get('signal')!r}")
    for key in ("method", "model", "dc"):
        if meta.get(key) is not None and not isinstance(meta[key], str):
            raise ValueError(f"{key} {meta[key]!r}")


def read_wav(path) -> WavInfo:
    """Read any mono audio file soundfile reads; `meta` is None when bowsynth did not write it.

    A file with fewer samples than its header or its metadata promise (cut short in a copy, edited) is refused,
    naming what is missing: scores over part of a file would look like scores over all of it.
    """
    p = Path(path)
    if p.suffix.lower() in (".wav", ""):
        regular_file(p, "WAV file", "a WAV file")
    else:
        regular_file(p, "audio file", "an audio file")
    try:
        with sf.SoundFile(str(p)) as f:
            data = f.read(dtype="float64", always_2d=True)
            rate = f.samplerate
            comment = f.comment
            fmt = f.format
    except (sf.LibsndfileError, RuntimeError) as e:
        raise UsageError(f"{p} is not a readable audio file ({e})") from None
    short = _riff_shortfall(p) if fmt == "WAV" else None
    if short is not None:
        declared, present = short
        raise UsageError(f"{p} is truncated: its header declares {declared} bytes of audio, only {present} are present "
                         f"({100 * present / declared:.1f} %, {len(data)} frames = {len(data) / rate:g} s readable)")
    if data.shape[1] != 1:
        data = data.mean(axis=1, keepdims=True)
    meta = None
    try:
        m = json.loads(comment) if comment else None
        if isinstance(m, dict) and m.get(META_KEY) in READ_VERSIONS:
            meta = m
            Scene.from_dict(meta["scene"])
            if not (math.isfinite(float(meta["gain"])) and float(meta["gain"]) > 0):
                raise ValueError("bad gain")
            _check_fields(meta)
    except (ValueError, KeyError, TypeError):
        raise UsageError(f"{p} has damaged bowsynth metadata; pass the scene with --fb/--vb/... flags") from None
    if meta is not None:
        want = Scene.from_dict(meta["scene"]).n_samples
        if len(data) != want:
            what = "missing" if len(data) < want else "extra"
            raise UsageError(f"{p} holds {len(data)} frames ({len(data) / rate:g} s) but its bowsynth metadata describes "
                             f"{want} ({want / rate:g} s): {abs(want - len(data))} frames {what}; the file was cut or "
                             f"edited, re-render it")
    return WavInfo(p, data[:, 0], rate, meta, fmt)
