"""The Python API the CLI and notebooks share: render a Scene, tune a pitch for its engine, fit a recording, train
an operator. torch is imported only when an operator is used."""

from __future__ import annotations

import contextlib
import math
import os
from pathlib import Path

from . import physics
from .errors import BowsynthError, UsageError, held, interrupt_exit_code
from .scene import Scene


class Interrupted(BowsynthError):
    """Training stopped by Ctrl-C (exit 130) or SIGTERM (exit 143) after saving its checkpoint.

    Parameters
    ----------
    msg : str
        What stopped, and where its checkpoint is.
    exit_code : int
        The CLI's exit status: 130 (Ctrl-C) or 143 (SIGTERM).

    Examples
    --------
    >>> Interrupted("terminated at step 40", exit_code=143).exit_code
    143
    """

    def __init__(self, msg: str, exit_code: int = 130):
        super().__init__(msg)
        self.exit_code = exit_code


def render(scene, engine: str = "operator", model=None, fallback: str = "none", oversample: int = 1,
           force: bool = False, windows: str | None = None):
    """Render a Scene (or a list of Scenes) with the trained operator or the FDM; see `bowsynth.engines.render`.

    Parameters
    ----------
    scene : Scene or list of Scene
        The note to play; a list is rolled out batched (the operator) and gives a list of renders.
    engine : {'operator', 'fdm'}
        The trained operator, or the finite-difference reference.
    model : OperatorModel, path or str, optional
        The operator's model (a model, a file, or a shipped model's name). None: of the models that cover a held
        note the one whose own cycle lies nearest the physics' period plays it (`music.pick.heard_pick`; a gesture:
        `engines.operator.choose.find_model`'s pick).
    fallback : {'none', 'fdm'}
        'fdm' finishes with the FDM an operator voice that leaves its model's domain (said in `Render.info`);
        'none' raises DomainError.
    oversample : int
        The FDM's steps per output sample.
    force : bool
        Render a request estimated past minutes of FDM work or gigabytes of memory, which is otherwise refused with
        the estimate (see `bowsynth.engines.limits`).
    windows : {'auto', 'free', 'locked', 'physics'}, optional
        The operator's windows (None: 'auto', `music.engine_tuning.RENDER_WINDOWS`). 'free' rolls each voice in
        windows of the trained length; 'locked' a held bow's voice in windows locked to the period its playing model
        sounds at (the model's own, measured once per model and bow and cached:
        `music.engine_tuning.operator_sounding`); 'physics' in windows that divide the physics' period at its bow,
        which pulls the note onto the physical pitch where the model holds it, else to the model's own
        (`model_ratio.lock_ratio`); 'auto' the physics' period where the model holds it, else free
        (`engine_tuning.auto_lock`). The physics' period comes from the shipped map (`music.ratio_map`); whether a
        model holds it, the operator measures of itself (once per model and bow, cached): no reference runs. A note
        whose bow moves only for an attack or a stop locks to the bow it holds (`Scene.held_bow`); a gesture rolls
        free. See `engines.operator.windows.locked_window`.

    Returns
    -------
    Render or list of Render
        The samples (float32 from the operator, float64 from the FDM), the engine that played them
        (`Render.method`) and what it reports (`Render.info`).

    Raises
    ------
    UsageError
        An unknown engine, fallback or windows, or a request past the limits without `force`.
    DomainError
        No model covers the scene (or a rollout left its model) and `fallback` is 'none'.
    ModelFileError
        A model file that is missing, unreadable, or does not do what its metadata claims.

    Notes
    -----
    Free windows spread the network's error into faint lines between and below the harmonics (60 dB down), locked
    ones put it on the harmonics (0.1 dB median instead of 0.03): a single note keeps its harmonics truer free, a
    chord or a mix (whose voices fill each other's gaps) sounds closer to the physics locked (`score`'s default); a
    held note at a given f0 sounds the physical pitch with 'physics' (0.0005 cents median for stick-slip bows against
    1.3 locked), after a pull-in a short note sounds.

    Examples
    --------
    >>> from bowsynth import api
    >>> from bowsynth.scene import Scene
    >>> r = api.render(Scene(duration=0.2))
    >>> r.method, r.q.shape, r.q.dtype
    ('operator', (8820,), dtype('float32'))
    >>> [str(x.method) for x in api.render([Scene(duration=0.2), Scene(f0=150, duration=0.2)], engine="fdm")]
    ['fdm', 'fdm']
    """
    from .engines import Engine, parse_choice
    from .engines import render as _r
    from .engines.limits import check_request

    check_request(scene, engine, oversample, force)
    if parse_choice(Engine, engine, "--method") is not Engine.operator:
        return _r(scene, engine=engine, model=model, fallback=fallback, oversample=oversample)
    from .engines.operator.choose import one_listing

    with one_listing():
        return _render_operator(scene, model, fallback, windows)


