"""--windows auto: per model, held bow and pitch, the windows that sound truest against the truth: free, or locked to
the physics' period (where the model holds it) in the fewest windows that hold it or up to MORE_TRIED more. Each is
measured once per model and bow at f0 100 and cached on disk; a note is scored at its own pitch (a soft voice's
also by its note there).

Each candidate is scored by its worse error as a share of the issue's worst-case target: max(harmonics 1-10's worst
dB / 1 dB, |cents| / 1 cent, |onset error| / max(5 ms, 2 % of the truth's onset)).

Why measured: neither mode is truest everywhere. Free windows keep the harmonics (a lock of two windows a period, a
soft model's, moves the network's error onto them: held-out soft bows 1.1-2.1 dB worst in physics windows, 0.57-0.97
free), a lock keeps the pitch (the stick-slip tiles' own cycles are 0.5-4 cents off; locked 0.006). Session 21's rule,
free where the model's own pitch is within 0.2 cent, else the lock, missed the harmonics' worst on both seeds' soft
bows (1.11 and 2.12 dB) and loosened to 0.8 cent missed the pitch (1.16 cents, median 0.23). The truth is an FDM at x
AUTO_OVERSAMPLE (harmonic levels to 1e-3 dB; the pitch is the sounding ratio's), once per bow.

Why the onset, and a note as long as it takes to speak (session 27): at a light fast bow a note grows for seconds
(F_B / w 0.02, v_B 0.28: its onset 8.2 s at f0 100), so 2 s from rest at f0 100 were played by the flow at rest and
scored nothing of the model; the pitch alone then chose the lock, and at 440 Hz that lock moved the onset 37 ms and
the harmonics 1.04 dB where free windows are 2.4 ms and 0.15 dB off (`corner-long`).

Why per pitch, over a ladder of pitches (session 29): a lock pulls a note in over tens of periods, and the pull-in can
slip. stick-halt at F_B / w 1.565, v_B 0.181 (sounding at 0.286 f0) holds the physics' period from period 80 on, but
its periods 60-80 are 2.2 cents sharp, so a 2 s note at 141 Hz, whose last second is periods 40-81, came out 1.14
cents sharp where the note at f0 100 (periods 29-57) and the ratio after 600 periods were within 0.07. A model's
window chain does not depend on f0, only which of its periods a note's last second holds: so each candidate's note is
played at f0 100 long enough to hold the last second of a note AUTO_SECONDS past its speaking at each pitch of
PITCH_LADDER (as many periods as there), and a note is scored by its pitch and harmonics there, around its own f0.
Scored by the worst over the ladder instead, a transient at low pitches outweighed a lasting error: stick-slow at
1.457 / 0.152 slips 3.1 cents in physics windows over periods 20-40 only, is 2.5 cents sharp free everywhere, and a
344 Hz note went free, 3.0 cents sharp, where physics plays it within 0.01.

Why a soft voice's notes are played at their own pitch (session 39): the chain above does not depend on f0 where a
window is a whole number of samples (a stick-slip voice's grid: grid.py). A soft voice's window ends at the output
sample nearest its length, and then it does: slow-bow at F_B / w 0.358, v_B 0.093, locked in the fewest windows (9 a
period), holds the physics' period at f0 100 and at 6 of 13 pitches over 400-480 Hz, but not at the other 7 (1.41-1.85
dB, +0.41-0.48 cents), one of them 412.3 Hz where 412.0 holds; 11 windows a period hold it at all 13 (0.21 dB). So
for a soft voice each ladder pitch's note is played at that pitch (_pitch_errors), and a note is also scored by its
own note at its own f0 (_at_pitch: the candidates' renders, ~0.1-0.3 s, cached per model, bow and f0), the worse of
the two.

Why more windows (session 29): where a lock's windows end in the cycle sets its harmonics. stick-high at F_B / w
1.630, v_B 0.210 at 356 Hz: 13 windows a period (the fewest) 1.15 dB worst, 14: 1.99, 15: 0.44, 16: 0.34; at f0 100's
2 s note 13 scored 0.65, which the later periods (a higher note's last second) do not keep.

Why per 100 ms frame too (session 34): a listener hears the pitch frame by frame, and a gesture is scored that way.
stick-halt-high at F_B / w 1.9, v_B 0.15 holds the physics' period, and in free windows a 150 Hz note's last second is
within 0.15 cent, but from frame to frame its own cycle wanders (-2.0 to +1.5 cents), so the heaviest bow stop, a
second of that bow, played 1.17 cents median a frame where a lock plays 0.002. So each candidate's note is also measured
at each pitch of the ladder by the median |cents| of its 100 ms frames at that pitch (frames of 0.1 f / 100 s of the
note at f0 100, the same periods), over TARGET_FRAME_CENTS, the gestures' median target. A frame of fewer than three
periods asks nothing (a slow heavy bow sounds ~10 Hz at f0 100: no pitch a frame). The pitch alone: the harmonics of a
held note are the ladder's, and fitting them per frame cost ~10x. The frames count only where they miss the target:
within it, a frame's pitch reads ~0.2-0.5 cent in every candidate (zero crossings of 10 periods), and graded, that
floor hid what a lock gains: slow-bow at F_B / w 0.258, v_B 0.08 went free, 0.44 cents off at 440 Hz where its lock
of two windows more is within 0.002 (bench map).
"""

