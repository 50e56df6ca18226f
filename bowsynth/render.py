"""Render: what every engine (FDM or operator) returns; `bowsynth.api.render` is the one entry point that picks the
engine."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .scene import Scene


class LazyControls(Mapping):
    """A render's controls (fb, vb per output sample), computed on first use by `make`.

    Two float64 arrays per voice are a measurable share of a many-voice score that never reads them (a 172-note
    chorale spent 35 ms expanding the operator's per-window bows).

    Parameters
    ----------
    make : callable
        make() returns {'fb': array, 'vb': array}; called once, on the first read.

    Examples
    --------
    >>> import numpy as np
    >>> c = LazyControls(lambda: {"fb": np.full(3, 100.0), "vb": np.full(3, 0.2)})
    >>> sorted(c), c["vb"].tolist()
    (['fb', 'vb'], [0.2, 0.2, 0.2])
    """

    def __init__(self, make):
        self._make, self._arrays = make, None

    def _get(self) -> dict:
        if self._arrays is None:
            self._arrays = self._make()
            self._make = None
        return self._arrays

    def __getitem__(self, key):
        return self._get()[key]

    def __iter__(self):
        return iter(("fb", "vb"))

    def __len__(self) -> int:
        return 2


class Played(str):
    """Which engines played a render, as a typed value that still reads (and compares) as the text users see.

    "fdm", "fdm x4" (oversampled), "operator", "operator+fdm" (a voice the FDM finished after it left its model),
    "operator+fdm + fdm release" (a note whose bow stop the FDM played).

    Parameters
    ----------
    engine : {'operator', 'fdm'}
        The engine that played the render.
    oversample : int
        The FDM's steps per output sample.
    fdm_fallback : bool
        The FDM finished an operator voice after it left its model.
    fdm_release : bool
        The FDM played the note's bow stop.

    Raises
    ------
    ValueError
        Another engine.

    Examples
    --------
    >>> p = Played("operator", fdm_fallback=True).with_fdm_release()
    >>> p == "operator+fdm + fdm release", p.engine, p.fdm_release
    (True, 'operator', True)
    >>> str(Played("fdm", 4))
    'fdm x4'
    """

    engine: str
    oversample: int
    fdm_fallback: bool
    fdm_release: bool

    def __new__(cls, engine: str, oversample: int = 1, fdm_fallback: bool = False, fdm_release: bool = False):
        if engine not in ("operator", "fdm"):
            raise ValueError(f"engine must be operator or fdm, got {engine!r}")
        text = ("fdm" if oversample == 1 else f"fdm x{oversample}") if engine == "fdm" else \
            "operator" + ("+fdm" if fdm_fallback else "")
        self = super().__new__(cls, text + (" + fdm release" if fdm_release else ""))
        self.engine, self.oversample, self.fdm_fallback, self.fdm_release = engine, oversample, fdm_fallback, fdm_release
        return self

    def __getnewargs__(self):
        """What pickle rebuilds it from (a render sent between processes: a Ray task's, a worker pool's)."""
        return self.engine, self.oversample, self.fdm_fallback, self.fdm_release

    def with_fdm_release(self) -> "Played":
        """The same engines, with the bow stop played by the FDM."""
        return Played(self.engine, self.oversample, self.fdm_fallback, True)


@dataclass
class RenderInfo:
    """What an engine reports beside the samples (each field None, or empty, where it does not apply).

    Examples
    --------
    >>> from bowsynth import api
    >>> from bowsynth.scene import Scene
    >>> api.render(Scene(duration=0.2)).info.model_id
    'fb100_f0100_vb0.2_a100@...'
    """

    model_id: str | None = None  # the operator's model
    model_path: str | None = None
    notes: list[str] = field(default_factory=list)  # what the user must know (a hand-off to the FDM, a check's verdict)
    loop: str | None = None  # the rollout loop that ran (numpy or compiled)
    setup_seconds: float | None = None  # choosing and preparing the model, before the loop
    batched: int | None = None  # voices rolled out together with this one
    range_validation: dict | None = None  # a range model's validation: how good it is over its box
    oversample: int | None = None  # the FDM's
    release: str | None = None  # who played a score note's bow stop: "operator" or "fdm"
    release_model: str | None = None  # the model that played it, where another than the sustain's took over at the hold
    rest_flow: float | None = None  # seconds from the start played by the flow at the bow's rest point (onset.py)
    ring_down: float | None = None  # seconds from which a held bow that damps the mass played that flow (onset.py)
    windows: int | None = None  # windows a sounding period where they were locked to it (windows.locked_window)
    chain: list | None = None  # (start in s, model name) per model, where models played the voice in turn


@dataclass
class Render:
    """A rendered scene: one value per output sample at the scene's sample rate (float64 from the FDM, float32 from
    the operator, the network's precision). Engines make it; `bowsynth.api.render` returns it.

    Parameters
    ----------
    scene : Scene
        What was rendered.
    t : numpy.ndarray or None
        The sample times (s). An engine may pass None: they are then made on first use, as few callers read them
        and they cost a render of 5 s ~1 ms of fresh memory.
    q, p : numpy.ndarray
        q = w u and p = u_t (m/s); u the mass displacement (m, `u`).
    method : Played
        The engines that played it ("fdm", "operator", "operator+fdm", ...).
    seconds : float
        The wall time the engine took.
    info : RenderInfo
        What the engine reports beside the samples.
    controls : Mapping, optional
        The bow force fb (m/s^2) and speed vb (m/s) the engine applied, one value per output sample (the operator
        holds them per window, so they may differ from the scene's curves between windows). None: the scene's
        curves at `t`, made on first use.

    Examples
    --------
    >>> from bowsynth import api
    >>> from bowsynth.scene import Scene
    >>> r = api.render(Scene(duration=0.2), engine="fdm")
    >>> r.method, r.q.dtype, r.t.shape, r.controls["fb"][:2].tolist()
    ('fdm', dtype('float64'), (8820,), [100.0, 100.0])
    >>> f"{abs(r.u).max() * 1e3:.2f} mm"
    '0.48 mm'
    """

    scene: Scene
    t: np.ndarray
    q: np.ndarray
    p: np.ndarray
    method: Played
    seconds: float = 0.0
    info: RenderInfo = field(default_factory=RenderInfo)
    controls: Mapping = None

    def __post_init__(self):
        if self.controls is None:  # an engine that applies the scene's controls as given
            self.controls = LazyControls(lambda: {"fb": self.scene.fb_at(self.t), "vb": self.scene.vb_at(self.t)})

    @property
    def u(self) -> np.ndarray:
        """The mass displacement u = q / w (m), w following the pitch where it varies."""
        if self.scene.pitch_varies:
            return self.q / (2.0 * np.pi * self.scene.f0_at(self.t))
        return self.q / self.scene.omega

    @property
    def realtime_factor(self) -> float:
        """Seconds of audio per second of wall time."""
        return self.scene.duration / self.seconds if self.seconds > 0 else float("inf")

    def signal(self, name: str = "u") -> np.ndarray:
        """The named signal: 'u' (displacement), 'p' (velocity) or 'q'.

        Parameters
        ----------
        name : {'u', 'p', 'q'}

        Returns
        -------
        numpy.ndarray
            One value per output sample.

        Raises
        ------
        ValueError
            Another name.

        Examples
        --------
        >>> from bowsynth import api
        >>> from bowsynth.scene import Scene
        >>> api.render(Scene(duration=0.2), engine="fdm").signal("p").shape
        (8820,)
        """
        if name not in ("u", "p", "q"):
            raise ValueError(f"signal must be u, p or q, got {name!r}")
        return getattr(self, name)


def _time_axis(r: Render) -> np.ndarray:
    t = r.__dict__.get("_t")
    if t is None:
        t = r.__dict__["_t"] = np.arange(len(r.p)) / r.scene.sample_rate
    return t


def _set_time_axis(r: Render, t) -> None:
    r.__dict__["_t"] = t


# after the dataclass is made: its __init__ assigns t through this property, so None can stand for "made later"
Render.t = property(_time_axis, _set_time_axis, doc="The sample times (s), float64.")
