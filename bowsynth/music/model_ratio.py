"""An operator model's own sounding ratio at a bow (the operator measuring itself: once per model and bow, cached), in
free windows and in windows locked to a period, and the lock a held note takes in windows locked to the physics'
period where the model holds it (`lock_ratio`). The physics' period comes from the shipped map (ratio_map), never
from the reference. engine_tuning tunes notes and locks windows with them."""

from __future__ import annotations

import json
from pathlib import Path

from .. import physics
from ..engines.operator.windows import Lock
from ..errors import DomainError
from ..scene import Scene
from .engine_ratio import SHIPPED_RATIOS, engine_ratio, ratio_key, shipped_ratios
from .ratio_map import physics_ratio
from .tuning import SilentNoteError

RATIO_F0 = 100.0  # the rate a model's ratio is measured at: its window chain does not depend on f0, only the samples
RATIO_PERIODS = 300  # sounding periods measured after the truth's settling time


def operator_ratio(model, locked: bool = False, more: int = 0):
    """The sounding ratio of a trained operator, as `pitch.tune(ratio=...)` takes it: the model rolled out from rest
    at the bow until the truth's settling time plus RATIO_PERIODS periods, its pitch over those periods; locked: in
    windows locked to the physics' period (lock_ratio), `more` windows a period beyond the fewest that fill it. A
    model's window chain depends on (beta, v_B) only, so one measurement per model and bow serves every pitch (cached
    on disk with the model's id)."""
    from ..metrics import f0_estimate
    from ..engines.operator.choose import as_model
    from ..engines.operator.engine import render_operator

    m = as_model(model)

    def ratio(beta: float, vb: float, a: float, f0: float) -> float:
        def measure():
            truth = physics_ratio(beta, vb, a)
            # a lock pulls the cycle in over tens to hundreds of periods (stick-slow at F_B / w 1.46, v_B 0.152: +0.2
            # cents over the first 300, +0.0008 over the next): measured after as many again
            periods = RATIO_PERIODS * (2 if locked else 1)
            seconds = min((truth.settle_periods + periods / truth.r) / RATIO_F0, 60.0)
            sc = Scene(f0=RATIO_F0, fb=beta * physics.omega(RATIO_F0), vb=vb, a=a, duration=seconds)
            r = render_operator(sc, model=m, sounding=Lock(RATIO_F0 * truth.r, more) if locked else None)
            tail = r.q[-int(RATIO_PERIODS / (truth.r * RATIO_F0) * sc.sample_rate):]
            return f0_estimate(tail, sc.sample_rate, tail=1.0) / RATIO_F0
        how = f"-locked2x{f'+{more}' if more else ''}" if locked else ""
        return engine_ratio(f"operator{how}{RATIO_PERIODS} {m.key}", beta, vb, a, measure, physics_ratio)
    ratio.physics = physics_ratio
    return ratio





# Windows locked to the physics (--windows physics) divide the period of the physics' limit cycle at the held bow (the
# shipped map of the reference's sounding ratio, ratio_map.physics_ratio), where the model holds that period. Such a
# clock pulls the
# operator's cycle onto it, as an oscillator is pulled within its locking range, and the network plays the wave within
# each period. Measured (`benchmarks/listener.py --windows physics`, the 12 held-out stick-slip bows):
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
# F_B / w 0.719, v_B 0.08: 17 windows of 0.994 T leave it 5.3-5.8 cents off, 18 hold it within 0.01; windows.Lock).
# Up to three more: floor-long's slowest heavy bows hold it in two more only (F_B / w 1.919, v_B 0.0849
# at 807 Hz: -1.65 / -0.54 / -0.008 cents in the fewest / one more / two more, -9.5 free; benchmarks/lock_more.py).
LOCK_MORE = (0, 1, 2, 3)


def lock_ratio(model, beta: float, vb: float, a: float) -> float | None:
    """The sounding ratio a held note's locked windows take with this model: the physics' where the model holds it
    (a Lock, with the windows a period it holds it in: the fewest that fill the period, else one more), else the
    model's own (own_ratio); None where neither is known (the physics settles on no period: a bow at or below v_B =
    1 / sqrt(2a); or the model cannot hold the bow from rest for the measurement)."""
    from ..metrics import cents

    try:
        truth = physics_ratio(beta, vb, a).r
    except SilentNoteError:
        return None
    for more in LOCK_MORE:
        try:
            held = operator_ratio(model, locked=True, more=more)(beta, vb, a, RATIO_F0)
            if abs(cents(held, truth)) <= LOCK_HOLDS_CENTS:
                return Lock(truth, more)
        except (DomainError, SilentNoteError):
            pass
    return own_ratio(model, beta, vb, a)


def own_ratio(model, beta: float, vb: float, a: float, f0: float = RATIO_F0) -> float | None:
    """The model's own sounding ratio at this bow (operator_ratio, cached), never the truth's; None where the model
    cannot hold the bow from rest for the measurement."""
    try:
        return operator_ratio(model)(beta, vb, a, f0)
    except (DomainError, SilentNoteError):
        return None


def build_shipped(path: Path = SHIPPED_RATIOS) -> Path:
    """Measure every shipped validated model's own ratio at each MIDI velocity's bow it covers, and write the table
    engine_ratio reads before measuring (SHIPPED_RATIOS): `play` starts without measuring them."""
    from ..engines.operator.choose import SHIPPED_DIR, available_models
    from ..io.outfile import atomic_write
    from . import midi as M

    ratios = {}
    for m in available_models():
        if m.path is None or m.path.parent.resolve() != SHIPPED_DIR.resolve() or m.failure is not None:
            continue
        for v in range(1, 128):
            beta, vb = M.bow_beta(v), M.bow_vb(v)
            sc = Scene(f0=RATIO_F0, fb=beta * physics.omega(RATIO_F0), vb=vb)
            if not m.covers(sc):
                continue
            r = own_ratio(m, beta, vb, sc.a)
            if r is not None:
                ratios[ratio_key(f"operator{RATIO_PERIODS} {m.key}", beta, vb, sc.a)] = r
    text = json.dumps({"format": "bowsynth-own-ratios", "ratios": ratios}, indent=0, sort_keys=True) + "\n"
    atomic_write(path, lambda tmp: Path(tmp).write_text(text))
    shipped_ratios.cache_clear()
    return path


if __name__ == "__main__":
    print(build_shipped())
