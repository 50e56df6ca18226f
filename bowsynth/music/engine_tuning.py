"""The sounding ratio of the engine that plays a note: the FDM at its rate and oversampling (its dispersion included),
or an operator model (its own pitch, measured once per model and bow and cached), so a note asked at a pitch sounds
there whichever engine plays it. The truth's ratio and the solve for f0 are in `tuning`."""

from __future__ import annotations

from .. import physics
from ..errors import DomainError, UsageError
from ..scene import Scene
from .tuning import SilentNoteError, _measure_ratio, engine_ratio, sounding_ratio


def fdm_measured_ratio(beta: float, vb: float, a: float, f0: float, rate: float) -> float:
    """The FDM's own sounding ratio at this bow with its step at `rate` (sample rate x oversampling): measured once,
    cached in the process and on disk like sounding_ratio. SilentNoteError where the scheme settles on no period."""
    k = physics.dtau(f0, rate)
    return engine_ratio(f"fdm {k!r}", beta, vb, a, lambda: _measure_ratio(beta, vb, a, k=k).r)


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


RATIO_F0 = 100.0  # the rate a model's ratio is measured at: its window chain does not depend on f0, only the samples
RATIO_PERIODS = 300  # sounding periods measured after the truth's settling time


def operator_ratio(model):
    """The sounding ratio of a trained operator, as `pitch.tune(ratio=...)` takes it: the model rolled out from rest
    at the bow until the truth's settling time plus RATIO_PERIODS periods, its pitch over those periods. A model's
    window chain depends on (beta, v_B) only, so one measurement per model and bow serves every pitch (cached on disk
    with the model's id)."""
    from ..analysis.metrics import f0_estimate
    from ..engines.operator.choose import as_model
    from ..engines.operator.engine import render_operator

    m = as_model(model)

    def ratio(beta: float, vb: float, a: float, f0: float) -> float:
        def measure():
            truth = sounding_ratio(beta, vb, a)
            seconds = min((truth.settle_periods + RATIO_PERIODS / truth.r) / RATIO_F0, 60.0)
            sc = Scene(f0=RATIO_F0, fb=beta * physics.omega(RATIO_F0), vb=vb, a=a, duration=seconds)
            r = render_operator(sc, model=m)
            tail = r.q[-int(RATIO_PERIODS / (truth.r * RATIO_F0) * sc.sample_rate):]
            return f0_estimate(tail, sc.sample_rate, tail=1.0) / RATIO_F0
        return engine_ratio(f"operator{RATIO_PERIODS} {m.id}", beta, vb, a, measure)
    return ratio


def ratio_for_engine(scene: Scene, engine: str = "operator", model=None, oversample: int = 1, models=None):
    """(ratio, what) for `make_scene(pitch=..., ratio=ratio)`: the sounding ratio of the engine that will play the
    scene (the FDM at its rate and oversampling, dispersion included; or the operator model that covers it, its own
    pitch), so that the asked note sounds there whichever engine plays. (None, why) when no model covers the scene:
    the note is then tuned with the truth's ratio (what compare scores against). models: those to choose among
    (default: available_models(), looked up again on each call)."""
    if str(getattr(engine, "value", engine)) == "fdm":
        from ..engines.fdm import check_oversample

        os_ = check_oversample(scene, oversample, warn=False)
        return fdm_ratio(scene.sample_rate, os_), f"the FDM at x{os_}"
    m, why = _playing_model(scene, model, models)
    if m is None:
        return None, why

    def ratio(beta, vb, a, f0):
        try:
            return operator_ratio(m)(beta, vb, a, f0)
        except DomainError:  # the model cannot play the bow the solve tries: its ratio is unknown there
            return sounding_ratio(beta, vb, a).r
    return ratio, f"model {m.id}"


def _playing_model(scene: Scene, model=None, models=None):
    """(the operator model that plays the scene: the one given, else find_model's pick among `models`; None) or
    (None, why) where that model does not cover it or none does."""
    from ..engines.operator.choose import as_model, find_model

    try:
        m = find_model(scene, models) if model is None else as_model(model)
    except DomainError as e:
        return None, str(e).split(";")[0]
    if not m.covers(scene):
        return None, f"model {m.id} does not cover the scene"
    return m, None


def own_ratio(model, beta: float, vb: float, a: float, f0: float = RATIO_F0) -> float | None:
    """The model's own sounding ratio at this bow (operator_ratio, cached), never the truth's; None where the model
    cannot hold the bow from rest for the measurement."""
    try:
        return operator_ratio(model)(beta, vb, a, f0)
    except (DomainError, SilentNoteError):
        return None


def operator_sounding(scene: Scene, model=None, models=None, held: Scene | None = None) -> float | None:
    """The frequency (Hz) the operator model that plays `scene` (given, or the covering one among `models`) sounds at
    with its held bow (held's, where the scene's bow moves only to stop: a score's note): f0 times the model's own
    ratio (operator_ratio, cached). The windows of its voice are locked to that period
    (engines.operator.windows.locked_window). None where there is no such number: a moving bow or pitch, no covering
    model, or a bow the model cannot hold from rest for the measurement."""
    held = scene if held is None else held
    if held.varying or scene.pitch_varies:
        return None
    m, _ = _playing_model(scene, model, models)
    if m is None:
        return None
    # the model's own pitch, never the truth's: a window clock at the truth's period pulls the note to it; where it
    # cannot hold the bow for the measurement, free windows
    r = own_ratio(m, held.beta, held.vb, held.a, held.f0)
    return None if r is None else held.f0 * r


WINDOWS = ("locked", "free")  # how an operator voice's windows lie against its note (api.render's `windows`)


def check_windows(windows: str) -> str:
    if windows not in WINDOWS:
        raise UsageError(f"--windows must be {' or '.join(WINDOWS)}, got {windows!r}")
    return windows


def sounding_for(scene, windows: str = "free", model=None, held=None):
    """What `engines.render(sounding=...)` takes for `api.render(windows=...)`: None for free windows; else per scene
    the frequency its playing model sounds at (operator_sounding; None where unknown: that voice rolls in free
    windows). scene: one, or a list; held: the scene (or list) whose held bow each note sounds with, where it is not
    the scene itself (a score's note: its sustain, while the whole note with its bow stop renders)."""
    check_windows(windows)
    if windows == "free":
        return None
    many = isinstance(scene, (list, tuple))
    scenes = list(scene) if many else [scene]
    helds = scenes if held is None else (list(held) if many else [held])
    pool = None
    if model is None:
        from ..engines.operator.choose import available_models

        pool = available_models()  # the model directories looked at once for all the scenes
    out = [operator_sounding(sc, model, models=pool, held=h) for sc, h in zip(scenes, helds)]
    return out if many else out[0]
