"""Scene: a typed, validated description of one render, and the presets that name common ones."""

from __future__ import annotations

import dataclasses
import itertools
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import controls, physics
from .controls import Curve
from .errors import SceneError, UsageError
from . import shipped

PRESET_DIR = shipped("presets")

MIN_RATE, MAX_RATE = 8_000, 384_000
CONTROLS = ("fb", "vb", "f0")  # the scene fields that may follow a curve (f0: a pitch curve, Hz)
# Bounds on magnitudes, far outside any playable value, so that every formula downstream (the FDM's step bounds,
# u = q / w, the gain of a file) stays finite: 1e308 bow forces, speeds or states overflowed into internal errors.
MIN_F0 = 1.0  # Hz: below it u = q / w grows without bound and nothing sounds
MIN_A = 1e-9  # s^2/m^2: a friction curve this flat is no friction; 5e-324 underflowed a / a_model to 0
MAGNITUDE_LIMITS = (("fb", 1e9, "m/s^2"), ("vb", 1e3, "m/s"), ("a", 1e9, "s^2/m^2"), ("q0", 1e3, "m/s"),
                    ("p0", 1e3, "m/s"))
# A note holds its bow (Scene.held_bow) where it holds one bow for at least this share of its length: a score's note
# holds it to its release, a rendered note with an attack or a stop mostly; a gesture moves through other bows.
HELD_SHARE = 0.5