def _render_operator(scene, model, fallback: str, windows: str | None):
    from .engines import render as _r
    from .music.engine_tuning import sounding_for

    def play(sc, m):
        return _r(sc, engine="operator", model=m, fallback=fallback, sounding=sounding_for(sc, windows, m))
    if model is not None:
        return play(scene, model)
    from .engines.operator.choose import available_models, covering_model
    from .music.pick import heard_pick

    pool = available_models()
    scenes = list(scene) if isinstance(scene, (list, tuple)) else [scene]
    # a held note whose covering models know its bow unequally plays the one whose own cycle is nearest the physics'
    alone = {i: m for i, sc in enumerate(scenes) for m in [heard_pick(sc, pool)] if m is not covering_model(sc, pool)}
    if not isinstance(scene, (list, tuple)):
        return play(scene, alone.get(0))
    rest = [i for i in range(len(scenes)) if i not in alone]
    out = dict(zip(rest, play([scenes[i] for i in rest], None) if rest else []))
    for i, m in alone.items():
        out[i] = play(scenes[i], m)
    return [out[i] for i in range(len(scenes))]


def tuning_for(scene: Scene, engine: str = "operator", model=None, oversample: int = 1, windows: str | None = None):
    """The sounding ratio of the engine that will play the scene in these windows, to tune a pitch with.

    Parameters
    ----------
    scene : Scene
        The note as it will be played (its bow, rate and duration).
    engine, model, oversample, windows
        As `render` takes them.

    Returns
    -------
    ratio : callable
        ratio(beta, vb, a, f0): the sounding ratio, for `make_scene(pitch=..., ratio=ratio)` (see
        `music.engine_tuning.ratio_for_engine`).
    what : str
        Whose ratio it is (a model in its windows, the FDM, or the physics' map and why).

    Examples
    --------
    >>> from bowsynth import api
    >>> from bowsynth.scene import Scene
    >>> ratio, what = api.tuning_for(Scene(duration=0.2), engine="fdm")
    >>> what
    'the FDM at x1'
    """
    from .music.engine_tuning import ratio_for_engine

    return ratio_for_engine(scene, engine, model, oversample, windows=windows, heard=True)


def render_fdm(scene: Scene, oversample: int = 1, force: bool = False):
    """Render a Scene with the FDM; see `bowsynth.engines.fdm.render_fdm` (imported here on first use).

    Parameters
    ----------
    scene : Scene
        The note to play.
    oversample : int
        Steps per output sample.
    force : bool
        Render past the estimates of `bowsynth.engines.limits` (else refused).

    Returns
    -------
    Render
        float64 samples; `method` 'fdm' (or 'fdm xN' oversampled).

    Raises
    ------
    UsageError
        A request past the limits without `force`.

    Examples
    --------
    >>> from bowsynth import api
    >>> from bowsynth.scene import Scene
    >>> r = api.render_fdm(Scene(duration=0.2), oversample=2)
    >>> r.method, r.q.dtype, len(r.q)
    ('fdm x2', dtype('float64'), 8820)
    """
    from .engines.fdm import render_fdm as _r
    from .engines.limits import check_request

    check_request(scene, "fdm", oversample, force)
    return _r(scene, oversample=oversample)


