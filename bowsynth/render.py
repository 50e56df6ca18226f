"""Render: what every engine (FDM or operator) returns, and the one entry point that picks the engine."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .scene import Scene


class SceneControls(Mapping):
    """The scene's own controls at the render's sample times, computed on first use: two float64 arrays per voice
    are a measurable share of a many-voice score that never reads them (issue 12)."""

    def __init__(self, scene: Scene, t: np.ndarray):
        self._scene, self._t, self._arrays = scene, t, None

    def _get(self) -> dict:
        if self._arrays is None:
            self._arrays = {"fb": self._scene.fb_at(self._t), "vb": self._scene.vb_at(self._t)}
        return self._arrays

    def __getitem__(self, key):
        return self._get()[key]

    def __iter__(self):
        return iter(("fb", "vb"))

    def __len__(self) -> int:
        return 2


@dataclass
class Render:
    """A rendered scene: one value per output sample at the scene's sample rate (float64 from the FDM, float32 from
    the operator, the network's precision).

    q = w u and p = u_t (m/s); u the mass displacement (m); t in s. `seconds` is the wall time the engine took.
    `controls` holds the bow force fb (m/s^2) and speed vb (m/s) the engine applied, one value per output sample
    (the operator holds them per window, so they may differ from the scene's curves between windows).
    """

    scene: Scene
    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    method: str
    seconds: float = 0.0
    info: dict = field(default_factory=dict)
    controls: Mapping = None

    def __post_init__(self):
        if self.controls is None:  # an engine that applies the scene's controls as given
            self.controls = SceneControls(self.scene, self.t)

    @property
    def u(self) -> np.ndarray:
        if self.scene.pitch_varies:
            return self.q / (2.0 * np.pi * self.scene.f0_at(self.t))
        return self.q / self.scene.omega

    @property
    def realtime_factor(self) -> float:
        """Seconds of audio per second of wall time."""
        return self.scene.duration / self.seconds if self.seconds > 0 else float("inf")

    def signal(self, name: str = "u") -> np.ndarray:
        """The named signal: 'u' (displacement), 'p' (velocity) or 'q'."""
        if name not in ("u", "p", "q"):
            raise ValueError(f"signal must be u, p or q, got {name!r}")
        return getattr(self, name)
