"""The sounding ratio of the engine that plays a note: the FDM at its rate and oversampling (its dispersion included),
or an operator model: in free windows and in windows locked to its note its own pitch (measured once per model and
bow and cached), in windows locked to the physics' period that period where the model holds it (`lock_ratio`). So a
note asked at a pitch sounds there whichever engine plays it. The operator's notes take the physics' period from the
shipped map (`ratio_map`), never from the reference; the solve for f0 is in `tuning`."""

from __future__ import annotations

import math

from .. import physics
from ..engines.operator.windows import lock_at
from ..errors import DomainError, UsageError
from ..io.cache import DiskTable
from ..scene import Scene
from .model_ratio import lock_ratio, operator_ratio, own_ratio
from .engine_ratio import engine_ratio, ratio_key
from .ratio_map import map_ratio, physics_ratio
from .tuning import SilentNoteError, measure_ratio, sounding_ratio


def fdm_measured_ratio(beta: float, vb: float, a: float, f0: float, rate: float) -> float:
    """The FDM's own sounding ratio at this bow with its step at `rate` (sample rate x oversampling): measured once,
    cached in the process and on disk like sounding_ratio. SilentNoteError where the scheme settles on no period."""
    k = physics.dtau(f0, rate)
    return engine_ratio(f"fdm {k!r}", beta, vb, a, lambda: measure_ratio(beta, vb, a, k=k).r)


def fdm_ratio(sample_rate: float, oversample: int = 1):
    """The sounding ratio of the FDM at this rate, as `tune(ratio=...)` takes it: the scheme's own, at its step in tau
    k w = 2 pi f0 / (sample_rate oversample), dispersion included (about (w k)^2 / 24: +2.2 cents at A5 at 44.1 kHz
    if tuned with the truth's ratio)."""
    def ratio(beta: float, vb: float, a: float, f0: float) -> float:
        try:
            return fdm_measured_ratio(beta, vb, a, f0, sample_rate * oversample)
        except SilentNoteError:
            # at so coarse a step the scheme can settle on no period where the truth does (A5 at F_B 1000, v_B 0.15:
            # ~43 samples a period): its pitch is undefined there, so the truth's ratio tunes the note
            return sounding_ratio(beta, vb, a).r
    return ratio


def held_lock(model, windows: str, beta: float, vb: float, a: float, f0: float | None = None,
              frames: bool = True) -> float | None:
    """The sounding ratio a held note's windows lock to in these windows: 'locked' the model's own (own_ratio; a
    clock at the physics' period would pull the note there: see lock_ratio), 'physics' lock_ratio's (the physics'
    period where the model holds it, else its own), 'auto' auto_lock's for a note at f0 (None: for every pitch;
    `frames`: a note heard frame by frame); None where they lock to nothing (free windows, or no period known)."""
    if windows == "auto":
        return auto_lock(model, beta, vb, a, f0, frames)
    how = {"locked": own_ratio, "physics": lock_ratio}.get(windows)
    return None if how is None else how(model, beta, vb, a)