def render_operator(scene, model=None, fallback: str = "none"):
    """Render a Scene (or a list of Scenes, batched) with the operator, in render's default windows (auto); see
    `bowsynth.engines.operator.engine.render_operator`.

    Parameters
    ----------
    scene : Scene or list of Scene
        The note(s) to play.
    model : OperatorModel, path or str, optional
        The model; None: the one `render` picks.
    fallback : {'none', 'fdm'}
        As `render` takes it.

    Returns
    -------
    Render or list of Render
        float32 samples, the network's precision.

    Raises
    ------
    DomainError
        No model covers the scene and `fallback` is 'none'.

    Examples
    --------
    >>> from bowsynth import api
    >>> from bowsynth.scene import Scene
    >>> r = api.render_operator(Scene(duration=0.2), model="paper-fb100")
    >>> r.method, r.info.model_id.split("@")[0]
    ('operator', 'fb100_f0100_vb0.2_a100')
    """
    return render(scene, engine="operator", model=model, fallback=fallback)


def fit(target, models=None, starts=None, progress=None, check: bool = True, curves: bool = False):
    """The held bow (F_B / w, v_B) and f0 that make the operator sound like `target`. See `bowsynth fit` and
    docs/fit.md.

    Parameters
    ----------
    target : str or Path
        A mono recording.
    models : list, optional
        The operator models to search with (default: the shipped and ./models ones).
    starts : int, optional
        Starts of the search's descent (default `bowsynth.fit.held.STARTS`).
    progress : callable, optional
        progress(stage, done, total), called as the search goes.
    check : bool
        Also play the fitted note as `render` plays it and measure it against the target.
    curves : bool
        Also fit the bow as breakpoint curves from the held fit (`bowsynth.fit.curves.CurveFit`).

    Returns
    -------
    Fit or (Fit, CurveFit)
        A `bowsynth.fit.held.Fit` (best, the spread the sound leaves open, bows that sound alike, and with `check`
        the fitted note against the target); with `curves`, (fit, curves).

    Raises
    ------
    FitError
        A target that cannot be read or used (a UsageError); FitMiss where no match is found.

    Examples
    --------
    >>> from bowsynth import api
    >>> api.fit("no-such-recording.wav")
    Traceback (most recent call last):
    ...
    bowsynth.fit.target.FitError: no-such-recording.wav: no such file
    >>> best = api.fit("note.wav", check=False).best  # doctest: +SKIP
    """
    from .fit import held
    from .fit.target import read_target

    t = read_target(target)
    f = held.fit_held(t, models=models, starts=starts or held.STARTS, progress=progress)
    if check:
        f.checked = held.check(f, t, render)
    if not curves:
        return f
    from .fit import curves as fc
    from .fit.frames import frame_bows

    c = fc.fit_curves(t, f, models=models, progress=progress, frames=frame_bows(t))
    if check:
        c.checked = fc.check(c, t, render)
    return f, c


def load_model(path):
    """Load an operator model file (safetensors + JSON metadata, no pickle).

    Parameters
    ----------
    path : str or Path
        The model file (`model_path` finds one by name).

    Returns
    -------
    OperatorModel

    Raises
    ------
    ModelFileError
        A file that is missing, corrupt, foreign or of another format version.

    Examples
    --------
    >>> from bowsynth import api
    >>> api.load_model(api.model_path("paper-fb100")).meta.name
    'fb100_f0100_vb0.2_a100'
    """
    from .engines.operator.modelfile import load_model as _l

    return _l(path)


