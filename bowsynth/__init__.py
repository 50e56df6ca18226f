"""bowsynth: a bowed mass-spring synthesizer driven by a physics-informed DeepONet."""

__version__ = "0.1.0"

from .errors import BowsynthError, DomainError, ModelFileError, SceneError, UsageError  # noqa: E402,F401
from .render import Render  # noqa: E402,F401
from .scene import Scene, load_preset, make_scene  # noqa: E402,F401
from .fdm import render_fdm  # noqa: E402,F401


def __getattr__(name):
    # torch is imported only when the operator is used: FDM-only users start fast
    if name in ("render_operator", "load_model", "train"):
        from . import api
        return getattr(api, name)
    raise AttributeError(name)
