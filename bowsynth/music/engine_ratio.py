"""An engine's own sounding ratio at a bow (the audio-rate FDM's, an operator model's), measured once and kept on disk:
what a note asked at a pitch is tuned with, so that it sounds there whichever engine plays it."""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

from .. import metrics
from ..errors import DomainError
from ..io.cache import DiskTable
from .tuning import SilentNoteError, sounding_ratio
from .. import shipped

_ratios = DiskTable("engine-ratio", "1")


# A measurement that fails is kept too, and raised again from the table: a model that cannot hold a bow from rest
# fails the same way every time (measured afresh, four locks cost 1.1 s of a 1.7 s warm render).
_FAILS = {"DomainError": DomainError, "SilentNoteError": SilentNoteError}
_ENGINE_RATIOS: dict[str, float] = {}  # this process's answers, ahead of the disk
# An engine's own ratio sits within cents of the physics' (the FDM's dispersion ~2 cents at A5, an operator's own cycle
# up to tens): a cached one further off than a quarter tone (a 6 % edit is 101 cents) is measured again.
PLAUSIBLE_CENTS = 50.0
# The shipped models' own ratios measured at build time at the bows the live engine plays (every MIDI velocity at
# neutral controllers; model_ratio.build_shipped): read before the disk, held to the same checks. Keyed as the cache is
# (a retrained model has another id, so none of its entries match).
SHIPPED_RATIOS = shipped("models") / "tables" / "own-ratios.json"


@functools.cache
def shipped_ratios() -> dict:
    try:
        d = json.loads(SHIPPED_RATIOS.read_text())
    except (OSError, ValueError, RecursionError):
        return {}
    return d.get("ratios", {}) if isinstance(d, dict) and isinstance(d.get("ratios"), dict) else {}


def _plausible(r, phys: float) -> bool:
    """A ratio read from outside (the disk, a shipped table): a number, finite, within PLAUSIBLE_CENTS of the
    physics'."""
    return (isinstance(r, float) and math.isfinite(r) and r > 0
            and abs(metrics.cents(r, phys)) <= PLAUSIBLE_CENTS)


def ratio_key(engine: str, beta: float, vb: float, a: float) -> str:
    """An engine's ratio's key: the bow to 10 significant digits (a bow solved for a pitch comes back 1e-16 off)."""
    return f"{engine} {beta:.10g} {vb:.10g} {a:.10g}"


def engine_ratio(engine: str, beta: float, vb: float, a: float, measure, physics_ratio=None) -> float:
    """An engine's sounding ratio at a bow, from the on-disk table or measured (a silent note raises, as the physics'
    does: `physics_ratio`, the source of the physics' Ratio, is asked first: sounding_ratio, the reference, by
    default; the operator's path passes the shipped map, ratio_map.physics_ratio), the shipped table or measured; a
    measurement that raised DomainError or SilentNoteError raises it again."""
    phys = (physics_ratio or sounding_ratio)(beta, vb, a).r
    key = ratio_key(engine, beta, vb, a)
    if key in _ENGINE_RATIOS:  # asked again in this process (the live engine's tables ask each bow ~100 times)
        return _ENGINE_RATIOS[key]
    shipped = shipped_ratios().get(key)
    if _plausible(shipped, phys) and shipped <= 1:  # an operator's: friction only lowers the pitch
        _ENGINE_RATIOS[key] = shipped
        return shipped
    hit = _ratios.get(key)
    if isinstance(hit, dict) and _plausible(hit.get("r"), phys):
        _ENGINE_RATIOS[key] = hit["r"]
        return hit["r"]
    if isinstance(hit, dict) and hit.get("fails") in _FAILS:
        raise _FAILS[hit["fails"]](str(hit.get("why", "")))
    try:
        r = float(measure())
        if not (math.isfinite(r) and r > 0):
            raise SilentNoteError(f"the note does not speak with this engine at F_B / w = {beta:.4g}, v_B = {vb:g}")
    except (DomainError, SilentNoteError) as e:
        _ratios.put(key, {"fails": "DomainError" if isinstance(e, DomainError) else "SilentNoteError", "why": str(e)})
        raise
    _ratios.put(key, {"r": r})
    _ENGINE_RATIOS[key] = r
    return r