from __future__ import annotations

import math

import numpy as np

from .. import physics
from ..engines.operator.windows import Lock, lock_more
from ..errors import DomainError
from ..io.cache import DiskTable
from ..scene import Scene
from .model_ratio import RATIO_F0, lock_ratio, operator_ratio, own_ratio
from .tuning import SilentNoteError, sounding_ratio

AUTO_SECONDS = 2.0  # from rest; scored over the last second, as benchmarks/listener.py scores a note
AUTO_MAX_SECONDS = 30.0  # a bow that takes longer than this to speak is scored at this length
AUTO_OVERSAMPLE = 10
PITCH_LADDER = (65.0, 82.0, 103.0, 130.0, 164.0, 206.0, 260.0, 327.0, 412.0, 519.0, 654.0, 880.0)  # the span
LADDER_MAX_SECONDS = 60.0  # at f0 100: the longest note the ladder plays (a bow that speaks after ~25 s at 880 Hz)
FIT_SECONDS = 1.0  # at f0 100: the harmonics of a span are fitted over its last second at most
MORE_TRIED = 3  # windows a period beyond the fewest that hold the lock, each a candidate
TARGET_HARMONIC_DB, TARGET_CENTS = 1.0, 1.0  # the worst-case targets, each error's unit in the score
TARGET_FRAME_CENTS = 1.0  # the gestures' target: the median over a note's 100 ms frames
# Where free windows meet the worst-case targets (score <= 1), a lock replaces them only if it scores at least this
# much better (session 30, auto the render's default): free windows are the ones a model was trained on, and their
# waveform the truest. paper-fb10's scores, free 0.004 and a lock 0.004, chose the lock on noise, and its NMSE from rest
# went 4.4e-7 -> 2.2e-5; paper-fb1000's 0.252 / 0.244. Where free windows miss a target, the best candidate: at
# stick-fast's (1.199, 0.28) every candidate's onset scores 1.6-1.9, and free windows, 1.728 against the lock's 1.633,
# played 1.04 cents flat where the lock is within 0.15.
AUTO_MARGIN = 0.1
_choices = DiskTable("auto-windows", f"11/{AUTO_SECONDS!r}/{AUTO_MAX_SECONDS!r}/{AUTO_OVERSAMPLE}/{PITCH_LADDER!r}/"
                                     f"{LADDER_MAX_SECONDS!r}/{FIT_SECONDS!r}/{MORE_TRIED}/{TARGET_HARMONIC_DB!r}/"
                                     f"{TARGET_CENTS!r}/{TARGET_FRAME_CENTS!r}")


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


