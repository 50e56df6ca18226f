"""A training recipe: the settings of one model's `bowsynth train` in a TOML file, so that the Makefile, the
benchmarks and a user who wants the same model again read one source instead of flags copied between them.

    # bowsynth/models/soft-range.toml
    f0 = 100
    fb = "6.283:282.7"      # a range LO:HI, as --fb takes it
    vb = "0:0.3"
    minutes = 40
    out = "soft-range.safetensors"   # relative to this file

`from` names the range model a recipe refines (`train --from`): a file relative to the recipe's folder (another
recipe's `out`), else a model's name. `make models` builds those recipes after the others.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from ..errors import UsageError

# key: the types the value may have (TOML's); each is the `bowsynth train` flag of that name
KEYS = {"preset": (str,), "f0": (int, float), "fb": (str, int, float), "vb": (str, int, float), "a": (int, float),
        "minutes": (int, float), "steps": (int,), "seed": (int,), "rest_linear": (bool,), "out": (str,),
        "batch": (int,), "width": (int,), "device": (str,), "window_ms": (int, float), "from": (str,),
        "band_seconds": (int, float), "deriv": (int, float)}


def load_recipe(path) -> dict:
    """The recipe's settings, checked: known keys, the right types, `out` resolved against the recipe's folder."""
    path = Path(path)
    try:
        with path.open("rb") as fh:
            raw = tomllib.load(fh)
    except FileNotFoundError:
        raise UsageError(f"--config {path}: no such file") from None
    except IsADirectoryError:
        raise UsageError(f"--config {path} is a directory, not a recipe file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise UsageError(f"--config {path} is not valid TOML: {e}") from None
    out = {}
    for key, value in raw.items():
        if key not in KEYS:
            raise UsageError(f"--config {path}: unknown key {key!r}; known: {', '.join(KEYS)}")
        types = KEYS[key]
        if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
            raise UsageError(f"--config {path}: {key} must be {' or '.join(t.__name__ for t in types)}, got {value!r}")
        out[key] = str(value) if key in ("fb", "vb") else value
    if "out" in out:
        out["out"] = path.parent / out["out"]
    if "from" in out and (path.parent / out["from"]).is_file():
        out["from"] = str(path.parent / out["from"])
    return out
