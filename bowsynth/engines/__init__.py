"""The one place that picks the engine for a render: the FDM or the trained operator.

    render(scene, engine="operator")          -> Render
    render([scene, ...], engine="operator")   -> [Render, ...]   (the operator batches voices in one rollout)

The CLI's render and score commands and the Python API all come through here, so an engine's options and its
refusals are stated once.
"""

from __future__ import annotations

from enum import Enum

from ..errors import UsageError
from ..render import Render


class Engine(str, Enum):
    operator = "operator"
    fdm = "fdm"


class Fallback(str, Enum):
    none = "none"
    fdm = "fdm"


def parse_choice(enum, value, flag: str):
    """A flag's value as a member of its Enum, or a UsageError naming the choices (the CLI, score and API share it)."""
    try:
        return enum(value)
    except ValueError:
        raise UsageError(f"{flag} must be {' or '.join(e.value for e in enum)}, got {value!r}") from None


def render(scene, engine: str = "operator", model=None, fallback: str = "none", oversample: int = 1, sounding=None):
    """Render a Scene (or a list of Scenes) with the FDM or the operator.

    model: operator model (path, OperatorModel, or None to pick the covering one); fallback: 'fdm' finishes an
    operator voice that leaves its model's domain with the FDM; oversample: FDM only, a multiple of the sample rate.
    sounding: operator only, the frequency (Hz) each note sounds at where known (a number, or a list for a list of
    scenes): its windows are locked to that period (operator.windows.locked_window).
    """
    engine = parse_choice(Engine, engine, "--method")
    fallback = parse_choice(Fallback, fallback, "--fallback")
    many = isinstance(scene, (list, tuple))
    scenes = list(scene) if many else [scene]
    if engine is Engine.fdm:
        from .fdm import render_fdm

        out = [render_fdm(s, oversample=oversample) for s in scenes]
        return out if many else out[0]
    from .operator.engine import render_operator

    return render_operator(scenes if many else scene, model=model, fallback=fallback.value, sounding=sounding)


__all__ = ["Engine", "Fallback", "Render", "parse_choice", "render"]