@dataclass(frozen=True)
class Scene:
    """One render: a bowed mass at pitch f0, bowed with force fb at speed vb, for duration seconds.

    Frozen and checked on construction. fb and vb are numbers or curves (a `Curve`, or a list of [t, value] pairs
    in s: linear between, held outside): bow gestures within the note. f0 may be a curve too (vibrato, glissando,
    pitch bend): the FDM follows w(t) at every step, the operator per window. A scene whose f0 varies has no single
    `omega` or `dtau`: use `f0_at`. Other constructors: `from_dict`, `load_preset` (a preset's fields) and
    `bowsynth.music.request.make_scene` (a preset, a pitch such as "A4" tuned for the engine, F_B / w).

    Parameters
    ----------
    f0 : float or Curve
        The mass's natural frequency (Hz), below Nyquist.
    fb : float or Curve
        Bow force per unit mass (m/s^2), >= 0.
    vb : float or Curve
        Bow speed (m/s).
    a : float
        Friction shape (s^2/m^2), > 0.
    duration : float
        Seconds, at most 3600 and at least 2 samples.
    sample_rate : int
        Hz, 8000 to 384000.
    q0, p0 : float
        The initial state: q0 = w u(0) and p0 = u_t(0), in m/s.

    Raises
    ------
    SceneError
        A value that is not a number (or a curve where one may be), not finite, or outside its range.

    Examples
    --------
    >>> s = Scene(f0=220, fb=[[0, 50], [0.5, 200]], duration=0.5)
    >>> s.varying, s.n_samples, s.describe()
    (True, 22050, 'fb=50@0,200@0.5 f0=220 vb=0.2 a=100')
    >>> s.fb_at([0, 0.25, 1.0]).tolist()
    [50.0, 125.0, 200.0]
    >>> round(Scene().beta, 6)  # F_B / w of a constant bow
    0.159155
    >>> Scene(f0=-1)
    Traceback (most recent call last):
    ...
    bowsynth.errors.SceneError: f0 must be > 0 Hz, got -1
    """

    f0: float = 100.0
    fb: float | Curve = 100.0
    vb: float | Curve = 0.2
    a: float = 100.0
    duration: float = 1.0
    sample_rate: int = 44_100
    q0: float = 0.0
    p0: float = 0.0

    def __post_init__(self):
        for name in CONTROLS:
            if not isinstance(getattr(self, name), bool):
                try:
                    object.__setattr__(self, name, controls.as_control(getattr(self, name)))
                except SceneError as e:
                    raise SceneError(f"{name}: {e}") from None
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, Curve):
                continue  # its breakpoints were checked finite by Curve; ranges below
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                kind = "a number or a curve ([[t, value], ...])" if f.name in CONTROLS else "a number"
                raise SceneError(f"{f.name} must be {kind}, got {v!r}")
            if not math.isfinite(v):
                raise SceneError(f"{f.name} must be finite, got {v}")
        if self.sample_rate != int(self.sample_rate):
            raise SceneError(f"sample_rate must be a whole number of Hz, got {self.sample_rate}")
        object.__setattr__(self, "sample_rate", int(self.sample_rate))
        if not MIN_RATE <= self.sample_rate <= MAX_RATE:
            raise SceneError(f"sample_rate must be in [{MIN_RATE}, {MAX_RATE}] Hz, got {self.sample_rate}")
        f0_lo, f0_hi = controls.bounds(self.f0)
        if f0_lo <= 0:
            raise SceneError(f"f0 must be > 0 Hz, got {f0_lo:g}")
        if f0_hi >= self.sample_rate / 2:
            raise SceneError(f"f0 must be below Nyquist ({self.sample_rate / 2:g} Hz), got {f0_hi:g}")
        if controls.bounds(self.fb)[0] < 0:
            raise SceneError(f"fb must be >= 0 m/s^2, got {self.fb}")
        if self.a <= 0:
            raise SceneError(f"a must be > 0 s^2/m^2, got {self.a}")
        if self.duration <= 0:
            raise SceneError(f"duration must be > 0 s, got {self.duration}")
        if self.duration * self.sample_rate < 2:
            raise SceneError(f"duration must hold at least 2 samples, got {self.duration} s")
        if self.duration > 3600:
            raise SceneError(f"duration must be <= 3600 s, got {self.duration}")
        for name, lim, unit in MAGNITUDE_LIMITS:
            v = getattr(self, name)
            big = max(abs(b) for b in controls.bounds(v)) if name in CONTROLS else abs(v)
            if big > lim:
                raise SceneError(f"{name} must be within +-{lim:g} {unit}, got {big:g}")
        if f0_lo < MIN_F0:
            raise SceneError(f"f0 must be >= {MIN_F0:g} Hz, got {f0_lo:g}")
        if self.a < MIN_A:
            raise SceneError(f"a must be >= {MIN_A:g} s^2/m^2, got {self.a:g}")

    @property
    def omega(self) -> float:
        """w = 2 pi f0 (rad/s); SceneError where f0 varies."""
        if isinstance(self.f0, Curve):
            raise SceneError("f0 varies in this scene; it has no single w (see f0_at)")
        return physics.omega(self.f0)

    @property
    def pitch_varies(self) -> bool:
        """Is f0 a curve?"""
        return isinstance(self.f0, Curve)

    def f0_at(self, t) -> "np.ndarray":
        """f0 (Hz) at times t (s)."""
        return controls.sample(self.f0, t)

    @property
    def f0_max(self) -> float:
        """The highest f0 (Hz) over the scene."""
        return controls.bounds(self.f0)[1]

    @property
    def varying(self) -> bool:
        """Does a bow control change during the render?"""
        return any(isinstance(getattr(self, n), Curve) for n in CONTROLS)

    @property
    def beta(self) -> float:
        """F_B / w of a scene with a constant bow force (a varying one has a range: `beta_range`)."""
        if isinstance(self.fb, Curve):
            raise SceneError("fb varies in this scene; it has no single F_B / w (see beta_range)")
        return physics.beta(self.fb, self.f0)

    @property
    def beta_range(self) -> tuple[float, float]:
        """(lowest, highest) F_B / w over the scene."""
        if isinstance(self.f0, Curve):  # fb / w of two piecewise-linear curves: extremes at their breakpoints
            t = np.union1d(controls.breakpoints(self.fb)[0], self.f0.times)
            b = self.fb_at(t) / (2.0 * math.pi * self.f0_at(t))
            return float(b.min()), float(b.max())
        lo, hi = controls.bounds(self.fb)
        return physics.beta(lo, self.f0), physics.beta(hi, self.f0)

    @property
    def vb_range(self) -> tuple[float, float]:
        """(lowest, highest) bow speed (m/s) over the scene."""
        return controls.bounds(self.vb)

    @property
    def fb_max(self) -> float:
        """The highest bow force (m/s^2) over the scene."""
        return controls.bounds(self.fb)[1]

    def fb_at(self, t) -> "np.ndarray":
        """Bow force (m/s^2) at times t (s)."""
        return controls.sample(self.fb, t)

    def vb_at(self, t) -> "np.ndarray":
        """Bow velocity (m/s) at times t (s)."""
        return controls.sample(self.vb, t)

    @property
    def dtau(self) -> float:
        """Sample spacing in dimensionless time tau = w t."""
        if isinstance(self.f0, Curve):
            raise SceneError("f0 varies in this scene; its sample spacing in tau varies (see f0_at)")
        return physics.dtau(self.f0, self.sample_rate)

    @property
    def n_samples(self) -> int:
        """Samples in the render: duration x sample_rate, rounded."""
        return int(round(self.duration * self.sample_rate))

    def held_bow(self) -> "Scene | None":
        """The scene with its bow held throughout at the bow it holds for most of the note.

        Where its curves move only for an attack (rising from F_B or v_B = 0) before that stretch and a stop
        (falling to 0) after it: what a held note's windows lock to (music.engine_tuning.sounding_for), as a
        score's note locks to its sustain.

        Returns
        -------
        Scene or None
            The held scene; the scene itself where its bow holds still; None for a gesture (a bow that moves
            otherwise, or holds for less than HELD_SHARE of the note) or a moving pitch.

        Examples
        --------
        >>> attack = Scene(fb=[[0, 0], [0.05, 100]], vb=[[0, 0], [0.05, 0.2]], duration=0.5)
        >>> attack.held_bow().describe()
        'fb=100 f0=100 vb=0.2 a=100'
        >>> Scene(fb=[[0, 50], [0.5, 200]], duration=0.5).held_bow() is None
        True
        """
        if self.pitch_varies:
            return None
        if not self.varying:
            return self
        end = self.duration
        t = np.union1d(np.concatenate([controls.breakpoints(c)[0] for c in (self.fb, self.vb)]), [0.0, end])
        t = t[(t >= 0) & (t <= end)]
        fb, vb = self.fb_at(t), self.vb_at(t)
        # linear between consecutive times of the union: a stretch holds where both ends agree in both curves
        flat = (fb[1:] == fb[:-1]) & (vb[1:] == vb[:-1])
        best = None  # the longest run of flat stretches: (its first time, its last) as indices into t
        for held, run in itertools.groupby(range(len(flat)), key=lambda j: bool(flat[j])):
            run = list(run)
            if held and (best is None or t[run[-1] + 1] - t[run[0]] > t[best[1]] - t[best[0]]):
                best = (run[0], run[-1] + 1)
        if best is None or t[best[1]] - t[best[0]] < HELD_SHARE * end:
            return None
        a, b = best
        attack = a == 0 or (min(fb[0], vb[0]) == 0 and (np.diff(fb[:a + 1]) >= 0).all()
                            and (np.diff(vb[:a + 1]) >= 0).all())
        stop = b == len(t) - 1 or (min(fb[-1], vb[-1]) == 0 and (np.diff(fb[b:]) <= 0).all()
                                   and (np.diff(vb[b:]) <= 0).all())
        return self.replace(fb=float(fb[a]), vb=float(vb[a])) if attack and stop else None

    def replace(self, **changes) -> "Scene":
        """A copy with `changes` (fields by name) applied and checked again.

        Examples
        --------
        >>> Scene().replace(f0=220.0).f0
        220.0
        """
        return dataclasses.replace(self, **changes)

    def after(self, t0: float, **changes) -> "Scene":
        """The rest of the scene from t0 s on (its curves shifted so that t0 is 0), with `changes` applied.

        Examples
        --------
        >>> Scene(fb=[[0, 50], [0.5, 200]], duration=0.5).after(0.25, duration=0.25).describe()
        'fb=125@0,200@0.25 f0=100 vb=0.2 a=100'
        """
        return self.replace(fb=controls.after(self.fb, t0), vb=controls.after(self.vb, t0),
                            f0=controls.after(self.f0, t0), **changes)

    def to_dict(self) -> dict:
        """Plain data (curves as lists of [t, value]): for JSON, TOML and WAV metadata; `from_dict` reads it back.

        Examples
        --------
        >>> Scene(fb=[[0, 50], [0.5, 200]], duration=0.5).to_dict()["fb"]
        [[0.0, 50.0], [0.5, 200.0]]
        """
        return {f.name: (v.to_list() if isinstance(v, Curve) else v)
                for f in dataclasses.fields(self) for v in [getattr(self, f.name)]}

    def describe(self) -> str:
        """The scene's bow in one phrase, for messages and table titles."""
        g = lambda v: str(v) if isinstance(v, Curve) else f"{v:g}"  # noqa: E731
        return f"fb={g(self.fb)} f0={g(self.f0)} vb={g(self.vb)} a={self.a:g}"

    @classmethod
    def from_dict(cls, d: dict) -> "Scene":
        """A Scene from plain data (what `to_dict` writes, or a subset of the fields).

        Parameters
        ----------
        d : dict
            Field names to values (curves as lists of [t, value]).

        Returns
        -------
        Scene

        Raises
        ------
        SceneError
            An unknown field, or a value the constructor refuses.

        Examples
        --------
        >>> Scene.from_dict({"f0": 220.0, "fb": [[0, 50], [1, 200]]}) == Scene(f0=220.0, fb=[[0, 50], [1, 200]])
        True
        """
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise SceneError(f"unknown scene field(s): {', '.join(sorted(unknown))} (known: {', '.join(sorted(names))})")
        return cls(**d)


