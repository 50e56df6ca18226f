"""Accuracy of the shipped models against a high-rate FDM: short rollouts in and out of sample, so that a model
10x worse than the shipped one fails here.

Each case renders 0.25 s with the operator and with the FDM at x100 the audio rate (x50 at 96 kHz) and asserts
NMSE(p) below LIMIT x the value measured for the shipped model (MEASURED, below). "In sample" is the render from rest
at the model's own scene (the trajectory training took its window starts from). Out of sample: states on that
trajectory at fractions of a window (no window of the trained render starts there) moved off it by a few percent,
other pitches with the same F_B / w where a window is not a whole number of samples (f0 130: 339.2 samples, f0 200:
220.5), and 48 / 96 kHz.

Measure (prints the tables RANGE_MEASURED and MEASURED hold; the shared 2-core CPU, about 30 s):
    PYTHONPATH=. python tests/test_accuracy.py
Point the tests at other model files with BOWSYNTH_TEST_MODELS=DIR: the paper's models by their scenes' names, the
others found by what they are (the soft bow's range model, the point models with the rest-linearised flow).
"""

import functools
import math
import os
from pathlib import Path

import pytest

import bowsynth
from bowsynth import Scene, load_model, make_scene, render_fdm, render_operator
from bowsynth.metrics import nmse

from conftest import soft_bow_model

MODELS = Path(os.environ.get("BOWSYNTH_TEST_MODELS") or bowsynth.shipped("models"))
DURATION = 0.25
LIMIT = 4.0  # x the measured value: run-to-run noise is ~1e-6 relative (float32 + BLAS order); 10x worse fails

# NMSE(p), 0.25 s, measured with the command above on the shipped models (commit of this file)
MEASURED = {
    'paper-fb10': {
        'in sample, from rest': 4.42e-07,
        'onset at 2.5 T, +3 %': 2.16e-05,
        'limit cycle at 20.25 T, -3 %': 1.21e-08,
        'limit cycle at 30.75 T, +2 %': 1.65e-08,
        'f0 130, from rest': 2.29e-07,
        'f0 200, from rest': 7.42e-08,
        'f0 130, limit cycle state': 2.17e-08,
        '48 kHz, from rest': 4.42e-07,
        '96 kHz, limit cycle state': 1.21e-08,
    },
    'paper-fb100': {
        'in sample, from rest': 2.59e-06,
        'onset at 2.5 T, +3 %': 2.21e-07,
        'limit cycle at 20.25 T, -3 %': 1.62e-07,
        'limit cycle at 30.75 T, +2 %': 1.94e-07,
        'f0 130, from rest': 2.34e-06,
        'f0 200, from rest': 8.39e-07,
        'f0 130, limit cycle state': 2.02e-07,
        '48 kHz, from rest': 2.59e-06,
        '96 kHz, limit cycle state': 1.62e-07,
    },
    'paper-fb1000': {
        'in sample, from rest': 3.26e-04,
        'onset at 2.5 T, +3 %': 4.11e-04,
        'limit cycle at 20.25 T, -3 %': 2.32e-04,
        'limit cycle at 30.75 T, +2 %': 2.75e-04,
        'f0 130, from rest': 2.59e-04,
        'f0 200, from rest': 2.40e-04,
        'f0 130, limit cycle state': 2.36e-04,
        '48 kHz, from rest': 3.26e-04,
        '96 kHz, limit cycle state': 2.32e-04,
    },
}


def _state_off_trajectory(sc: Scene, t_windows: float, nudge: float):
    """The render-from-rest state (FDM x100) at t = t_windows periods, scaled by (1 + nudge): off the trajectory."""
    r = render_fdm(sc.replace(duration=(t_windows + 0.5) / sc.f0, sample_rate=4 * sc.sample_rate, q0=0.0, p0=0.0),
                   oversample=25)
    i = int(round(t_windows / sc.f0 * r.scene.sample_rate))
    return float(r.q[i]) * (1 + nudge), float(r.p[i]) * (1 + nudge)