def candidate_errors(model, beta: float, vb: float, a: float, lock) -> dict:
    """Per candidate ('free'; 'physics<k>', k windows a period beyond the fewest, from the lock's own up to
    MORE_TRIED more; lock None: free windows alone) what a held note from rest at f0 100 measures against the truth,
    each error over its worst-case target (None where it does not play): 'base' the worse of the harmonics' worst and
    the onset from a note lasting AUTO_SECONDS past the time the physics speaks (onset.settled_seconds) against the
    FDM at x AUTO_OVERSAMPLE, 'cents' the cached ratio's (own_ratio's, the lock's: where a long note ends up),
    'ladder' per ladder_spans span the worse of its pitch and its harmonics (a 2 s note's last second at each pitch of
    PITCH_LADDER), 'frames' per pitch of PITCH_LADDER the median |cents| of the note's 100 ms frames at that pitch
    (_frame_errors)."""
    from ..analysis.metrics import cents, listener_errors, onset_limit_ms
    from ..engines.fdm import render_fdm
    from ..engines.operator.choose import as_model
    from ..engines.operator.engine import render_operator
    from ..engines.operator.grid import needs_whole_windows
    from ..engines.operator.onset import settled_seconds

    m = as_model(model)
    truth_r = sounding_ratio(beta, vb, a).r
    sc = Scene(f0=RATIO_F0, fb=beta * physics.omega(RATIO_F0), vb=vb, a=a, duration=1.0)
    sc = sc.replace(duration=settled_seconds(sc, AUTO_SECONDS, AUTO_MAX_SECONDS))
    truth = render_fdm(sc, oversample=AUTO_OVERSAMPLE)
    spans = ladder_spans(sc)
    long = sc.replace(duration=max([sc.duration] + [b for _, b in spans]))
    plays = [("free", lambda: own_ratio(m, beta, vb, a), None)]
    for k in range(lock_more(lock), lock_more(lock) + MORE_TRIED + 1) if lock is not None else ():
        plays.append((f"physics{k}", lambda k=k: operator_ratio(m, locked=True, more=k)(beta, vb, a, RATIO_F0),
                      Lock(RATIO_F0 * float(lock), k)))
    on_grid = not needs_whole_windows(m.domain, beta)
    refs = _span_refs(truth.p, spans, sc.sample_rate, RATIO_F0 * truth_r)  # once per bow, for every candidate
    if on_grid:  # _at_pitch's reference: this very render
        _settled_truth(beta, vb, a, truth.p)
    out = {}
    for name, ratio_of, sounding in plays:
        try:
            r = render_operator(long, model=m, sounding=sounding)
            ratio = ratio_of()
        except (DomainError, SilentNoteError):
            out[name] = None
            continue
        e = listener_errors(r.p[:sc.n_samples], truth.p, sc.sample_rate)
        harm = e["harm_db_max"]
        harm = math.inf if harm is None or not math.isfinite(harm) else harm
        ref_ms, err_ms = e["onset_ref_ms"], e["onset_err_ms"]
        # no onset in the truth: nothing to score; one in the truth and none in the note: the worst
        onset = 0.0 if not math.isfinite(ref_ms) else (abs(err_ms) / onset_limit_ms(ref_ms) if math.isfinite(err_ms)
                                                       else math.inf)
        off = math.inf if ratio is None else abs(cents(ratio, truth_r))
        if on_grid:  # an output-grid voice: each pitch's note played at that pitch (_pitch_errors)
            notes = _notes_at(m, sc, [(f, b * RATIO_F0 / f, sounding) for f, (_, b) in zip(PITCH_LADDER, spans)])
            ladder = _pitch_errors(notes, refs, sc.sample_rate)
        else:
            ladder = [_heard_error(r.p[i:j], r.p[k:j], sc.sample_rate, ref, levels) for i, j, k, ref, levels in refs]
        out[name] = {"base": _finite(max(harm / TARGET_HARMONIC_DB, onset)), "cents": _finite(off / TARGET_CENTS),
                     "ladder": [_finite(x) for x in ladder],
                     "frames": [_finite(x) for x in _frame_errors(r.p[:sc.n_samples], truth.p, sc.sample_rate)]}
    return out


def _frame_errors(p, truth_p, sample_rate: float) -> list[float]:
    """Per pitch f of PITCH_LADDER: the median |cents| of p's frames against the truth's (metrics.frame_errors, the
    pitch alone), frames of FRAME_SECONDS f / RATIO_F0 (p is a note at RATIO_F0: a 100 ms frame at f), over
    TARGET_FRAME_CENTS; 0 where no frame has a pitch in both (it asks nothing: the base and the ladder score a note
    that does not sound)."""
    from ..analysis.metrics import FRAME_SECONDS, frame_errors

    out = []
    for f in PITCH_LADDER:
        c = frame_errors(p, truth_p, sample_rate, frame=FRAME_SECONDS * f / RATIO_F0, harmonics=False)["cents_median"]
        out.append(0.0 if math.isnan(c) else c / TARGET_FRAME_CENTS)
    return out


