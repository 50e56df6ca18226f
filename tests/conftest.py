import atexit
import functools
import math
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from bowsynth.cli.main import main as _main
from bowsynth.engines.operator.modelfile import MAX_VALIDATION_CENTS, is_finite

os.environ.setdefault("OMP_NUM_THREADS", "2")
# measured pitch ratios are cached on disk (bowsynth.io.cache): the tests keep theirs out of the user's ~/.cache
# (made once, by the process that starts the run: xdist's workers inherit it; setdefault's argument would make an
# unused directory in every worker) and removed when that process ends, so runs leave nothing in the temp dir
if "BOWSYNTH_CACHE" not in os.environ:
    os.environ["BOWSYNTH_CACHE"] = tempfile.mkdtemp(prefix="bowsynth-test-cache-")
    atexit.register(shutil.rmtree, os.environ["BOWSYNTH_CACHE"], ignore_errors=True)

# the authors' reference data the tests use, in the repository (see tests/data/README.md for provenance)
ANCHORS = Path(__file__).resolve().parent / "data"


@pytest.fixture
def anchors():
    return ANCHORS


def tiny_config(steps=150, **kw):
    from bowsynth.engines.operator.network import NetConfig
    from bowsynth.training import TrainConfig

    return TrainConfig(minutes=None, steps=steps, optimizer=kw.pop("optimizer", "adam"), lr=kw.pop("lr", 5e-3), n_data=256, data_times=32, data_oversample=4, batch_states=64,
                       batch_times=32, band_seconds=0.3, checkpoint_seconds=1e9, select_every=kw.pop("select_every", 0.0),
                       net=NetConfig(width=16, depth=2, k=8, ff_branch=8, ff_trunk=8), **kw)


@pytest.fixture(scope="session")
def tiny_model(tmp_path_factory):
    """A tiny operator for fb 100, trained for a few seconds (shared by the tests that need a model)."""
    from bowsynth import Scene
    from bowsynth.training import Trainer

    # box sampling: a model this small strays off the thin band at once, and these tests need a rollout to run
    tr = Trainer(Scene(fb=100), tiny_config(steps=300, sampling="box"), "tiny")
    tr.run()
    model = tr.model()
    path = tmp_path_factory.mktemp("models") / "tiny.safetensors"
    model.save(path)
    return path


def run_main(args, capsys, monkeypatch):
    """Run the real entry point (which turns errors into one line and an exit code): (code, stdout, stderr)."""
    monkeypatch.setattr("sys.argv", ["bowsynth", *args])
    with pytest.raises(SystemExit) as e:
        _main()
        raise SystemExit(0)
    cap = capsys.readouterr()
    return e.value.code or 0, cap.out, cap.err


@pytest.fixture(scope="session")
def tiny_rest_model(tmp_path_factory):
    """A tiny point model with the rest-linearised flow (NetConfig.rest_linear), at scratch-g2's F_B / w and v_B."""
    from bowsynth import Scene
    from bowsynth.training import Trainer

    sc = Scene(f0=100.0, fb=0.815 * 2 * 3.141592653589793 * 100, vb=0.3)
    tr = Trainer(sc, tiny_config(steps=200, sampling="box", rest_linear=True), "tiny-rest")
    tr.run()
    path = tmp_path_factory.mktemp("models") / "tiny-rest.safetensors"
    tr.model().save(path)
    return path


# What a test holds a shipped model to comes from the model's own file, never from a table keyed by its name, so that
# a retrained catalogue keeps the tests meaningful. Its validation (training.selection.validate) plays a note from rest
# at each bow of a grid over its box, its centre among them, against the FDM at 100x: the pitch error there (cents; the
# larger of the whole render's and the listener's) is what the model claims for its note in free windows, the windows
# it was trained in. Where its validation locked the windows to the note's period (its record's 'windows': 'N a
# period'), which takes the free cycle's pitch error away, the record claims nothing for free windows: the claim is
# then MAX_VALIDATION_CENTS, what a model picked by default may be off at a grid bow. The limit is the claim plus a
# quarter, plus 0.2 cent for what a rollout longer than the validation's note and the pitch estimate add.
CLAIM_MARGIN, CLAIM_FLOOR_CENTS = 1.25, 0.2


def centre_record(m) -> dict:
    """The validation record of the model's centre bow (a point model's: its one record; {} where there is none)."""
    v = m.meta.validation or {}
    if v.get("points") is None:
        return v
    d = m.domain
    return next((r for r in v["points"] if math.isclose(r.get("beta", math.nan), d.beta, rel_tol=1e-6)
                 and math.isclose(r.get("vb", math.nan), d.vb, rel_tol=1e-6, abs_tol=1e-12)), {})


def claimed_cents(m) -> float:
    """The pitch error (|cents|) the model's validation measured for its note at its centre bow in free windows, or
    MAX_VALIDATION_CENTS where it played locked windows there (or recorded no pitch)."""
    r = centre_record(m)
    errs = [abs(r[k]) for k in ("cents", "heard_cents") if is_finite(r.get(k))]
    return max(errs) if errs and r.get("windows", "free") == "free" else MAX_VALIDATION_CENTS


def pitch_limit(m) -> float:
    return CLAIM_MARGIN * claimed_cents(m) + CLAIM_FLOOR_CENTS


# Tests take the shipped models they are about from the catalogue by what those are (a point model, the model picked
# at a bow, a box that plays below it, the model a pick was refined from), never by file name, so that retraining the
# catalogue, which renames models, leaves them meaningful.
def shipped_models() -> list:
    """The shipped catalogue as the package reads it (its readable files, failed validations included)."""
    from bowsynth.engines.operator.choose import SHIPPED_DIR, available_models

    return [m for m in available_models() if m.path is not None and m.path.parent.resolve() == SHIPPED_DIR.resolve()]


def shipped_pick(scene):
    """The shipped model the renderer picks for the scene (choose.find_model over the shipped catalogue)."""
    from bowsynth.engines.operator.choose import find_model

    return find_model(scene, shipped_models())


def soft_bow_model(models=None):
    """The model of the whole soft bow: of the validated range models that play below their box (an attack from
    F_B 0), the one with the widest box of bows (the shipped ones unless `models` are given)."""
    soft = [m for m in (shipped_models() if models is None else models)
            if m.failure is None and m.domain.is_range and m.domain.plays_below]
    assert soft, "no validated range model plays below its box"
    return max(soft, key=lambda m: m.domain.bow_extent)


@functools.cache
def shipped_stages() -> tuple:
    """The stages shipped refinements were made through (models/stages): kept to rebuild them, never picked."""
    from bowsynth.engines.operator.choose import SHIPPED_DIR
    from bowsynth.engines.operator.modelfile import load_model

    return tuple(load_model(p) for p in sorted((SHIPPED_DIR / "stages").glob("*.safetensors"))
                 if not p.name.endswith(".ckpt.safetensors"))


def refined_from(m):
    """The shipped model or stage that `m` was refined from (the id its training's 'refined_from' names)."""
    parent = m.meta.training.get("refined_from")
    assert parent, f"{m.path.name} was not refined from another model"
    found = [p for p in [*shipped_models(), *shipped_stages()] if p.id == parent]
    assert found, f"{m.path.name} was refined from {parent}, which is neither a shipped model nor a stage"
    return found[0]