def list_presets() -> list[str]:
    """The shipped presets' names (presets/*.toml), sorted.

    Examples
    --------
    >>> "paper-fb100" in list_presets()
    True
    """
    return sorted(p.stem for p in PRESET_DIR.glob("*.toml"))


def load_preset(name: str) -> dict:
    """The scene fields a preset sets (a dict, so CLI flags can override them before validation).

    Parameters
    ----------
    name : str
        A preset's name (`list_presets`), never a path.

    Returns
    -------
    dict
        Its fields, without its description; a preset may give pitch and beta instead of f0 and fb
        (`bowsynth.music.request.make_scene` reads those).

    Raises
    ------
    UsageError
        An unknown preset.

    Examples
    --------
    >>> fields = load_preset("paper-fb100")
    >>> fields
    {'f0': 100.0, 'fb': 100.0, 'vb': 0.2, 'a': 100.0, 'duration': 1.0}
    >>> Scene(**{**fields, "duration": 0.2}).n_samples
    8820
    """
    path = PRESET_DIR / f"{name}.toml"
    # a preset is a name, never a path: "../x" or "./bad.toml" must not reach a file outside the presets
    if not isinstance(name, str) or name not in list_presets() or not path.is_file():
        raise UsageError(f"unknown preset {name!r}; known presets: {', '.join(list_presets()) or 'none'}")
    with path.open("rb") as fh:
        data = tomllib.load(fh)
    data.pop("description", None)
    return data


def preset_description(name: str) -> str:
    """The one-line description a preset's file gives (empty where it has none).

    Examples
    --------
    >>> preset_description("paper-fb100")
    "The DAFx25 paper's F_B = 100 case (f0 100 Hz, v_B 0.2 m/s, a 100)"
    """
    with (PRESET_DIR / f"{name}.toml").open("rb") as fh:
        return tomllib.load(fh).get("description", "")