def model_path(name) -> Path:
    """A model file given as a path, or by its name in ./models or the shipped models (`soft-range`).

    Parameters
    ----------
    name : str or Path
        A path (returned as it is), or a model's name.

    Returns
    -------
    Path

    Raises
    ------
    ModelFileError
        No model of that name.

    Examples
    --------
    >>> from bowsynth import api
    >>> api.model_path("soft-range").name
    'soft-range.safetensors'
    """
    from .engines.operator.choose import model_path as _m

    return _m(name)


def train(scene: Scene, config=None, out=None, force=False, resume=False, progress=False, console=None, box=None,
          init=None, **settings):
    """Train an operator for `scene`, save it to `out` and validate it.

    Parameters
    ----------
    scene : Scene
        The bow to train for; with `box`, the pitch, sample rate and a at which the training renders are made.
    config : TrainConfig, optional
        A `bowsynth.training.TrainConfig`; else made from `settings`. Its defaults are the only ones.
    out : str or Path, optional
        The model file (default ./models/<name>.safetensors). Checkpoints go beside it.
    force : bool
        Overwrite `out`, or start over from an unfinished run's checkpoint.
    resume : bool
        Continue from the checkpoint beside `out`.
    progress : bool
        Report progress on `console`.
    console : rich.console.Console, optional
        Where progress goes.
    box : ParamBox, optional
        A `bowsynth.training.ParamBox` of bows (beta, v_B) to train a range model for (see `range_scene`).
    init : OperatorModel, path or str, optional
        A trained range model to refine for `box` (or for the scene's own bow, a box of zero width): its network
        and scalings are kept and trained further on this box's data (`train --from`).
    **settings
        The config's fields as keywords (minutes=, steps=, seed=, optimizer=, ...); `window_ms` gives the window in
        ms at the scene's pitch, `width` / `depth` the network's (`make_train_config`).

    Returns
    -------
    TrainResult
        The model, the file it was saved to and the training's history. A model whose validation rollout fails is
        saved but marked failed in its record (it is never picked by default).

    Raises
    ------
    UsageError
        A bad setting or file name, an existing `out` without `force`, an unfinished run without `resume` or
        `force`, or another training writing `out`.
    Interrupted
        Ctrl-C or SIGTERM, after the checkpoint is saved.

    Examples
    --------
    >>> from bowsynth import api
    >>> from bowsynth.scene import Scene
    >>> api.train(Scene(), out="model.pt")
    Traceback (most recent call last):
    ...
    bowsynth.errors.UsageError: model files end in .safetensors, got model.pt
    >>> result = api.train(Scene(), minutes=1, out="models/mine.safetensors")  # doctest: +SKIP
    """
    from .training.config import check_net_options, check_refine, checkpoint_path, default_model_name

    config = config or make_train_config(scene, **settings)
    config.validate()
    if init is not None:
        from .engines.operator.choose import as_model
        from .training.ranges import ParamBox

        init = as_model(init)
        box = box or ParamBox(scene.beta, scene.beta, scene.vb, scene.vb, scene.a)
        check_refine(init, config, scene, box)
    elif box is not None and box.is_point:
        box = None
    check_net_options(config, scene, box)
    name = default_model_name(scene) if box is None else range_model_name(scene, box)
    out = Path(out) if out else Path("models") / f"{name}.safetensors"
    if out.suffix != ".safetensors":
        raise UsageError(f"model files end in .safetensors, got {out}")
    if out.exists() and not force:
        raise UsageError(f"{out} exists; pass --force to overwrite it, or --out to choose another file")
    ckpt = checkpoint_path(out)
    for p in (out, ckpt):  # a FIFO would block the read (or be replaced by the write), a device never ends
        if (p.exists() or p.is_symlink()) and not p.is_file():
            raise UsageError(f"{p} is not a regular file (a FIFO, a device, a directory or a broken link): remove it "
                             f"or pick another --out")
    if resume and not ckpt.exists():
        raise UsageError(f"no checkpoint to resume at {ckpt}")
    if ckpt.exists() and not (resume or force):  # the same command run again must not throw an interrupted run away
        raise UsageError(f"{ckpt} holds an unfinished run for {out}: continue it with --resume, or pass --force to "
                         f"start over")
    out.parent.mkdir(parents=True, exist_ok=True)
    with training_lock(out):
        return _train(scene, config, out, ckpt, name, force, resume, progress, console, box, init)


