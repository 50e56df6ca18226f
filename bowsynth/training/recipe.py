"""A training recipe: the settings of one model's `bowsynth train` in a TOML file, so that the Makefile, the
benchmarks and a user who wants the same model again read one source instead of flags copied between them.

    # models/soft-range.toml
    f0 = 100
    fb = "6.283:282.7"      # a range LO:HI, as --fb takes it
    vb = "0:0.3"
    minutes = 40
    out = "soft-range.safetensors"   # relative to this file

`from` names the range model a recipe refines (`train --from`): a file relative to the recipe's folder (another
recipe's `out`), else a model's name. `make models` builds each recipe after the one whose model it refines
(build_order: `python -m bowsynth.training.recipe RECIPE ...` prints them so).
"""

from __future__ import annotations

import tomllib
from pathlib import Path

from ..errors import UsageError
from ..io.infile import regular_file

# key: the types the value may have (TOML's); each is the `bowsynth train` flag of that name
KEYS = {"preset": (str,), "f0": (int, float), "fb": (str, int, float), "vb": (str, int, float), "a": (int, float),
        "minutes": (int, float), "steps": (int,), "seed": (int,), "rest_linear": (bool,), "out": (str,),
        "batch": (int,), "width": (int,), "device": (str,), "window_ms": (int, float), "from": (str,),
        "band_seconds": (int, float), "deriv": (int, float),
        "rollout": (int, float)}


def load_recipe(path) -> dict:
    """The recipe's settings, checked: known keys, the right types, `out` resolved against the recipe's folder."""
    path = Path(path)
    regular_file(path, "--config", "a recipe file")
    try:
        with path.open("rb") as fh:
            raw = tomllib.load(fh)
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


def parents(paths) -> dict[Path, Path | None]:
    """Each recipe's parent among `paths` (the recipe whose `out` it refines), or None."""
    paths = [Path(p) for p in paths]
    by_out: dict[Path, Path] = {}
    src_of: dict[Path, Path | None] = {}
    for p in paths:
        # read by its absolute path: load_recipe puts the folder before a `from` whose file exists, and a relative
        # folder (`make models` passes models/...) would be put before it twice below
        a = p.resolve()
        r = load_recipe(a)
        by_out[Path(r.get("out", a.with_suffix(".safetensors"))).resolve()] = p
        # the parent's file need not exist yet (a fresh build): its path as the recipe names it, from its folder
        # (a name, as `train --from` takes it, is the model file of that name beside the recipe)
        src = Path(r["from"]) if "from" in r else None
        if src is not None and not src.suffix:
            src = src.with_suffix(".safetensors")
        src_of[p] = (a.parent / src).resolve() if src is not None else None
    return {p: by_out.get(src_of[p]) if src_of[p] is not None else None for p in paths}


def build_order(paths) -> list[Path]:
    """The recipes in an order that builds each after the recipe whose `out` it refines (`from`), the rest as given.
    Why: a refinement of a refinement (fast-long from soft-fast from soft-range; creep-mid from stick-halt from a
    stage) must find its parent built, and a retrained parent must come before what refines it, else `make models`
    refines from the old parent and leaves the child stale for the next run. A cycle is refused."""
    paths = [Path(p) for p in paths]
    up_of = parents(paths)
    order: list[Path] = []
    state: dict[Path, int] = {}  # 1: being placed, 2: placed

    def place(p: Path) -> None:
        if state.get(p) == 2:
            return
        if state.get(p) == 1:
            raise UsageError(f"recipes refine each other in a cycle through {p}")
        state[p] = 1
        up = up_of[p]
        if up is not None:
            place(up)
        state[p] = 2
        order.append(p)
    for p in paths:
        place(p)
    return order


if __name__ == "__main__":
    import sys

    from ..errors import BowsynthError

    try:
        print("\n".join(str(p) for p in build_order(sys.argv[1:])), flush=True)
    except BowsynthError as e:  # `make models` runs this: one line, not a traceback
        sys.exit(f"error: {e}")
    except BrokenPipeError:  # read by `head` or the like, which stopped reading: nothing more to say
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        sys.exit(0)
