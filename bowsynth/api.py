"""The Python API the CLI and notebooks share. torch is imported only when an operator is used."""

from __future__ import annotations

import contextlib
import math
from pathlib import Path

from .errors import BowsynthError, UsageError, interrupt_exit_code
from .fdm import render_fdm  # noqa: F401
from .scene import Scene


class Interrupted(BowsynthError):
    """Training stopped by Ctrl-C (exit 130) or SIGTERM (exit 143) after saving its checkpoint."""

    def __init__(self, msg: str, exit_code: int = 130):
        super().__init__(msg)
        self.exit_code = exit_code


def render(scene, engine: str = "operator", model=None, fallback: str = "none", oversample: int = 1,
           force: bool = False):
    """Render a Scene (or a list of Scenes) with engine 'operator' or 'fdm'; see `bowsynth.engines.render`.

    A request estimated past minutes of FDM work or gigabytes of memory is refused with the estimate (a UsageError)
    unless force=True; see `bowsynth.limits`."""
    from .engines import render as _r
    from .limits import check_request

    check_request(scene, engine, oversample, force)
    return _r(scene, engine=engine, model=model, fallback=fallback, oversample=oversample)


def render_operator(scene, model=None, fallback: str = "none"):
    """Render a Scene (or a list of Scenes, batched) with the operator; see `bowsynth.rollout.render_operator`."""
    return render(scene, engine="operator", model=model, fallback=fallback)


def load_model(path):
    """Load an operator model file (safetensors + JSON metadata, no pickle)."""
    from .model import load_model as _l

    return _l(path)


def train(scene: Scene, minutes=None, steps=None, seed=0, optimizer="soap", lbfgs=0.0, hybrid=True, window_ms=None,
          width=64, depth=4, n_data=None, checkpoint_seconds=60.0, out=None, force=False, resume=False,
          progress=False, console=None, config=None):
    """Train an operator for `scene`, save it to `out` (default ./models/<name>.safetensors) and validate it.

    Checkpoints go beside `out` every minute; `resume=True` continues from one. Returns a TrainResult.
    """
    from .network import NetConfig
    from .train import TrainConfig, Trainer, checkpoint_path, default_model_name, validate

    name = default_model_name(scene)
    out = Path(out) if out else Path("models") / f"{name}.safetensors"
    if out.suffix != ".safetensors":
        raise UsageError(f"model files end in .safetensors, got {out}")
    if out.exists() and not force:
        raise UsageError(f"{out} exists; pass --force to overwrite it, or --out to choose another file")
    out.parent.mkdir(parents=True, exist_ok=True)
    ckpt = checkpoint_path(out)
    if resume and not ckpt.exists():
        raise UsageError(f"no checkpoint to resume at {ckpt}")
    if config is None:
        if minutes is None and steps is None:
            minutes = 5.0
        config = TrainConfig(minutes=minutes, steps=steps, seed=seed, optimizer=optimizer, lbfgs_fraction=lbfgs,
                             hybrid=hybrid, window=None if window_ms is None else scene.omega * window_ms / 1e3,
                             checkpoint_seconds=checkpoint_seconds, net=NetConfig(width=width, depth=depth))
        if n_data is not None:
            config.n_data = n_data
    with _status(console, progress, "preparing: scene band and high-rate FDM training data"):
        tr = Trainer(scene, config, name)
    if resume:
        tr.load_checkpoint(ckpt)
    try:
        with _progress(console, progress, tr) as on_step:
            tr.run(ckpt=ckpt, on_step=on_step)
        model = tr.model()
        with _status(console, progress, "validating: 1 s rollout against a high-rate FDM"):
            model.meta.validation = validate(model, scene)
    except KeyboardInterrupt as e:  # Ctrl-C, or SIGTERM raised as errors.Terminated by the CLI
        tr.save_checkpoint(ckpt)
        code = interrupt_exit_code(e)
        raise Interrupted(f"{'terminated' if code == 143 else 'interrupted'} at step {tr.step}; checkpoint saved to "
                          f"{ckpt}; continue with the same command and --resume", exit_code=code) from None
    model.save(out, force=True)
    ckpt.unlink(missing_ok=True)
    from .train import TrainResult

    return TrainResult(model, out, tr.history)


@contextlib.contextmanager
def _status(console, enabled, msg):
    if not enabled or console is None:
        yield
        return
    with console.status(msg):
        yield


@contextlib.contextmanager
def _progress(console, enabled, tr):
    if not enabled or console is None:
        yield None
        return
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    cols = [TextColumn("training"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"), TimeElapsedColumn(),
            TextColumn("eta"), TimeRemainingColumn(), TextColumn("{task.fields[terms]}")]
    with Progress(*cols, console=console, transient=False) as prog:
        task = prog.add_task("train", total=1000, terms="")

        def on_step(rec):
            if tr.step % 25 == 0:
                terms = " ".join(f"{k} {v:.1e}" for k, v in rec.items() if k != "lr")
                prog.update(task, completed=1000 * tr.progress(), terms=f"step {tr.step} {terms}")

        yield on_step
        prog.update(task, completed=1000)