def _train(scene, config, out, ckpt, name, force, resume, progress, console, box, init):
    from .io.progress import Reporter

    with Reporter(console, enabled=progress, title="train: ") as rep:
        rep.update("preparing", 0.0, "loading torch")  # before torch loads: a log shows life from the first second
        with held():  # cut half-way, the import left a warning about a file torch had open
            from .training import Trainer, TrainResult, validate

        tr = Trainer(scene, config, name, on_progress=lambda phase, f: rep.update(f"preparing: {phase}", f), box=box,
                     init=init)
        if resume:
            tr.load_checkpoint(ckpt)
        def on_step(rec):
            if tr.step % 25 == 0:
                terms = " ".join(f"{k} {v:.1e}" for k, v in rec.items() if k != "lr")
                rep.update("training", tr.progress(), f"step {tr.step} {terms}")

        try:
            rep.update("training", tr.progress(), f"step {tr.step}, {config.optimizer}")
            tr.run(ckpt=ckpt, on_step=on_step)
            model = tr.model()
            try:
                if box is None:
                    rep.update("validating: 1 s rollout against a x100 FDM", 0.0)
                    model.meta.validation = validate(model, scene)
                else:
                    from .training import validate_range

                    secs = config.judge_seconds
                    rep.update(f"validating: {secs:g} s rollouts on a 3 x 3 grid of the box against a x100 FDM", 0.0)
                    model.meta.validation = validate_range(model, scene, box, seconds=secs)
            except Exception as e:  # the whole budget's training is in the network: kept for a rerun to validate
                with contextlib.suppress(Exception):  # a checkpoint that cannot be saved leaves the error as it is
                    tr.save_checkpoint(ckpt)
                    e.add_note(f"the trained network is kept in {ckpt}: the same command with --resume validates it "
                               f"without training again")
                raise
            rep.update("validated", 1.0)
        except KeyboardInterrupt as e:  # Ctrl-C, or SIGTERM raised as errors.Terminated by the CLI
            code = interrupt_exit_code(e)
            what = "terminated" if code == 143 else "interrupted"
            try:
                tr.save_checkpoint(ckpt)
            except Exception as save_error:  # still an interruption (its exit code), said in one line
                raise Interrupted(f"{what} at step {tr.step}; the checkpoint could not be saved "
                                  f"({type(save_error).__name__}: {save_error})", exit_code=code) from None
            raise Interrupted(f"{what} at step {tr.step}; checkpoint saved to {ckpt}; continue with the same command "
                              f"and --resume", exit_code=code) from None
    out = _save_new(model, out, force)
    ckpt.unlink(missing_ok=True)
    return TrainResult(model, out, tr.history)


def _save_new(model, out: Path, force: bool) -> Path:
    """Save the trained model at `out`; a file that appeared there while it trained (the check was at the start) is
    never replaced without force: the model goes beside it under a free name, and a warning says so."""
    import warnings

    try:
        return model.save(out, force=force)
    except FileExistsError:
        for i in range(1, 1000):
            alt = out.with_name(f"{out.stem}-{i}{out.suffix}")
            try:
                path = model.save(alt, force=False)
            except FileExistsError:
                continue
            warnings.warn(f"{out} appeared while training and was kept; the new model was written to {path}")
            return path
        raise


