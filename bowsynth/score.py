"""Many voices at once: a TOML score (or a list of presets) rendered in one batched operator rollout.

    # score.toml
    [defaults]          # optional, applied to every voice
    duration = 2.0
    [[voice]]
    name = "root"
    preset = "paper-fb100"
    [[voice]]
    name = "fifth"
    preset = "paper-fb100"
    f0 = 150.0
    fb = 150.0          # same F_B / w, so the same model plays it
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from .errors import UsageError
from .render import Render
from .scene import Scene, make_scene


@dataclass
class Voice:
    name: str
    scene: Scene


def load_score(path) -> list[Voice]:
    p = Path(path)
    if not p.is_file():
        raise UsageError(f"score file {p} not found")
    try:
        with p.open("rb") as fh:
            data = tomllib.load(fh)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise UsageError(f"score {p} is not valid TOML ({e})") from None
    defaults = data.get("defaults", {})
    voices = data.get("voice")
    if not isinstance(voices, list) or not voices:
        raise UsageError(f"score {p} has no [[voice]] entries")
    out = []
    for i, v in enumerate(voices):
        if not isinstance(v, dict):
            raise UsageError(f"score {p}: voice {i + 1} is not a table")
        fields = {**defaults, **v}
        name = str(fields.pop("name", f"voice{i + 1}"))
        preset = fields.pop("preset", None)
        try:
            out.append(Voice(name, make_scene(preset, **fields)))
        except UsageError as e:
            raise UsageError(f"score {p}, voice {name!r}: {e}") from None
    return out


def voices_from_presets(names: list[str], **overrides) -> list[Voice]:
    return [Voice(n, make_scene(n, **overrides)) for n in names]


def render_voices(voices: list[Voice], method: str = "operator", model=None, fallback: str = "none") -> list[Render]:
    from .engines import render

    return render([v.scene for v in voices], engine=method, model=model, fallback=fallback)


def safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "voice"


def voice_paths(voices, out: Path) -> list[Path]:
    """The file each voice gets in the directory `out`: name.wav, and name-2.wav, ... for repeated names."""
    paths = []
    seen: dict[str, int] = {}
    for v in voices:
        stem = safe_name(v.name)
        seen[stem] = seen.get(stem, 0) + 1
        paths.append(out / (f"{stem}.wav" if seen[stem] == 1 else f"{stem}-{seen[stem]}.wav"))
    return paths


def write_voices(voices, renders, out: Path, mix: bool, signal: str = "u", dc: str = "remove",
                 gain_db: float | None = None, force: bool = True) -> list[Path]:
    """One WAV per voice into the directory `out`, or (mix=True) their sum into the file `out` (see wav.write_mix)."""
    from .wav import write_mix, write_wav

    if not mix:
        out.mkdir(parents=True, exist_ok=True)
        paths = voice_paths(voices, out)
        for path, r in zip(paths, renders):
            write_wav(path, r, signal=signal, dc=dc, gain_db=gain_db, force=force)
        return paths
    rates = {r.scene.sample_rate for r in renders}
    if len(rates) != 1:
        raise UsageError(f"a mix needs one sample rate; the voices use {sorted(rates)}")
    # no scene of its own: `compare` on a mix asks for the scene flags
    write_mix(out, [r.signal(signal) for r in renders], [v.name for v in voices], rates.pop(), dc=dc,
              gain_db=gain_db, force=force)
    return [out]