# --windows auto: free windows keep a model's harmonics (they are the windows it was trained in), a lock to the
# physics' period keeps its pitch. Each is judged by the operator against itself and the shipped map, never against the
# reference: free windows by how far the model's own free cycle lies from the map's period over the long run, and for
# a note heard frame by frame (an attack or a bow stop, scored per 100 ms frame as a gesture is) in its median frame
# too (a cycle that wanders frame to frame is heard so there), the lock by how far it moves the note's harmonics from
# the free note's (a lock puts the network's error on them). Each error over its worst-case target (1 cent, 1 dB); the
# smaller plays. Free windows within FREE_CENTS of the map's period play without the lock's measurement.
# A held note is heard whole (its pitch over its steady part): a free cycle whose long-run period lies within
# FREE_CENTS of the map's wanders frame to frame about the right pitch, and plays free (at 384 Hz, F_B / w 0.52, v_B
# 0.085: 0.05 cents over the long run, 2 cents a frame; free windows play 0.78 dB / 0.04 cents from the x100 FDM, the
# lock 2.06 dB / 0.003 cents). One whose long-run pitch misses is judged by its frames too: its wander says the model
# does not hold the cycle (at 141 Hz, F_B / w 0.58, v_B 0.107: 0.89 cents long-run, 3.3 a frame; free 1.63 dB / -0.49
# cents, the lock 0.97 dB / 0.002 cents). benchmarks/auto_rule.py prints these measurements beside the truth's.
FREE_CENTS = 0.2
TARGET_CENTS, TARGET_DB = 1.0, 1.0
NOTE_SECONDS = 2.0  # the held note each measures: from rest until the map's settling time and this much more
FRAME_F0 = 150.0  # the pitch whose frames a choice for every pitch is made by (the live engine's)
_choices = DiskTable("auto-windows", f"truth-free-4/{FRAME_F0!r}/{FREE_CENTS!r}/{TARGET_CENTS!r}/{TARGET_DB!r}/"
                                     f"{NOTE_SECONDS!r}")


def auto_lock(model, beta: float, vb: float, a: float, f0: float | None = None, frames: bool = True):
    """--windows auto, a render's default: None (free windows) or the Lock a held note's windows take, for a note at
    f0 (its frames: 100 ms at f0 hold as many periods as frames of 0.1 f0 / 100 s of a note at f0 100; None: as at
    FRAME_F0, the live engine's one choice for every pitch). frames: the note is heard frame by frame (an attack or a
    bow stop), so its free cycle's median frame counts; a held note (False) is heard whole.

    A point model plays free windows (the cycle it was trained and validated on at its one bow: the paper's three
    scenes' NMSE(p) over 1 s 4e-8 / 1e-6 / 9e-7 free). A range model plays the lock (lock_ratio: the map's period,
    where the model holds it) where the lock's harmonic shift, over 1 dB, is smaller than the free cycle's pitch error,
    over 1 cent; else free windows. Measured once per model and bow (notes of the operator at f0 100), cached."""
    from ..metrics import cents
    from ..engines.operator.choose import as_model
    from ..engines.operator.windows import Lock

    m = as_model(model)
    if not m.domain.is_range:
        return None
    lock = lock_ratio(m, beta, vb, a)
    if not isinstance(lock, Lock):
        return None
    frame = round(0.1 * (FRAME_F0 if f0 is None else f0) / 100.0, 3)  # at f0 100: a 100 ms frame at the note's f0
    key = f"{ratio_key(m.key, beta, vb, a)} {frame!r}" if frames else f"{ratio_key(m.key, beta, vb, a)} whole"
    hit = _choices.get(key)
    if isinstance(hit, dict) and isinstance(hit.get("lock"), bool):
        return lock if hit["lock"] else None
    own = own_ratio(m, beta, vb, a)
    free_score = abs(cents(own, float(lock))) / TARGET_CENTS if own else math.inf
    free = None  # the free note: rendered where its frames count (held: where its long-run pitch already misses)
    if frames or free_score > FREE_CENTS / TARGET_CENTS:
        sc, free = _held_note(m, beta, vb, a, None)
        if free is not None:
            free_score = max(free_score, frame_wander(free.q, sc.sample_rate, sc.f0 * float(lock), frame)
                             / TARGET_CENTS)
    use = False
    if free_score > FREE_CENTS / TARGET_CENTS:
        use = lock_harmonic_shift(m, beta, vb, a, lock, free) / TARGET_DB < free_score
    _choices.put(key, {"lock": bool(use)})
    return lock if use else None