def _span_refs(truth_p, spans, sample_rate: float, truth_hz: float) -> list[tuple]:
    """Per span (seconds of a note at f0 100): its samples i..j, the start k of its last FIT_SECONDS at most, and what
    a candidate's span is scored against (_heard_error): the truth's pitch there and its harmonics over k..j where the
    span lies within the truth's render, else the physics' sounding frequency and the render's last second (its limit
    cycle: the truth has settled by then)."""
    from ..analysis.metrics import f0_estimate, harmonic_levels

    settled = harmonic_levels(truth_p[-int(sample_rate):], sample_rate)
    out = []
    for a, b in spans:
        i, j = int(a * sample_rate), int(b * sample_rate)
        k = max(i, j - int(FIT_SECONDS * sample_rate))
        inside = j <= len(truth_p)
        out.append((i, j, k, f0_estimate(truth_p[i:j], sample_rate, tail=1.0) if inside else truth_hz,
                    harmonic_levels(truth_p[k:j], sample_rate) if inside else settled))
    return out


def _notes_at(m, sc: Scene, notes) -> list:
    """p of each held note (f, seconds, lock) at pitch f from rest as a render plays it, its lock (a frequency at the
    scene's f0, or None: free windows) moved to f; None for one that does not play. One batched rollout (one by one,
    ~18 ms a note: 60 of a soft bow's first render); one by one where the batch stops."""
    from ..engines.operator.engine import render_operator_batch

    scenes = [sc.replace(f0=f, fb=sc.beta * physics.omega(f), duration=t) for f, t, _ in notes]
    locks = [None if s is None else Lock(float(s) * f / sc.f0, lock_more(s)) for f, _, s in notes]
    try:
        return [r.p for r in render_operator_batch(scenes, model=m, sounding=locks)]
    except (DomainError, SilentNoteError):
        pass
    out = []
    for one, lock in zip(scenes, locks):
        try:
            out.append(render_operator_batch([one], model=m, _single=True, sounding=[lock])[0].p)
        except (DomainError, SilentNoteError):
            out.append(None)
    return out


def _pitch_errors(notes, refs, sample_rate: float) -> list[float]:
    """The ladder of a soft voice (the module docstring: its chain depends on f0), each span's note played at its
    ladder pitch (notes: p of each, _notes_at) and scored over its last second, as a listener hears it, against the
    span's truth (_span_refs, the same periods): a lock not held drifts through the windows' phase, and its
    harmonics' error with it (slow-bow's at 417.4 Hz: 1.48 dB over its last second, 0.3 dB over the last FIT_SECONDS
    of f0 100's periods)."""
    out = []
    for f, (_, _, _, ref, levels), p in zip(PITCH_LADDER, refs, notes):
        tail = None if p is None else p[-int(sample_rate):]
        out.append(_heard_error(tail, tail, sample_rate, ref * f / RATIO_F0, levels))
    return out


def _heard_error(pitched, fitted, sample_rate: float, ref_hz: float, ref_levels) -> float:
    """The worse of |cents| of `pitched`'s pitch against ref_hz and the harmonics' worst |dB| of `fitted` against
    ref_levels, each over its target; inf where there is no note (None), no pitch, or a harmonic the truth has is
    missing."""
    from ..analysis.metrics import cents, f0_estimate, harmonic_errors, harmonic_levels

    got = None if pitched is None else f0_estimate(pitched, sample_rate, tail=1.0)
    if not (got is not None and got > 0 and ref_hz > 0):
        return math.inf
    err, missing = harmonic_errors(harmonic_levels(fitted, sample_rate), ref_levels)
    harm = math.inf if missing else float(np.nanmax(err, initial=0.0))
    return max(abs(cents(got, ref_hz)) / TARGET_CENTS, harm / TARGET_HARMONIC_DB)


