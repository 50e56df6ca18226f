"""Which model plays a held note in auto windows when no model is given: the renderer's pick (choose.covering_model:
the most specialised model that has the bow away from its box's edges) unless it is measured to miss the worst-case
targets at the note's bow and pitch; then the truest of the models that cover the note.

The pick is judged by auto windows' own score (auto_windows.auto_score: the harmonics' worst dB, the pitch's cents
and the onset, each over its worst-case target, in the windows auto plays; where it does not hold the physics'
period, in free windows, measured for this). Where that is over CHALLENGE_SCORE, or the pick cannot hold the bow from
rest where the truth sounds (its render would be refused), every validated model that covers the note is scored the
same way (measured once per model and bow, cached on disk like auto's windows), and the lowest plays where it scores
AUTO_MARGIN better than the pick. So is a model that failed its validation by ear alone (modelfile.missed_by_ear: a
pitch or harmonics miss at some grid bow of its box): it is never the pick, but a measurement at this bow says more
of it here than its worst grid bow does, for a note from rest, which is what it measures. The pick and the
candidates are each also heard at the note's own pitch (auto_score's at_pitch, the worse of the two; cached per
model, bow and pitch): at the band's floor the ladder's pitches misranked models by 1.6 cents and scored 0.47 a pick
that played 28 cents flat at 70.7 Hz (session 50). A note that starts elsewhere (`--q0`, `--p0`) is played by such a
model only where the model, from that state, settles on the note it plays from rest (its own 2 s notes, within
NOTE_CENTS): session 48's `seam-base`, truer from rest at its bows, settled from 3 of 12 random states on a second
cycle 344 cents flat, where the truth has one.
Elsewhere no other model is measured.
Where the model that plays still misses the targets, the render's notes say so and name `--method fdm`.

Why the pick's own note is measured where it does not hold the physics' period, not only its long-run pitch: that
note, from rest, is what a render plays. (Session 36 came to it at F_B / w 1.6, v_B 0.071, 110 Hz, where stick-halt's
note read 1281 cents off; that was the pitch estimator's, misled by a ripple on the note's slow creep, and the note
plays within 0.8 cents: metrics.CROSS_DIP, session 37.)

Why (session 36): the smallest box is not always the truest. Of 48 held-out stick-slip bows, one, at 196.8 Hz, F_B /
w 1.702, v_B 0.0968, lies deep in stick-high's box (the smallest that has it away from its edges), whose own cycle
there is 12.5 cents flat of the truth's and does not take the physics' period; stick-halt, which covers it too, holds
that period within 0.003 cents. A box's size or validation NMSE does not say which model is truer at one bow; a
measurement at that bow does.

Why half the targets, not the targets: the score reads a note's last second at the ladder's pitches (at f0 100, the
same periods), which is not quite a note at its own pitch. Of session 35's 48 held-out stick-slip bows, stick-mid at
69.1 Hz, F_B / w 1.457, v_B 0.1695 scores 0.78 and measures 1.11 dB at its own pitch (stick-halt: 0.16); elsewhere
the score read 0.6-1.4x the measured worst. Over half: 3 of those 48 bows and 2 of 48 soft ones.

A render (api.render, `bowsynth render`, `bench map`) plays this choice and tunes `--pitch` for it. A score and the
live engine play the renderer's pick in any windows, and tune for it (engine_tuning.ratio_for_engine's `listen`):
their notes are batched per model, and each window's lock is the playing model's."""

from __future__ import annotations

import math
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass

from .. import compiled
from ..engines.operator.choose import available_models, bow_key, covering_model
from ..engines.operator.modelfile import OperatorModel, missed_by_ear
from ..errors import BowsynthError
from ..scene import Scene
from .auto_windows import AUTO_MARGIN, auto_lock, auto_score, is_measured
from .tuning import SilentNoteError, sounding_ratio