def _held_note(model, beta: float, vb: float, a: float, lock):
    """(scene, render): a held note of the model from rest at f0 100 until the map's settling time and NOTE_SECONDS
    more, in free windows (lock None) or locked; render None where the model cannot play it."""
    from ..engines.operator.engine import render_operator
    from ..engines.operator.windows import Lock
    from .model_ratio import RATIO_F0

    settle = physics_ratio(beta, vb, a).settle_seconds(RATIO_F0)
    sc = Scene(f0=RATIO_F0, fb=beta * physics.omega(RATIO_F0), vb=vb, a=a, duration=min(settle + NOTE_SECONDS, 30.0))
    try:
        return sc, render_operator(sc, model=model, sounding=None if lock is None else
                                   Lock(RATIO_F0 * float(lock), lock.more))
    except DomainError:
        return sc, None


def frame_wander(x, sample_rate: float, hz: float, frame: float, seconds: float = 1.0) -> float:
    """The median |cents| from `hz` of the pitch of each `frame`-second frame of x's last `seconds` (frames holding
    at least three periods; 0 where none does: no pitch a frame is heard)."""
    from ..metrics import cents, f0_estimate

    n = int(frame * sample_rate)
    tail = x[-max(int(seconds * sample_rate), n):]
    if n * hz / sample_rate < 3:
        return 0.0
    off = [abs(cents(f0_estimate(tail[i:i + n], sample_rate, tail=1.0), hz)) for i in range(0, len(tail) - n + 1, n)]
    off = [c for c in off if math.isfinite(c)]
    return float(sorted(off)[len(off) // 2]) if off else math.inf


def lock_harmonic_shift(model, beta: float, vb: float, a: float, lock, free) -> float:
    """The most a lock moves a held note's harmonics 1-10 (dB) from the same note in free windows (`free`, its render
    by _held_note; None where it failed to play), each fitted at its own pitch over its last second. inf where either
    note fails to play."""
    from ..metrics import listener_errors

    if free is None:
        return math.inf
    sc, locked = _held_note(model, beta, vb, a, lock)
    if locked is None:
        return math.inf
    e = listener_errors(locked.p, free.p, sc.sample_rate)
    return float(e["harm_db_max"]) if math.isfinite(e["harm_db_max"]) else math.inf


def ratio_for_engine(scene: Scene, engine: str = "operator", model=None, oversample: int = 1, models=None,
                     windows: str | None = None, by_pitch: bool = True, heard: bool = False):
    """(ratio, what) for `make_scene(pitch=..., ratio=ratio)`: the sounding ratio of the engine that will play the
    scene (the FDM at its rate and oversampling, dispersion included; or the operator model that covers it: its own
    pitch, or in windows locked to the physics the period it holds there), so that the asked note sounds there
    whichever engine plays. When no model covers the scene, the physics' ratio from the shipped map, with why. models:
    those to choose among (default: available_models(), looked up again on each call). by_pitch: kept for callers
    (a model's windows do not depend on the note's f0). heard: with no model given, the model `pick.heard_pick`
    chooses (api.render's: it plays that one); else the renderer's static pick (a score's, the live engine's). The
    operator's ratios carry `physics`, the shipped map, which `tune` solves from: no reference runs."""
    if str(getattr(engine, "value", engine)) == "fdm":
        from ..engines.fdm import check_oversample

        os_ = check_oversample(scene, oversample, warn=False)
        return fdm_ratio(scene.sample_rate, os_), f"the FDM at x{os_}"
    windows = check_windows(windows)
    m, why = _playing_model(scene, model, models, heard)
    if m is None:
        return map_ratio, f"the physics' pitch map ({why})"  # refused, or played by the FDM (--fallback fdm)
    held = windows in ("physics", "auto") and scene.held_bow() is not None  # else free

    def ratio(beta, vb, a, f0):
        try:
            r = held_lock(m, windows, beta, vb, a, f0 if by_pitch else None, scene.varying) if held else None
            if r is None and not (held and windows == "physics"):  # free windows, or auto's free ones: its own
                r = operator_ratio(m)(beta, vb, a, f0)
        except DomainError:  # the model cannot play the bow the solve tries: its ratio is unknown there
            r = None
        return physics_ratio(beta, vb, a).r if r is None else r
    ratio.physics = physics_ratio
    return ratio, f"model {m.id}" + (f" in {windows} windows" if held else "")


def _playing_model(scene: Scene, model=None, models=None, heard: bool = False):
    """(the operator model that plays the scene: the one given, else find_model's pick among `models`, or with
    `heard` pick.heard_pick's; None) or (None, why) where that model does not cover it or none does."""
    from ..engines.operator.choose import as_model, find_model
    from .pick import heard_pick

    try:
        if model is None and heard:
            m = heard_pick(scene, models) or find_model(scene, models)  # none covers it: find_model says why
        else:
            m = find_model(scene, models) if model is None else as_model(model)
    except DomainError as e:
        return None, str(e).split(";")[0]
    if not m.covers(scene):
        return None, f"model {m.id} does not cover the scene"
    return m, None


def operator_sounding(scene: Scene, model=None, models=None, held: Scene | None = None,
                      windows: str = "locked") -> float | None:
    """The frequency (Hz) a held note played by an operator model (given, or the covering one among `models`) is
    locked to, at its held bow (Scene.held_bow of `held`, else of the scene: a score's note gives its sustain): f0
    times the ratio held_lock gives for the windows (the model's own, or the physics' where the model holds it). The
    windows of its voice divide that period (engines.operator.windows.locked_window). None where there is no such
    number: a gesture or a moving pitch, no covering model, or a bow the model cannot hold from rest (or whose
    physics settles on no period)."""
    held = (scene if held is None else held).held_bow()
    if held is None or scene.pitch_varies:
        return None
    m, _ = _playing_model(scene, model, models)
    if m is None and model is None:  # no one model covers it (a stop at the space's edge: a chain of models); the
        m, _ = _playing_model(held, None, models)  # held bow's model locks its own stretches (chain.render_chain)
    if m is None:
        return None
    r = held_lock(m, windows, held.beta, held.vb, held.a, held.f0, scene.varying)
    return lock_at(r, held.f0)


WINDOWS = ("locked", "free", "physics", "auto")  # how an operator voice's windows lie against its note (api.render's)
# A render's default is what a listener hears from one note: the physics' period where the model holds it, else the
# model's free cycle. A score keeps windows locked to each model's own period (a mix's voices fill each other's gaps,
# and a short note does not sound a lock's pull-in), the live engine free ones (its windows are fixed when a voice
# starts).
RENDER_WINDOWS, SCORE_WINDOWS, LIVE_WINDOWS = "auto", "locked", "free"


def check_windows(windows: str | None, default: str = RENDER_WINDOWS) -> str:
    """The windows' name, `default` for None; a UsageError naming the choices for anything else."""
    windows = default if windows is None else windows
    if windows not in WINDOWS:
        raise UsageError(f"--windows must be {', '.join(WINDOWS[:-1])} or {WINDOWS[-1]}, got {windows!r}")
    return windows


def sounding_for(scene, windows: str | None = None, model=None, held=None):
    """What `engines.render(sounding=...)` takes for `api.render(windows=...)`: None for free windows; else per scene
    the frequency its windows are locked to (operator_sounding; None where unknown: that voice rolls in free
    windows). scene: one, or a list; held: the scene (or list) whose held bow each note sounds with (a score's note:
    its sustain, while the whole note with its bow stop renders); None: each scene's Scene.held_bow (a note with an
    attack or a stop locks to the bow it holds; a gesture rolls free). windows None: RENDER_WINDOWS."""
    windows = check_windows(windows)
    if windows == "free":
        return None
    many = isinstance(scene, (list, tuple))
    scenes = list(scene) if many else [scene]
    helds = [None] * len(scenes) if held is None else (list(held) if many else [held])
    pool = None
    if model is None:
        from ..engines.operator.choose import available_models

        pool = available_models()  # the model directories looked at once for all the scenes
    out = [operator_sounding(sc, model, models=pool, held=h, windows=windows) for sc, h in zip(scenes, helds)]
    return out if many else out[0]