def cases(preset: str) -> dict:
    """name -> Scene, for the model trained on `preset` (f0 100 Hz, 44.1 kHz)."""
    sc = make_scene(preset, duration=DURATION)
    beta = sc.beta
    out = {"in sample, from rest": sc}
    for name, t, nudge in (("onset at 2.5 T, +3 %", 2.5, 0.03), ("limit cycle at 20.25 T, -3 %", 20.25, -0.03),
                           ("limit cycle at 30.75 T, +2 %", 30.75, 0.02)):
        q0, p0 = _state_off_trajectory(sc, t, nudge)
        out[name] = sc.replace(q0=q0, p0=p0)
    for f0 in (130.0, 200.0):
        out[f"f0 {f0:g}, from rest"] = sc.replace(f0=f0, fb=beta * 2 * math.pi * f0)
    q0, p0 = _state_off_trajectory(sc, 20.25, -0.03)
    out["f0 130, limit cycle state"] = sc.replace(f0=130.0, fb=beta * 2 * math.pi * 130.0, q0=q0, p0=p0)
    out["48 kHz, from rest"] = sc.replace(sample_rate=48_000)
    out["96 kHz, limit cycle state"] = sc.replace(sample_rate=96_000, q0=q0, p0=p0)
    return out


def error(model, sc: Scene) -> float:
    ref = render_fdm(sc, oversample=50 if sc.sample_rate > 50_000 else 100)
    return nmse(render_operator(sc, model=model).p, ref.p)


PRESETS = tuple(MEASURED)  # the paper's three scenes, each played by the model trained on it (named after it)


@functools.cache
def catalogue() -> tuple:
    """The model files in MODELS (the shipped ones unless BOWSYNTH_TEST_MODELS names others)."""
    files = sorted(p for p in MODELS.glob("*.safetensors") if not p.name.endswith(".ckpt.safetensors"))
    return tuple(load_model(p) for p in files)


@pytest.fixture(scope="module", params=PRESETS)
def shipped(request):
    return request.param, load_model(MODELS / f"{request.param}.safetensors")


def test_shipped_model_accuracy_in_and_out_of_sample(shipped):
    preset, model = shipped
    bad = []
    for name, sc in cases(preset).items():
        assert model.covers(sc), f"{preset}: {name} is outside the model's domain"
        e = error(model, sc)
        want = MEASURED[preset][name]
        if not e <= LIMIT * want:
            bad.append(f"{name}: NMSE(p) {e:.3g} > {LIMIT * want:.3g} ({LIMIT:g} x the measured {want:.3g})")
    assert not bad, f"{preset} ({MODELS}):\n" + "\n".join(bad)


# The point models with the rest-linearised flow (NetConfig.rest_linear) are those of slow onsets: the shipped one's
# note (F_B / w 0.815, v_B 0.3) grows from rest for ~0.2 s, so 0.25 s would score the onset alone. Each plays its
# validation's span from rest at its own pitch and two others against FDM x100, held to LIMIT x the NMSE its
# validation claims for its note (measured on the shipped one: within 1.25 x its claim at all three, the onset 2-6
# ms early, the pitch within 0.06 cents; the same scene without the rest-linearised flow scored 0.57, its onset 52 ms
# late).
SLOW_ONSET_CASES = ("own pitch", "f0 100", "f0 300")


def slow_onset_models() -> list:
    return [m for m in catalogue() if not m.domain.is_range and m.cfg.rest_linear]


@pytest.mark.parametrize("case", SLOW_ONSET_CASES)
def test_slow_onset_model_from_rest(case):
    models = slow_onset_models()
    assert models
    for model in models:
        v = model.meta.validation
        sc = Scene(**{**model.meta.scene, "duration": v["seconds"]})
        if case != "own pitch":
            f0 = float(case.split()[1])
            sc = sc.replace(f0=f0, fb=sc.beta * 2 * math.pi * f0)
        assert model.covers(sc)
        assert error(model, sc) <= LIMIT * v["nmse"], model.path.stem


