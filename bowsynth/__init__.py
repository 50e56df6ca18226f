"""bowsynth: a bowed mass-spring synthesizer driven by a physics-informed DeepONet."""

__version__ = "0.1.0"

from .errors import BowsynthError, DomainError, ModelFileError, SceneError, UsageError  # noqa: E402,F401

# Everything else is imported on first use, so `import bowsynth` (and the CLI's start) loads no numpy, numba (the
# FDM, ~0.5 s) or torch (training, seconds) until a command needs them.
_LAZY = {"Render": "render", "Scene": "scene", "load_preset": "scene", "make_scene": "music.request", "render_fdm": "api",
         "render_operator": "api", "load_model": "api", "train": "api"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_LAZY])
