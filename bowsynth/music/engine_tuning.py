"""The sounding ratio of the engine that plays a note: the FDM at its rate and oversampling (its dispersion included),
or an operator model: in free windows and in windows locked to its note its own pitch (measured once per model and
bow and cached), in windows locked to the physics' period that period where the model holds it (`lock_ratio`). So a
note asked at a pitch sounds there whichever engine plays it. The truth's ratio and the solve for f0 are in `tuning`."""

from __future__ import annotations

import math

from .. import physics
from ..engines.operator.windows import Lock, lock_more
from ..errors import DomainError, UsageError
from ..io.cache import DiskTable
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


def operator_ratio(model, locked: bool = False, more: int = 0):
    """The sounding ratio of a trained operator, as `pitch.tune(ratio=...)` takes it: the model rolled out from rest
    at the bow until the truth's settling time plus RATIO_PERIODS periods, its pitch over those periods; locked: in
    windows locked to the physics' period (lock_ratio), `more` windows a period beyond the fewest that fill it. A
    model's window chain depends on (beta, v_B) only, so one measurement per model and bow serves every pitch (cached
    on disk with the model's id)."""
    from ..analysis.metrics import f0_estimate
    from ..engines.operator.choose import as_model
    from ..engines.operator.engine import render_operator

    m = as_model(model)

    def ratio(beta: float, vb: float, a: float, f0: float) -> float:
        def measure():
            truth = sounding_ratio(beta, vb, a)
            # a lock pulls the cycle in over tens to hundreds of periods (stick-slow at F_B / w 1.46, v_B 0.152: +0.2
            # cents over the first 300, +0.0008 over the next): measured after as many again
            periods = RATIO_PERIODS * (2 if locked else 1)
            seconds = min((truth.settle_periods + periods / truth.r) / RATIO_F0, 60.0)
            sc = Scene(f0=RATIO_F0, fb=beta * physics.omega(RATIO_F0), vb=vb, a=a, duration=seconds)
            r = render_operator(sc, model=m, sounding=Lock(RATIO_F0 * truth.r, more) if locked else None)
            tail = r.q[-int(RATIO_PERIODS / (truth.r * RATIO_F0) * sc.sample_rate):]
            return f0_estimate(tail, sc.sample_rate, tail=1.0) / RATIO_F0
        how = f"-locked2x{f'+{more}' if more else ''}" if locked else ""
        return engine_ratio(f"operator{how}{RATIO_PERIODS} {m.id}", beta, vb, a, measure)
    return ratio


# Windows locked to the physics (--windows physics) divide the period of the physics' limit cycle at the held bow (the
# truth's sounding ratio, `tuning.sounding_ratio`: the reference integration `--pitch` has always run, Richardson-
# extrapolated, once per bow, 30-100 ms, cached on disk), where the model holds that period. Such a clock pulls the
# operator's cycle onto it, as an oscillator is pulled within its locking range, and the network plays the wave within
# each period. Measured (session 21, `benchmarks/listener.py --windows physics`, the 12 held-out stick-slip bows):
# 0.0005 / 0.006 cents (median / worst) against 1.33 / 4.32 with windows locked to each model's own period, harmonics
# 0.028 / 1.12 dB against 0.030 / 0.81, onsets 12/12 both; the 12 soft bows 0.009 / 0.11 cents against 0.072 / 0.36. Not
# every model holds it: velocity-loud's C3 at velocity 112 came out 0.92 cents off the physics' pitch, a barely trained
# test model left its states. So the lock is measured once per model and bow (cached) and taken where the model's pitch
# in it is within LOCK_HOLDS_CENTS of the physics'; elsewhere the windows lock to the model's own period (--windows
# locked), the note tuned with that. The pull-in has a price: a short note sounds it. The chorale's mix
# (`benchmarks/chorale.py`, notes of 0.4-1.6 s) came out 1.12 dB from the FDM's (60 dB floor) against 0.88 with its
# windows locked to each model's own period, so a score keeps those (--windows locked, its default).
LOCK_HOLDS_CENTS = 0.05
# Windows a period beyond the fewest, tried in turn: windows of nearly T do not always pull the cycle (stick-stops at
# F_B / w 0.719, v_B 0.08: 17 windows of 0.994 T leave it 5.3-5.8 cents off, 18 hold it within 0.01; windows.Lock)
LOCK_MORE = (0, 1)