CHALLENGE_SCORE = 0.5  # over this (1 meets the worst-case targets) the pick is measured against the other models
# Where the pick cannot play the note (its render is refused), another model plays it only under this score: 50 cents
# or dB over the targets of 1 is a quarter tone off, another note. A refusal names `--method fdm`; a wrong note does
# not (session 38: stops-band at 319.8 Hz, F_B / w 1.188, v_B 0.0711, where stick-stops leaves its states, 6060 cents).
OTHER_NOTE_SCORE = 50.0
# Told (a callable taking one line: `told`) before a render waits for the notes of models not yet measured at its bow:
# 6-9 s at the band's floor, where 7-12 models cover a note, once per bow (sessions 54, 57); the CLI's render prints it
_NOTICE: ContextVar = ContextVar("bowsynth_pick_notice", default=None)
NOTE_CENTS = 50.0  # a quarter tone: a note that starts off rest and settles this far from the note from rest is another
CHECK_SECONDS = 2.0  # how long that note and the note from rest play before their pitches are compared


@dataclass(frozen=True)
class AutoPick:
    """A held note's model in auto windows: `model` plays (None: no validated model covers the note); `switched`
    whether it is not the renderer's pick; `note` says why it plays, or that it was measured to miss the worst-case
    targets at this bow and no model that covers it does better (None otherwise)."""

    model: OperatorModel | None
    note: str | None = None
    switched: bool = False


@contextmanager
def told(say):
    """Within it, `say` (a callable taking one line, or None) hears when a pick waits for models to be measured."""
    token = _NOTICE.set(say)
    try:
        yield
    finally:
        _NOTICE.reset(token)


def _name(m: OperatorModel) -> str:
    return m.path.stem if m.path else m.meta.name


# auto_pick's answers in this process, by the models looked among (the objects, so an id is never reused), which of
# them passed validation, the scene's bow_key and its held bow: a render asks it for its tuning, its windows and its
# rollout.
_PICKS: dict = {}


def auto_pick(scene: Scene, models: list[OperatorModel] | None = None) -> AutoPick:
    """The model that plays the scene in auto windows with no model given (see the module's text). A scene with no
    held bow (a gesture, a moving pitch), or one whose truth rests, is the renderer's pick's."""
    pool = tuple(available_models() if models is None else models)
    held = scene.held_bow()
    key = (pool, tuple(m.failure is None for m in pool), bow_key(scene),
           None if held is None else (held.beta, held.vb, held.f0))
    if key not in _PICKS:
        if len(_PICKS) >= 1024:
            _PICKS.clear()
        _PICKS[key] = _auto_pick(scene, held, list(pool))
    return _PICKS[key]