@contextlib.contextmanager
def training_lock(out: Path):
    """Hold `out`.lock for the whole training: a second training to the same --out (which would share the checkpoint
    too) is refused at its start. A lock whose process is gone (killed) is taken over."""
    lock = out.with_name(out.name + ".lock")
    for _ in range(2):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                pid = int(lock.read_text().strip() or 0)
            except (OSError, ValueError):
                pid = 0
            if pid > 0 and _alive(pid):
                raise UsageError(f"another training (process {pid}) is writing {out}; wait for it, or choose another "
                                 f"--out") from None
            lock.unlink(missing_ok=True)  # stale: its process died without releasing it
            continue
        with os.fdopen(fd, "w") as fh:
            fh.write(str(os.getpid()))
        break
    else:
        raise UsageError(f"could not take the lock {lock}; remove it if no training is running")
    try:
        yield
    finally:
        lock.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def range_scene(box, f0: float = 100.0, sample_rate: int = 44100, duration: float = 1.0) -> Scene:
    """The scene a range model trains at: the box's centre bow (geometric in beta) at this pitch and rate.

    Parameters
    ----------
    box : ParamBox
        The bows (beta_lo..beta_hi, vb_lo..vb_hi, a) the model is to play.
    f0 : float
        Hz.
    sample_rate : int
        Hz.
    duration : float
        s.

    Returns
    -------
    Scene

    Examples
    --------
    >>> from bowsynth import api
    >>> from bowsynth.training import ParamBox
    >>> api.range_scene(ParamBox(0.1, 0.2, 0.1, 0.3, 100.0), f0=220).describe()
    'fb=195.487 f0=220 vb=0.2 a=100'
    """
    beta = math.sqrt(max(box.beta_lo, 1e-12) * max(box.beta_hi, 1e-12))
    return Scene(f0=f0, fb=beta * physics.omega(f0), vb=(box.vb_lo + box.vb_hi) / 2, a=box.a, duration=duration,
                 sample_rate=sample_rate)


def model_status(scene: Scene, config, out, box=None, init=None) -> str | None:
    """Why the model file `out` is not what training `scene` (and `box`) with `config` makes, in a few words.

    What `train --update` (and so `make models`) asks before training. Settings a recipe does not name are not
    compared: a model trained by an older version of the trainer stays current until its recipe changes.

    Parameters
    ----------
    scene, config, box
        As `train` takes them.
    out : str or Path
        The model file.
    init : path or str, optional
        The model a refinement starts from (as `train --from`): the file must have been refined from that model as
        it is now.

    Returns
    -------
    str or None
        missing, unreadable (with the loader's reason), or stale (it plays another scene or box, or was trained with
        another budget, seed, batch, window, derivative or rollout weight or network); None when it is what the
        recipe asks for.

    Examples
    --------
    >>> from bowsynth import api
    >>> from bowsynth.scene import Scene
    >>> api.model_status(Scene(), api.make_train_config(Scene(), steps=10), "models/none.safetensors")
    'missing'
    """
    import dataclasses

    from .engines.operator.modelfile import load_model
    from .errors import ModelFileError
    from .training.config import default_model_name

    out = Path(out)
    if not out.exists():
        return "missing"
    try:
        m = load_model(out)
    except (ModelFileError, OSError) as e:
        return f"unreadable ({str(e).splitlines()[0]})"
    if box is not None and box.is_point:
        box = None
    name = default_model_name(scene) if box is None else range_model_name(scene, box)
    if m.meta.name != name:
        return f"stale: it plays {m.meta.name}, the recipe asks for {name}"
    defaults = {f.name: f.default for f in dataclasses.fields(config) if f.default is not dataclasses.MISSING}
    trained = m.meta.training or {}
    for key in ("minutes", "steps", "seed", "batch_states", "rest_linear", "window", "band_seconds"):
        was, want = trained.get(key, defaults.get(key)), getattr(config, key)
        if was != want and not (init is not None and key == "window"):  # a refinement keeps its base's window
            return f"stale: trained with {key} {was}, the recipe asks for {want}"
    was = (trained.get("weights") or {}).get("deriv", 0.0)  # the weight the model trained with, named or default
    if config.deriv is not None and was != config.deriv:
        return f"stale: trained with deriv {was}, the recipe asks for {config.deriv}"
    was = (trained.get("weights") or {}).get("roll", 0.0)
    if was != config.rollout:
        return f"stale: trained with rollout {was}, the recipe asks for {config.rollout}"
    for key in ("width", "depth"):
        was, want = (m.meta.net or {}).get(key), getattr(config.net, key)
        if was != want and init is None:  # a refinement keeps its base's network
            return f"stale: its network has {key} {was}, the recipe asks for {want}"
    was = trained.get("refined_from")
    if init is not None:
        from .engines.operator.choose import as_model

        try:
            base = as_model(init).id
        except (ModelFileError, OSError, UsageError) as e:
            return f"stale: its base {init} is unreadable ({str(e).splitlines()[0]})"
        if was != base:
            return f"stale: refined from {was}, the recipe's base is {base}"
    elif was is not None:
        return f"stale: refined from {was}, the recipe trains from scratch"
    return None