def lock_ratio(model, beta: float, vb: float, a: float) -> float | None:
    """The sounding ratio a held note's locked windows take with this model: the physics' where the model holds it
    (a Lock, with the windows a period it holds it in: the fewest that fill the period, else one more), else the
    model's own (own_ratio); None where neither is known (the physics settles on no period: a bow at or below v_B =
    1 / sqrt(2a); or the model cannot hold the bow from rest for the measurement)."""
    try:
        truth = sounding_ratio(beta, vb, a).r
    except SilentNoteError:
        return None
    for more in LOCK_MORE:
        try:
            held = operator_ratio(model, locked=True, more=more)(beta, vb, a, RATIO_F0)
            if abs(1200.0 * math.log2(held / truth)) <= LOCK_HOLDS_CENTS:
                return Lock(truth, more)
        except (DomainError, SilentNoteError):
            pass
    return own_ratio(model, beta, vb, a)


# --windows auto, per model and held bow: the windows that sound truest at f0 100 against the truth, free or locked to
# the physics' period (where the model holds it), each note scored by its worse error as a share of the issue's worst-
# case target: max(harmonics 1-10's worst dB / 1 dB, |cents| / 1 cent, |onset error| / max(5 ms, 2 % of the truth's
# onset)). Why measured: neither mode is truest
# everywhere. Free windows keep the harmonics (a lock of two windows a period, a soft model's, moves the network's
# error onto them: held-out soft bows 1.1-2.1 dB worst in physics windows, 0.57-0.97 free), a lock keeps the pitch
# (the stick-slip tiles' own cycles are 0.5-4 cents off; locked 0.006). Session 21's rule, free where the model's
# own pitch is within 0.2 cent, else the lock, missed the harmonics' worst on both seeds' soft bows (1.11 and 2.12 dB)
# and loosened to 0.8 cent missed the pitch (1.16 cents, median 0.23). The scores at f0 100 mostly predict those at
# the note's pitch: on 24 held-out bows at 66-408 Hz the harmonics' worst in either mode moved 0.015 dB median, 0.15
# at the 90th percentile, 0.78 at a 66.5 Hz note (session 23); at soft-range's box edge (v_B 0.28) they did not. The
# truth is an FDM at x AUTO_OVERSAMPLE (harmonic levels to 1e-3 dB; the pitch is the sounding ratio's), once per bow;
# the choice is kept on disk per model and bow.
# Why the onset, and a note as long as it takes to speak (session 27): at a light fast bow a note grows for seconds
# (F_B / w 0.02, v_B 0.28: its onset 8.2 s at f0 100), so 2 s from rest at f0 100 were played by the flow at rest and
# scored nothing of the model; the pitch alone then chose the lock, and at 440 Hz that lock moved the onset 37 ms and
# the harmonics 1.04 dB where free windows are 2.4 ms and 0.15 dB off (`corner-long`).
# Why per pitch, over a ladder of pitches (session 29): a lock pulls a note in over tens of periods, and the pull-in
# can slip. stick-halt at F_B / w 1.565, v_B 0.181 (sounding at 0.286 f0) holds the physics' period from period 80
# on, but its periods 60-80 are 2.2 cents sharp, so a 2 s note at 141 Hz, whose last second is periods 40-81, came
# out 1.14 cents sharp where the note at f0 100 (periods 29-57) and the ratio after 600 periods were within 0.07. A
# model's window chain does not depend on f0, only which of its periods a note's last second holds: so each mode's
# note is played at f0 100 long enough to hold the last second of a note AUTO_SECONDS past its speaking at each pitch
# of PITCH_LADDER (as many periods as there), and a note is scored by its pitch error at its own f0 (the ladder's
# pitches around it) and the cached ratio's. Scored by the worst over the ladder instead, a transient at low pitches
# outweighed a lasting error: stick-slow at 1.457 / 0.152 slips 3.1 cents in physics windows over periods 20-40 only,
# is 2.5 cents sharp free everywhere, and a 344 Hz note went free, 3.0 cents sharp, where physics plays it within 0.01.
AUTO_SECONDS = 2.0  # from rest; scored over the last second, as benchmarks/listener.py scores a note
AUTO_MAX_SECONDS = 30.0  # a bow that takes longer than this to speak is scored at this length
AUTO_OVERSAMPLE = 10
PITCH_LADDER = (65.0, 82.0, 103.0, 130.0, 164.0, 206.0, 260.0, 327.0, 412.0, 519.0, 654.0, 880.0)  # the span
LADDER_MAX_SECONDS = 60.0  # at f0 100: the longest note the ladder plays (a bow that speaks after ~25 s at 880 Hz)
TARGET_HARMONIC_DB, TARGET_CENTS = 1.0, 1.0  # the worst-case targets, each error's unit in the score
_choices = DiskTable("auto-windows", f"3/{AUTO_SECONDS!r}/{AUTO_MAX_SECONDS!r}/{AUTO_OVERSAMPLE}/"
                                     f"{TARGET_HARMONIC_DB!r}/{TARGET_CENTS!r}/{PITCH_LADDER!r}/{LADDER_MAX_SECONDS!r}")


