"""Which model plays a held note when none is given: of the validated models that cover it, the one whose own cycle
lies nearest the physics' period from the shipped map, measured by the operator itself (never against the reference).

The renderer's static pick (`choose.covering_model`: the most specialised model that has the bow away from its box's
edges) does not always know the bow best: at a tile's seam a refinement has the bow near its edge and its parent has
it deep, and the parent can be the worse of the two (at 637 Hz, F_B / w 0.454, v_B 0.227 the parent's own cycle is
5.1 cents off the physics' period and its note 2.0 dB off in the worst harmonic; the refinement's 0.11 cents and
0.17 dB). A model whose free cycle holds the physics' period has learnt the bow's limit cycle; one that does not, has
not. So each covering model's own sounding ratio at the bow (`model_ratio.own_ratio`: once per model and bow, cached)
is compared with the map's, and the nearest plays where it is nearer than the static pick by more than PICK_CENTS.
"""

from __future__ import annotations

import math

from ..metrics import cents
from ..engines.operator.choose import available_models, covering_model
from ..errors import DomainError
from ..scene import Scene
from .model_ratio import own_ratio
from .ratio_map import physics_ratio
from .tuning import SilentNoteError

PICK_CENTS = 0.2  # the median pitch target: a model this much nearer the physics' period than the static pick plays


def heard_pick(scene: Scene, models=None):
    """The model that plays a held note (None where no validated model covers it): the static pick, or the covering
    model whose own cycle is nearest the map's period where it is nearer by more than PICK_CENTS. A gesture, a moving
    pitch or a note the physics does not sound keeps the static pick."""
    models = available_models() if models is None else models
    pick = covering_model(scene, models)
    held = scene.held_bow()
    if pick is None or held is None or scene.pitch_varies:
        return pick
    try:
        target = physics_ratio(held.beta, held.vb, held.a).r
    except (SilentNoteError, DomainError):
        return pick
    others = [m for m in models if m is not pick and m.failure is None and m.covers(scene)]
    if not others:
        return pick

    def off(m) -> float:
        r = own_ratio(m, held.beta, held.vb, held.a)
        return abs(cents(r, target)) if r else math.inf
    mine = off(pick)
    if mine <= PICK_CENTS:  # no other can be nearer by more than PICK_CENTS: none is measured
        return pick
    best = min(others, key=off)
    return best if off(best) < mine - PICK_CENTS else pick