def _settled_truth(beta: float, vb: float, a: float, p=None) -> list[float]:
    """The truth's harmonic levels (dB re its fundamental) over the last second of a note at f0 100 lasting
    AUTO_SECONDS past its speaking (at most AUTO_MAX_SECONDS): its limit cycle, which a note at any pitch reaches in
    the same periods. Cached with the scores; p: that note's truth, already rendered (candidate_errors')."""
    from ..analysis.metrics import harmonic_levels
    from ..engines.fdm import render_fdm
    from ..engines.operator.onset import settled_seconds

    key = f"truth {beta!r} {vb!r} {a!r}"
    hit = _choices.get(key) if p is None else None
    if isinstance(hit, list) and len(hit) > 1:
        return [float(x) for x in hit]
    sc = Scene(f0=RATIO_F0, fb=beta * physics.omega(RATIO_F0), vb=vb, a=a, duration=1.0)
    sc = sc.replace(duration=settled_seconds(sc, AUTO_SECONDS, AUTO_MAX_SECONDS))
    p = render_fdm(sc, oversample=AUTO_OVERSAMPLE).p if p is None else p
    levels = [_finite(x) if math.isfinite(x) else -1e9 for x in harmonic_levels(p[-int(sc.sample_rate):],
                                                                               sc.sample_rate)]
    _choices.put(key, levels)
    return levels


def _at_pitch(m, beta: float, vb: float, a: float, lock, f0: float, names) -> dict:
    """{candidate: _heard_error} of each candidate's held note from rest at f0 itself, lasting AUTO_SECONDS past its
    speaking, against the truth's settled levels and pitch: a soft voice's ladder pitches do not stand for the pitches
    between them (slow-bow's lock of 9 windows a period holds at 412.0 Hz, not at 412.3). Cached per model, bow, f0."""
    from ..engines.operator.onset import settled_seconds

    key = f"{m.key} {beta!r} {vb!r} {a!r} at {f0!r}"
    hit = _choices.get(key)
    if isinstance(hit, dict) and all(n in hit for n in names):
        return hit
    truth_r = sounding_ratio(beta, vb, a).r
    levels = np.array(_settled_truth(beta, vb, a))
    levels[levels < -1e8] = np.nan
    sc = Scene(f0=f0, fb=beta * physics.omega(f0), vb=vb, a=a, duration=1.0)
    sc = sc.replace(duration=settled_seconds(sc, AUTO_SECONDS, AUTO_MAX_SECONDS))
    snd = [None if n == "free" else Lock(f0 * float(lock), int(n[len("physics"):])) for n in names]
    notes = _notes_at(m, sc, [(f0, sc.duration, s) for s in snd])
    tails = [None if p is None else p[-int(sc.sample_rate):] for p in notes]
    out = {n: _finite(_heard_error(t, t, sc.sample_rate, f0 * truth_r, levels)) for n, t in zip(names, tails)}
    _choices.put(key, out)
    return out


def _finite(x: float) -> float:
    """A score as the disk cache keeps it (JSON has no inf): at most 1e9."""
    return min(float(x), 1e9)


def candidate_score(errors: dict | None, f0: float | None = None) -> float:
    """A candidate's score (candidate_errors') for a note at f0: the worst of its base, its ratio's cents, its ladder
    at f0 (the worse of the two ladder pitches around it; past the ladder its end) and its frames there where they
    miss their target (above 1); f0 None: over the whole ladder (a choice for every pitch: the live engine's, per
    velocity). inf where it does not play."""
    if errors is None:
        return math.inf
    ladder = errors["ladder"]
    pitches = PITCH_LADDER[:len(ladder)]
    if f0 is None or not ladder:
        lo, hi = 0, len(ladder)
    else:
        i = sum(1 for f in pitches if f <= f0)  # pitches[:i] lie at or below f0
        lo, hi = (max(i - 1, 0), i + 1) if i < len(pitches) else (len(ladder) - 1, len(ladder))
    missed = [x for x in errors["frames"][lo:hi] if x > 1.0]
    return max([errors["base"], errors["cents"]] + ladder[lo:hi] + missed)


def is_measured(model, beta: float, vb: float, a: float) -> bool:
    """Whether the model's notes at this bow are measured already (on disk): a first render waits for them."""
    return isinstance(_choices.get(_errors_key(model, beta, vb, a)), dict)


def _errors_key(model, beta: float, vb: float, a: float) -> str:
    from ..engines.operator.choose import as_model
    return f"{as_model(model).key} {beta!r} {vb!r} {a!r}"