def range_model_name(scene: Scene, box) -> str:
    """The name a range model trained for `box` at `scene`'s pitch gets (its file's stem by default).

    Examples
    --------
    >>> from bowsynth.training import ParamBox
    >>> range_model_name(Scene(f0=220), ParamBox(0.1, 0.2, 0.1, 0.3, 100.0))
    'range_fb138.2-276.5_f0220_vb0.1-0.3_a100'
    """
    w = scene.omega
    return (f"range_fb{box.beta_lo * w:.4g}-{box.beta_hi * w:.4g}_f0{scene.f0:g}_vb{box.vb_lo:g}-{box.vb_hi:g}"
            f"_a{box.a:g}")


def make_train_config(scene: Scene, window_ms=None, width=None, depth=None, **fields):
    """A TrainConfig from keyword settings (None means the config's default).

    Parameters
    ----------
    scene : Scene
        What `window_ms` is measured against (the window in units of its w).
    window_ms : float, optional
        The window in ms at the scene's pitch.
    width, depth : int, optional
        The network's.
    **fields
        Other `bowsynth.training.TrainConfig` fields; a step budget alone (steps= without minutes=) has no time
        limit.

    Returns
    -------
    TrainConfig

    Raises
    ------
    UsageError
        An unknown setting, or a window that holds no sample.

    Examples
    --------
    >>> from bowsynth import api
    >>> from bowsynth.scene import Scene
    >>> c = api.make_train_config(Scene(), steps=10)
    >>> c.steps, c.minutes
    (10, None)
    """
    import dataclasses

    from .engines.operator.npnet import NetConfig  # torch-free: `train --update` on a current model loads no torch
    from .training import TrainConfig

    known = {f.name for f in dataclasses.fields(TrainConfig)}
    unknown = set(fields) - known
    if unknown:
        raise UsageError(f"unknown training setting(s): {', '.join(sorted(unknown))}")
    fields = {k: v for k, v in fields.items() if v is not None}
    if "minutes" not in fields and "steps" in fields:
        fields["minutes"] = None  # a step budget alone
    if window_ms is not None:
        if not (math.isfinite(window_ms) and window_ms > 0):
            raise UsageError(f"--window-ms must be > 0, got {window_ms:g}")
        if window_ms / 1e3 * scene.sample_rate < 1:
            raise UsageError(f"--window-ms {window_ms:g} holds no sample at {scene.sample_rate} Hz (at least "
                             f"{1e3 / scene.sample_rate:.4g} ms)")
        fields["window"] = scene.omega * window_ms / 1e3
    net = {k: v for k, v in (("width", width), ("depth", depth)) if v is not None}
    if net:
        fields["net"] = NetConfig(**net)
    return TrainConfig(**fields)