def _auto_pick(scene: Scene, held: Scene | None, pool: list[OperatorModel]) -> AutoPick:
    pick = covering_model(scene, pool)
    if pick is None or held is None:
        return AutoPick(pick)
    bow = (held.beta, held.vb, held.a, held.f0)
    first = auto_score(pick, *bow, at_pitch=True)  # heard at the note's pitch too (the ladder read 0.47 for 28 cents)
    if first is None and _sounds(bow):  # the pick cannot hold the bow from rest (its render is refused)
        first = math.inf
    if first is None or first <= CHALLENGE_SCORE:
        return AutoPick(pick)
    scored = [(first, pick)] if math.isfinite(first) else []  # the pick measured once, above
    at_rest = scene.q0 == 0 and scene.p0 == 0
    covering = [m for m in pool if m is not pick and _candidate(m) and m.covers(scene)]
    unheard = [m for m in covering if m.failure is not None and not at_rest and not _same_note_from(m, scene)]
    heard = [m for m in covering if m not in unheard]
    notice = _NOTICE.get()
    todo = sum(not is_measured(m, *bow[:3]) for m in heard) if notice is not None else 0
    if todo:
        notice(f"note: choosing the model by listening: measuring {todo} more model{'s' * (todo > 1)} that cover this "
               f"bow, once (cached after)")
    scored += [(s, m) for s, m in zip(_scores(heard, bow), heard) if s is not None and math.isfinite(s)]
    if not scored:
        return AutoPick(pick)
    mine = next((s for s, m in scored if m is pick), math.inf)
    best_s, best = min(scored, key=lambda x: x[0])  # min keeps the first of equals: the pick, then pool order
    # said wherever a note plays that misses: a model left out for its start state might have done better
    skipped = (f" ({', '.join(_name(m) for m in unheard)}, which failed validation by ear, "
               f"{'does' if len(unheard) == 1 else 'do'} not settle from q0 {scene.q0:g}, p0 {scene.p0:g} on the "
               f"note measured from rest)" if unheard else "")
    # where even the truest misses, say so: the band just above vb_stop at heavy forces, 5-150 cents off (session 37)
    missed = (f"; it misses the worst-case targets there too (1 meets them){skipped}: `--method fdm` plays "
              f"the physics" if best_s > 1.0 else "")
    if best is pick or best_s + AUTO_MARGIN > mine or (not math.isfinite(mine) and best_s > OTHER_NOTE_SCORE):
        if not math.isfinite(mine) or mine <= 1.0:
            return AutoPick(pick)
        return AutoPick(pick, f"note: {_name(pick)} misses the worst-case targets at this bow (auto windows score "
                              f"{mine:.3g}, 1 meets them) and no model that covers it does better{skipped}: "
                              f"`--method fdm` plays the physics")
    unvalidated = f" ({best.failure}: measured at this bow)" if best.failure else ""
    against = f" against {mine:.3g}" if math.isfinite(mine) else f"; {_name(pick)} cannot play it from rest"
    return AutoPick(best, f"note: {_name(best)} plays this bow: it sounds truer there than {_name(pick)}, the most "
                          f"specialised model that covers it (auto windows score {best_s:.3g}{against}; "
                          f"1 meets the worst-case targets){unvalidated}{missed}", switched=True)


def _scores(models: list[OperatorModel], bow: tuple) -> list[float | None]:
    """auto_score at the bow (at its pitch too) of each model, None for one that cannot be measured here (a file of
    ./models failing its physics check: not a candidate; the pick's own failure shows when it renders).

    Over the cores (compiled.share; the rollouts and the FDM release the GIL): each model's score is its own
    measurement, so the order they run in changes no number. At the band's floor 7-12 models cover a note, each
    measured 0.3-1.5 s: a first render there waited 10 s for them on one core (session 54)."""
    out: list[float | None] = [None] * len(models)

    def one(i: int) -> None:
        try:
            out[i] = auto_score(models[i], *bow, at_pitch=True)
        except BowsynthError:
            out[i] = None

    compiled.share(one, range(len(models)), min(compiled.usable_cores(), len(models)))
    return out


def _same_note_from(m: OperatorModel, scene: Scene) -> bool:
    """Whether m, from the scene's start state, settles on the note it plays from rest (what auto_score measured):
    its own notes at the held bow, CHECK_SECONDS each in the windows a render plays them in, their pitches over the
    last second within NOTE_CENTS. False where it cannot play from that state or either note does not sound."""
    from ..analysis.metrics import cents, f0_estimate
    from ..engines.operator.engine import render_operator_batch
    from ..engines.operator.windows import lock_at

    start = scene.held_bow().replace(duration=CHECK_SECONDS)
    try:
        lock = lock_at(auto_lock(m, start.beta, start.vb, start.a, start.f0), start.f0)  # a render's auto windows
        notes = render_operator_batch([start, start.replace(q0=0.0, p0=0.0)], model=m, sounding=[lock, lock])
    except BowsynthError:
        return False
    hz = [f0_estimate(r.p, start.sample_rate, tail=1.0) for r in notes]
    return all(math.isfinite(f) and f > 0 for f in hz) and abs(cents(hz[0], hz[1])) <= NOTE_CENTS


def _sounds(bow: tuple) -> bool:
    """Whether the truth sounds at a held bow (beta, vb, a, f0): it settles on a period."""
    try:
        sounding_ratio(*bow[:3])
    except SilentNoteError:
        return False
    return True


def _candidate(m: OperatorModel) -> bool:
    """A model measured against the pick at a bow: a validated one, or one that failed its validation by ear alone."""
    return m.failure is None or missed_by_ear(m.meta)