def _cached_errors(model, beta: float, vb: float, a: float, lock) -> dict:
    hit = _choices.get(key := _errors_key(model, beta, vb, a))
    # an entry of free windows alone (auto_score's, where the model held no lock) does not answer for a lock
    if not (isinstance(hit, dict) and "free" in hit and (lock is None or len(hit) > 1)):
        hit = candidate_errors(model, beta, vb, a, lock)
        _choices.put(key, hit)
    return hit


def window_scores(model, beta: float, vb: float, a: float, lock, f0: float | None = RATIO_F0) -> dict:
    """{candidate: score} for a note at f0 (candidate_score), measured once per model and bow (cached); a voice on
    the output grid (a soft model's) also by its note at f0 itself (_at_pitch), the worse of the two."""
    from ..engines.operator.choose import as_model
    from ..engines.operator.grid import needs_whole_windows

    m = as_model(model)
    scores = {name: candidate_score(e, f0) for name, e in _cached_errors(m, beta, vb, a, lock).items()}
    if f0 is None or needs_whole_windows(m.domain, beta):
        return scores
    at = _at_pitch(m, beta, vb, a, lock, f0, [n for n, x in scores.items() if math.isfinite(x)])
    return {n: max(x, at.get(n, math.inf)) if math.isfinite(x) else x for n, x in scores.items()}


def auto_lock(model, beta: float, vb: float, a: float, f0: float | None = RATIO_F0) -> float | None:
    """windows 'auto': the physics' sounding ratio (a Lock, with the windows a period of the best candidate) where
    a held note at f0 locks its windows to it, None where it plays in free windows (they score best, or within
    the targets and no lock scores AUTO_MARGIN better: window_scores; or a lock the model does not hold, or no period
    known). f0 None: the choice for every pitch."""
    try:
        truth = sounding_ratio(beta, vb, a).r
    except SilentNoteError:
        return None
    lock = lock_ratio(model, beta, vb, a)
    if lock is None or lock != truth:  # the model does not hold the physics' period: its own, in free windows
        return None
    best = _best(window_scores(model, beta, vb, a, lock, f0))
    return None if best == "free" else Lock(truth, int(best[len("physics"):]))


def _best(scores: dict) -> str:
    """auto's candidate of window_scores: the lowest score; free windows where they meet the targets and no lock
    scores AUTO_MARGIN better (a lock must earn its place where free windows do well)."""
    best = min(scores, key=lambda k: (scores[k], k != "free"))
    close = scores[best] + AUTO_MARGIN > scores["free"]
    return "free" if best == "free" or (close and scores["free"] <= 1.0) else best


def auto_score(model, beta: float, vb: float, a: float, f0: float = RATIO_F0, at_pitch: bool = False) -> float | None:
    """The score (candidate_score, over the worst-case targets: 1 meets them) of what auto windows play of this model
    at this bow for a note at f0: the lock's or free windows' that auto_lock chooses (where the model does not hold
    the physics' period, its free windows' note is measured: an FDM at x AUTO_OVERSAMPLE and a render, 0.5-3 s, once
    per model and bow). None where nothing is judged: the truth does not sound, or the model cannot hold the bow from
    rest to measure its pitch. at_pitch: a voice on whole windows (stick-slip's) is also heard at f0 itself, as a soft
    voice always is (_at_pitch), the worse of the two: the model chosen by listening compares models so (session 50:
    at the band's floor just above vb_stop, seam-low scored 0.28 by the ladder and played 1.64 cents sharp at 91.1 Hz,
    where seam-mid, scored 0.42, played within 0.001)."""
    from ..engines.operator.choose import as_model
    from ..engines.operator.grid import needs_whole_windows

    try:
        truth = sounding_ratio(beta, vb, a).r
    except SilentNoteError:
        return None
    lock = lock_ratio(model, beta, vb, a)
    if lock is None:
        return None
    if lock != truth:  # the model does not hold the physics' period: its free windows
        lock = None
    scores = window_scores(model, beta, vb, a, lock, f0)
    name = _best(scores) if lock is not None else "free"
    if not at_pitch or f0 is None or not math.isfinite(scores[name]):
        return scores[name]
    m = as_model(model)  # read only when heard at f0: a model given by name is a file
    # a soft voice's scores already hear it at f0 (window_scores); a whole-window voice's are the ladder's alone
    if not needs_whole_windows(m.domain, beta):
        return scores[name]
    return max(scores[name], _at_pitch(m, beta, vb, a, lock, f0, [name])[name])
