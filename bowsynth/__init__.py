"""bowsynth: a bowed mass-spring synthesizer driven by a physics-informed DeepONet."""

__version__ = "0.1.0"

import os as _os

# numpy's OpenBLAS on one thread (unless the user set it; it is read when numpy loads): bowsynth's numpy products are
# small (a trunk on its grid, a harmonic fit), the compiled core keeps its own threads, and OpenBLAS's threads spin
# for cores another process holds. Measured with a training beside it on this 2-core machine: a harmonic fit's
# 44100 x 21 normal matrix 1380 ms on OpenBLAS's threads, 1.3 ms on one (a first `play --windows auto` 384 s -> 90 s,
# with the harmonic fit's normal equations); a whole `score --mix` of the chorale showed no difference beyond its noise
# (docs/BENCHMARKS.md, "numpy's BLAS on one thread").
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from .errors import BowsynthError, DomainError, ModelFileError, SceneError, UsageError  # noqa: E402,F401


def shipped(name: str):
    """The folder `name` ('models', 'presets') that ships with bowsynth: inside the installed package, where a wheel
    puts it, else at the top of the source checkout, where it is kept (an editable install reads it there)."""
    from pathlib import Path

    here = Path(__file__).resolve().parent
    inside = here / name
    return inside if inside.is_dir() else here.parent / name

# Everything else is imported on first use, so `import bowsynth` (and the CLI's start) loads no numpy, the
# compiled core or torch (training, seconds) until a command needs them.
_LAZY = {"Render": "render", "Scene": "scene", "load_preset": "scene", "make_scene": "music.request", "render_fdm": "api",
         "render_operator": "api", "load_model": "api", "train": "api"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_LAZY])