def ladder_spans(sc: Scene) -> list[tuple[float, float]]:
    """(start, end) in seconds of the held note `sc` (at its f0) that hold the last second of a note from rest
    lasting AUTO_SECONDS past its speaking (onset.settled_seconds, at most AUTO_MAX_SECONDS) at each pitch of
    PITCH_LADDER: the same periods, since a window chain does not depend on f0. Spans past LADDER_MAX_SECONDS are
    left out."""
    from ..engines.operator.onset import settled_seconds

    spans = []
    for f in PITCH_LADDER:
        at = sc.replace(f0=f, fb=sc.beta * physics.omega(f))
        end = settled_seconds(at, AUTO_SECONDS, AUTO_MAX_SECONDS) * f / sc.f0
        if end <= LADDER_MAX_SECONDS:
            spans.append((end - f / sc.f0, end))
    return spans


def mode_errors(model, beta: float, vb: float, a: float, lock) -> dict:
    """Per mode ('free', 'physics') what a held note from rest at f0 100 measures against the truth, each error over
    its worst-case target (None where the mode does not play): 'base' the worse of the harmonics' worst (TARGET_
    HARMONIC_DB) and the onset (its limit) from a note lasting AUTO_SECONDS past the time the physics speaks
    (onset.settled_seconds) against the FDM at x AUTO_OVERSAMPLE, 'cents' the cached ratio's (own_ratio's, the
    lock's: where a long note ends up), 'ladder' the note's pitch over each ladder_spans span (a 2 s note's last
    second at each pitch of PITCH_LADDER), each over TARGET_CENTS."""
    from ..analysis.metrics import listener_errors, onset_limit_ms
    from ..engines.fdm import render_fdm
    from ..engines.operator.choose import as_model
    from ..engines.operator.engine import render_operator
    from ..engines.operator.onset import settled_seconds

    m = as_model(model)
    truth_r = sounding_ratio(beta, vb, a).r
    sc = Scene(f0=RATIO_F0, fb=beta * physics.omega(RATIO_F0), vb=vb, a=a, duration=1.0)
    sc = sc.replace(duration=settled_seconds(sc, AUTO_SECONDS, AUTO_MAX_SECONDS))
    truth = render_fdm(sc, oversample=AUTO_OVERSAMPLE)
    spans = ladder_spans(sc)
    long = sc.replace(duration=max([sc.duration] + [b for _, b in spans]))
    own = own_ratio(m, beta, vb, a)
    held = operator_ratio(m, locked=True, more=lock_more(lock))(beta, vb, a, RATIO_F0)
    out = {}
    locked = Lock(RATIO_F0 * float(lock), lock_more(lock))
    for mode, ratio, sounding in (("free", own, None), ("physics", held, locked)):
        try:
            r = render_operator(long, model=m, sounding=sounding)
        except (DomainError, SilentNoteError):
            out[mode] = None
            continue
        e = listener_errors(r.p[:sc.n_samples], truth.p, sc.sample_rate)
        harm = e["harm_db_max"]
        harm = math.inf if harm is None or not math.isfinite(harm) else harm
        ref_ms, err_ms = e["onset_ref_ms"], e["onset_err_ms"]
        # no onset in the truth: nothing to score; one in the truth and none in the note: the worst
        onset = 0.0 if not math.isfinite(ref_ms) else (abs(err_ms) / onset_limit_ms(ref_ms) if math.isfinite(err_ms)
                                                       else math.inf)
        cents = math.inf if ratio is None else abs(1200.0 * math.log2(ratio / truth_r))
        ladder = _span_cents(r.p, truth.p, spans, sc.sample_rate, RATIO_F0 * truth_r)
        out[mode] = {"base": _finite(max(harm / TARGET_HARMONIC_DB, onset)), "cents": _finite(cents / TARGET_CENTS),
                     "ladder": [_finite(c / TARGET_CENTS) for c in ladder]}
    return out