# The soft bow's range model (conftest.soft_bow_model: one net over F_B / w 0.01-0.45 x v_B 0-0.3, bow stops and
# attacks included, trained with the derivative term): bows of the held-out grid of benchmarks/ranges.py (cell centres
# in log F_B / w; no training bow is one) and a crescendo through the box, 1 s from rest at f0 100 against FDM x100
# (the crescendo's reference follows the curve per step; the operator holds each window's bow at its middle). NMSE
# from rest is ill-conditioned in the bow (docs/measures.md), so the held bows are pinned by what a listener hears too
# (RANGE_HEARD: the worst of harmonics 1-10 in dB and the pitch in cents, over the last 0.5 s): an NMSE of 1e-4 to
# 6e-3 here can hide harmonics 30 dB off. The shipped one (width 128) is within 0.34 dB and 0.3 cents, at NMSE 1e-4
# to 1e-2 (python tests/test_accuracy.py prints both). Its validation's claims are its grid's worst (0.95 dB, 0.9
# cents), too loose to pin these bows: the tables hold its measurements.
RANGE_MEASURED = {(0.0226, 0.1437): 1.23e-4, (0.0514, 0.1437): 1.10e-3, (0.1168, 0.1437): 1.95e-3,
                  (0.1168, 0.2062): 7.66e-3, "crescendo 0.05 -> 0.35": 9.56e-3}
RANGE_HEARD = {(0.0226, 0.1437): (0.026, 0.017), (0.0514, 0.1437): (0.148, 0.127), (0.1168, 0.1437): (0.334, 0.297),
               (0.1168, 0.2062): (0.335, 0.153)}


def range_case(case) -> Scene:
    w = 2 * math.pi * 100.0
    if isinstance(case, tuple):
        return Scene(f0=100.0, fb=case[0] * w, vb=case[1], duration=1.0)
    return Scene(f0=100.0, fb=[[0.0, 0.05 * w], [1.0, 0.35 * w]], vb=0.2, duration=1.0)


@pytest.mark.parametrize("case", list(RANGE_MEASURED), ids=str)
def test_soft_range_model_held_out_bows(case):
    model = soft_bow_model(catalogue())
    sc = range_case(case)
    assert model.covers(sc)
    assert error(model, sc) <= LIMIT * RANGE_MEASURED[case]


def heard(model, sc: Scene) -> tuple[float, float]:
    from bowsynth.metrics import listener_errors

    e = listener_errors(render_operator(sc, model=model).p, render_fdm(sc, oversample=100).p, sc.sample_rate,
                        steady_seconds=0.5)
    return e["harm_db_max"], abs(e["cents"])


@pytest.mark.parametrize("case", list(RANGE_HEARD), ids=str)
def test_soft_range_model_held_out_bows_as_heard(case):
    harm, cents = heard(soft_bow_model(catalogue()), range_case(case))
    want_harm, want_cents = RANGE_HEARD[case]
    assert harm <= 1.5 * want_harm + 0.1 and cents <= 1.5 * want_cents + 0.05, (harm, cents)


if __name__ == "__main__":
    m = soft_bow_model(catalogue())
    for case in RANGE_MEASURED:
        print(f"    {case!r}: {error(m, range_case(case)):.2e},")
    for case in RANGE_HEARD:
        print(f"    {case!r}: {tuple(round(v, 3) for v in heard(m, range_case(case)))},")
    for preset in PRESETS:
        m = load_model(MODELS / f"{preset}.safetensors")
        print(f"    {preset!r}: {{")
        for name, sc in cases(preset).items():
            print(f"        {name!r}: {error(m, sc):.2e},")
        print("    },")
