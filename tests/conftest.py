import atexit
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from bowsynth.cli.main import main as _main

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
