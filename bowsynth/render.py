"""Render: what every engine (FDM or operator) returns, and the one entry point that picks the engine."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .scene import Scene


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
    controls: dict = None

    def __post_init__(self):
        if self.controls is None:  # an engine that applies the scene's controls as given
            self.controls = {"fb": self.scene.fb_at(self.t), "vb": self.scene.vb_at(self.t)}

    @property
    def u(self) -> np.ndarray:
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