def _finite(x: float) -> float:
    """A score as the disk cache keeps it (JSON has no inf): at most 1e9."""
    return min(float(x), 1e9)


def mode_score(errors: dict | None, f0: float | None = None) -> float:
    """A mode's score (mode_errors') for a note at f0: the worst of its base, its ratio's cents and its ladder's
    cents at f0 (the worse of the two ladder pitches around it; past the ladder its end); f0 None: the ladder's
    worst (a choice for every pitch: the live engine's, per velocity). inf where the mode does not play."""
    if errors is None:
        return math.inf
    ladder = errors["ladder"]
    pitches = PITCH_LADDER[:len(ladder)]
    if f0 is None or not ladder:
        near = ladder
    else:
        i = sum(1 for f in pitches if f <= f0)  # pitches[:i] lie at or below f0
        near = ladder[max(i - 1, 0):i + 1] if i < len(pitches) else ladder[-1:]
    return max([errors["base"], errors["cents"]] + list(near))


def window_scores(model, beta: float, vb: float, a: float, lock, f0: float | None = RATIO_F0) -> tuple[float, float]:
    """(free, physics): each mode's score (mode_score) for a note at f0, measured once per model and bow (cached)."""
    errors = _mode_errors_cached(model, beta, vb, a, lock)
    return mode_score(errors["free"], f0), mode_score(errors["physics"], f0)


def _mode_errors_cached(model, beta: float, vb: float, a: float, lock) -> dict:
    from ..engines.operator.choose import as_model

    key = f"{as_model(model).id} {beta!r} {vb!r} {a!r}"
    hit = _choices.get(key)
    if not (isinstance(hit, dict) and set(hit) == {"free", "physics"}):
        hit = mode_errors(model, beta, vb, a, lock)
        _choices.put(key, hit)
    return hit


def _span_cents(p, truth_p, spans, sample_rate: float, truth_hz: float) -> list[float]:
    """|cents| of p's pitch over each span (seconds) against the truth's there: its render's where the span lies
    within it, else the physics' sounding frequency (the truth has settled by then); inf where p has no pitch."""
    from ..analysis.metrics import f0_estimate

    out = []
    for a, b in spans:
        i, j = int(a * sample_rate), int(b * sample_rate)
        f = f0_estimate(p[i:j], sample_rate, tail=1.0)
        ref = f0_estimate(truth_p[i:j], sample_rate, tail=1.0) if j <= len(truth_p) else truth_hz
        out.append(abs(1200.0 * math.log2(f / ref)) if f > 0 and ref > 0 else math.inf)
    return out


