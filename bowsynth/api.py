"""The Python API the CLI and notebooks share."""

from __future__ import annotations

from .fdm import render_fdm  # noqa: F401


def render_operator(scene, model=None, fallback: str = "none"):
    from .rollout import render_operator as _r

    return _r(scene, model=model, fallback=fallback)