def auto_lock(model, beta: float, vb: float, a: float, f0: float | None = RATIO_F0) -> float | None:
    """windows 'auto': the physics' sounding ratio (a Lock) where a held note at f0 locks its windows to it, None
    where it plays in free windows (they score at least as well there: window_scores; or a lock the model does not
    hold, or no period known). f0 None: the choice for every pitch (mode_score)."""
    try:
        truth = sounding_ratio(beta, vb, a).r
    except SilentNoteError:
        return None
    lock = lock_ratio(model, beta, vb, a)
    if lock is None or lock != truth:  # the model does not hold the physics' period: its own, in free windows
        return None
    free, locked = window_scores(model, beta, vb, a, lock, f0)
    return lock if locked < free else None


def held_lock(model, windows: str, beta: float, vb: float, a: float, f0: float | None = None) -> float | None:
    """The sounding ratio a held note's windows lock to in these windows: 'locked' the model's own (own_ratio; a
    clock at the physics' period would pull the note there: see lock_ratio), 'physics' lock_ratio's, 'auto'
    auto_lock's for a note at f0 (None: for every pitch); None where they lock to nothing (free windows, or no period
    known)."""
    if windows == "auto":
        return auto_lock(model, beta, vb, a, f0)
    how = {"locked": own_ratio, "physics": lock_ratio}.get(windows)
    return None if how is None else how(model, beta, vb, a)


def ratio_for_engine(scene: Scene, engine: str = "operator", model=None, oversample: int = 1, models=None,
                     windows: str = "free", by_pitch: bool = True):
    """(ratio, what) for `make_scene(pitch=..., ratio=ratio)`: the sounding ratio of the engine that will play the
    scene (the FDM at its rate and oversampling, dispersion included; or the operator model that covers it: its own
    pitch, or in windows locked to the physics the period it holds there), so that the asked note sounds there
    whichever engine plays. (None, why) when no model covers the scene: the note is then tuned with the truth's ratio
    (what compare scores against). models: those to choose among (default: available_models(), looked up again on
    each call). by_pitch: auto windows chosen for the note's f0 (a render's, a score's); False: one choice for every
    pitch (the live engine's, whose windows are fixed per velocity)."""
    if str(getattr(engine, "value", engine)) == "fdm":
        from ..engines.fdm import check_oversample

        os_ = check_oversample(scene, oversample, warn=False)
        return fdm_ratio(scene.sample_rate, os_), f"the FDM at x{os_}"
    m, why = _playing_model(scene, model, models)
    if m is None:
        return None, why
    held = check_windows(windows) in ("physics", "auto") and scene.held_bow() is not None  # else free

    def ratio(beta, vb, a, f0):
        try:
            r = held_lock(m, windows, beta, vb, a, f0 if by_pitch else None) if held else None
            if r is None and not (held and windows == "physics"):  # free windows, or auto's free ones: its own
                r = operator_ratio(m)(beta, vb, a, f0)
        except DomainError:  # the model cannot play the bow the solve tries: its ratio is unknown there
            r = None
        return sounding_ratio(beta, vb, a).r if r is None else r
    return ratio, f"model {m.id}" + (f" in {windows} windows" if held else "")


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
    if m is None:
        return None
    r = held_lock(m, windows, held.beta, held.vb, held.a, held.f0)
    return None if r is None else Lock(held.f0 * r, lock_more(r))


WINDOWS = ("locked", "free", "physics", "auto")  # how an operator voice's windows lie against its note (api.render's)


def check_windows(windows: str) -> str:
    if windows not in WINDOWS:
        raise UsageError(f"--windows must be {', '.join(WINDOWS[:-1])} or {WINDOWS[-1]}, got {windows!r}")
    return windows


def sounding_for(scene, windows: str = "free", model=None, held=None):
    """What `engines.render(sounding=...)` takes for `api.render(windows=...)`: None for free windows; else per scene
    the frequency its windows are locked to (operator_sounding; None where unknown: that voice rolls in free
    windows). scene: one, or a list; held: the scene (or list) whose held bow each note sounds with (a score's note:
    its sustain, while the whole note with its bow stop renders); None: each scene's Scene.held_bow (a note with an
    attack or a stop locks to the bow it holds; a gesture rolls free)."""
    check_windows(windows)
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
