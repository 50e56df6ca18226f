"""`bowsynth train`: a point model, a range model over a box of bows, or the models a score needs."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..errors import UsageError
from .app import (AOpt, F0Opt, FbOpt, P0Opt, PresetOpt, Q0Opt, VbOpt, app, err, fmt_num, range_validation_text,
                  scene_from_flags, tell)


@app.command()
def train(
    preset: Optional[str] = PresetOpt, f0: Optional[float] = F0Opt, fb: Optional[str] = FbOpt,
    vb: Optional[str] = VbOpt, a: Optional[float] = AOpt,
    q0: Optional[float] = Q0Opt, p0: Optional[float] = P0Opt,
    minutes: Optional[float] = typer.Option(None, "--minutes", help="Wall-clock budget in minutes (default 5 when --steps is not given; at most a day)."),
    steps: Optional[int] = typer.Option(None, "--steps", help="Optimiser steps (with --minutes, whichever ends first)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (default 0): same seed and machine, same model (with --steps)."),
    optimizer: Optional[str] = typer.Option(None, "--optimizer", help="soap (pytorch-optimizer's SOAP, default) or adam."),
    lbfgs: Optional[float] = typer.Option(None, "--lbfgs", help="Share of the --minutes budget for an L-BFGS finish (0 to 0.9, default 0)."),
    hybrid: bool = typer.Option(True, "--hybrid/--no-hybrid", help="Add the FDM data loss (default) or train purely physics-informed."),
    window_ms: Optional[float] = typer.Option(None, "--window-ms", help="Window length in ms at the scene's f0 (default: one period of the free oscillator)."),
    width: Optional[int] = typer.Option(None, "--width", help="Hidden width of branch and trunk (default 64)."),
    depth: Optional[int] = typer.Option(None, "--depth", help="Hidden layers of branch and trunk (default 4)."),
    rest_linear: bool = typer.Option(False, "--rest-linear", help="Point models whose note starts slowly (v_B near 0.3): carry the bowed mass's flow linearised at its rest state, so the onset's growth rate is exact (docs/BENCHMARKS.md)."),
    from_model: Optional[str] = typer.Option(None, "--from", help="Refine a trained range model (a file, or a name such as soft-range) for these bows or this score: its network is kept and trained further on their data only (the bows must lie in its box)."),
    batch: Optional[int] = typer.Option(None, "--batch", help="Window starts per optimiser step (default 1024); a GPU takes more per second."),
    device: Optional[str] = typer.Option(None, "--device", help="auto (a CUDA GPU where torch sees one, default), cpu or cuda; the model records which."),
    band_seconds: Optional[float] = typer.Option(None, "--band-seconds", help="Seconds (at --f0) of the renders from rest the training data comes from, and of a range model's selection and validation rollouts (default 1; up to 30): longer for bows whose notes take seconds to grow."),
    deriv: Optional[float] = typer.Option(None, "--deriv", help="Weight of the loss that matches the network's time derivative to the ODE's on the true trajectories (default 0.1 for range models, 0 for point models): it sharpens the stick capture's knee (docs/BENCHMARKS.md)."),
    rollout: Optional[float] = typer.Option(None, "--rollout", help="Weight of the loss on chains of 16 windows rolled out as a render does, each from the network's own end state, against the FDM (default 0: none): a held note's pitch is what the windows' small errors add up to; seam-roll trained at 1e-5, where it matches the data term (docs/BENCHMARKS.md)."),
    n_data: Optional[int] = typer.Option(None, "--n-data", help="FDM training trajectories (hybrid) drawn from the scene's band (default 4096)."),
    checkpoint_every: Optional[float] = typer.Option(None, "--checkpoint-every", help="Seconds between checkpoints (default 60)."),
    out_path: Optional[Path] = typer.Option(None, "--out", "-o", help="Model file (default ./models/<name>.safetensors)."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing model file."),
    resume: bool = typer.Option(False, "--resume", help="Continue from the checkpoint beside --out."),
    update: bool = typer.Option(False, "--update", help="With --config: train only if the model file is missing, unreadable or stale against the recipe (replacing it), continuing from its checkpoint if an interrupted run left one; otherwise say it is up to date (`make models`)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress (a bar in a terminal, a line every 10 s elsewhere)."),
    score: Optional[Path] = typer.Option(None, "--score", help="Train a range model for the bows this score (.toml) or MIDI file (.mid) plays."),
    a4: Optional[float] = typer.Option(None, "--a4", help="With --score: the pitch of A4 in Hz (default 440)."),
    config: Optional[Path] = typer.Option(None, "--config", help="A training recipe (TOML: these flags' names as keys, "
                                          "e.g. the shipped models' models/*.toml); flags given override it."),
    atlas: Optional[list[Path]] = typer.Option(None, "--atlas", help="Train an atlas's units: a directory of recipes (and its stages/) or recipe files, each as --config R --update, each after the unit it refines."),
    workers: int = typer.Option(1, "--workers", "-j", min=1, max=1024, help="With --atlas: Ray workers on this machine (1: one unit after another here)."),
    address: Optional[str] = typer.Option(None, "--address", help="With --atlas: a Ray cluster's address (default RAY_ADDRESS)."),
):
    """Train a PI-DeepONet for a scene (its F_B / w, v_B, a and the states a render from its initial state visits),
    or for a playing range: --fb LO:HI and/or --vb LO:HI (at --f0), or --score FILE (the bows a score or MIDI file
    plays). A range model plays any bow inside its box and follows gestures through it."""
    from .. import api
    from ..engines.operator.modelfile import unpicked_text
    from ..training.recipe import load_recipe

    if atlas:
        return _atlas(atlas, workers, address)
    if config is not None:
        given = dict(preset=preset, f0=f0, fb=fb, vb=vb, a=a, minutes=minutes, steps=steps, seed=seed,
                     rest_linear=rest_linear or None, out=out_path,
                     batch=batch, width=width, device=device, window_ms=window_ms, band_seconds=band_seconds,
                     deriv=deriv, rollout=rollout)
        given["from"] = from_model
        r = load_recipe(config)
        merged = {k: (v if v is not None else r.get(k)) for k, v in given.items()}
        preset, f0, fb, vb, a = (merged[k] for k in ("preset", "f0", "fb", "vb", "a"))
        minutes, steps, seed, out_path = merged["minutes"], merged["steps"], merged["seed"], merged["out"]
        rest_linear = bool(merged["rest_linear"])
        batch, width, device, window_ms = merged["batch"], merged["width"], merged["device"], merged["window_ms"]
        from_model, band_seconds, deriv = merged["from"], merged["band_seconds"], merged["deriv"]
        rollout = merged["rollout"]
    scene, box = _scene_and_box(preset, f0, fb, vb, a, q0, p0, score, a4)
    cfg = _train_config(scene, box, minutes=minutes, steps=steps, seed=seed, optimizer=optimizer, lbfgs=lbfgs,
                        hybrid=hybrid, window_ms=window_ms, width=width, depth=depth, n_data=n_data,
                        checkpoint_every=checkpoint_every, rest_linear=rest_linear, batch=batch, device=device,
                        band_seconds=band_seconds, deriv=deriv, rollout=rollout)
    if update:
        if config is None or out_path is None:
            raise UsageError("--update compares a model file with its recipe: give --config (a recipe with `out`)")
        why = api.model_status(scene, cfg, out_path, box, init=from_model)
        if why is None:
            tell(quiet, f"{out_path} is up to date with {config}")
            return
        from ..training.config import checkpoint_path

        resume = resume or checkpoint_path(out_path).exists()
        force = True  # the recipe's own file, missing, unreadable or stale: replaced is what --update is for
        tell(quiet, f"{out_path}: {why}; training it" + (" (continuing from its checkpoint)" if resume else ""))
    res = api.train(scene, config=cfg, out=out_path, force=force, resume=resume, progress=not quiet, console=err,
                    box=box, init=from_model)
    v = res.model.meta.validation
    tell(False, f"model written to {res.path} ({res.model.id})")
    if res.model.failure:
        err.print(f"warning: {res.model.failure}: this model is {unpicked_text(res.model.meta)}; train longer "
                  f"(--minutes) before rendering with it", soft_wrap=True)
    if v.get("error"):
        return
    if box is not None and not box.is_point:  # a score with one bow trains a point model
        tell(False, range_validation_text(v))
        return
    tell(False, f"validation (1 s from the scene's initial state vs FDM x{v.get('ref_oversample')}): "
                f"NMSE(p) {fmt_num(v.get('nmse'), '.3g')}, NCC {fmt_num(v.get('ncc_percent'), '.3f')} %, "
                f"pitch error {fmt_num(v.get('cents'), '+.3f')} cents")


def _scene_and_box(preset, f0, fb, vb, a, q0, p0, score, a4):
    """The scene a training renders at and its box of bows (None: a point model), from train's flags."""
    if score is not None:
        if fb is not None or vb is not None or preset is not None:
            raise UsageError("--score trains for the bows the score plays: drop --fb, --vb and --preset")
        return _score_box(score, a4)
    if (fb is not None and ":" in str(fb)) or (vb is not None and ":" in str(vb)):
        return _range_box(preset, f0, fb, vb, a)
    scene = scene_from_flags(preset, f0, fb, vb, a, None, None, q0, p0)
    if scene.varying:
        raise UsageError("train takes a number or a range LO:HI for --fb and --vb, not a curve (a range model "
                         "follows curves inside its range): e.g. --fb 50:200")
    return scene, None


def _train_config(scene, box, minutes=None, steps=None, seed=None, optimizer=None, lbfgs=None, hybrid=True,
                  window_ms=None, width=None, depth=None, n_data=None, checkpoint_every=None, rest_linear=False,
                  batch=None, device=None, band_seconds=None, deriv=None, rollout=None):
    """The TrainConfig of train's flags (a recipe's keys are those flags' names): the one mapping of flags to its
    fields, for a training and for `recipe_status`'s comparison alike."""
    from .. import api

    return api.make_train_config(scene, minutes=minutes, steps=steps, seed=seed, optimizer=optimizer,
                                 lbfgs_fraction=lbfgs, hybrid=hybrid, window_ms=window_ms, width=width, depth=depth,
                                 n_data=n_data if box is None else None,
                                 range_n_data=n_data if box is not None else None,
                                 checkpoint_seconds=checkpoint_every, rest_linear=rest_linear or None,
                                 batch_states=batch, device=device, band_seconds=band_seconds, deriv=deriv,
                                 rollout=rollout)


def recipe_status(recipe: Path) -> str | None:
    """api.model_status of a recipe's model file against the recipe alone (what `train --config R --update` would
    find, flags aside): None when it is up to date."""
    from .. import api
    from ..training.recipe import load_recipe

    r = load_recipe(recipe)
    scene, box = _scene_and_box(r.get("preset"), r.get("f0"), r.get("fb"), r.get("vb"), r.get("a"), None, None,
                                None, None)
    cfg = _train_config(scene, box, **{k: r.get(k) for k in ("minutes", "steps", "seed", "width", "batch", "device",
                                                             "rest_linear", "window_ms", "band_seconds",
                                                             "deriv", "rollout")})
    return api.model_status(scene, cfg, r.get("out", recipe.with_suffix(".safetensors")), box, init=r.get("from"))


def _range_box(preset, f0, fb, vb, a):
    """--fb / --vb as ranges: the ParamBox (beta = F_B / w at --f0) and the scene its band is rendered at."""
    from .. import api
    from ..training.ranges import ParamBox, parse_range

    base = scene_from_flags(preset, f0, None, None, a, None, None, None, None)
    fbr = parse_range(fb, "fb") if fb is not None else (float(base.fb),) * 2
    vbr = parse_range(vb, "vb") if vb is not None else (float(base.vb),) * 2
    for (lo, hi), name in ((fbr, "fb"), (vbr, "vb")):
        if lo < 0:
            raise UsageError(f"--{name} range must be >= 0, got {lo:g}:{hi:g}")
    box = ParamBox.from_forces(fbr, vbr, base.f0, base.a)
    if box.is_point:  # `--fb 100:100` is the point 100
        return base.replace(fb=fbr[0], vb=vbr[0]), None
    return api.range_scene(box, base.f0, base.sample_rate), box


def _score_box(path, a4):
    """--score: the box of bows a score or MIDI file plays (its notes' sustains), at its lowest pitch's f0 (the
    dynamics in tau depend on the bow only; the pitch sets where the windows fall)."""
    from .. import api
    from ..errors import UsageError as _U
    from ..music.perform import score_box
    from ..music.score import load_score as load_notes
    from ..training.ranges import ParamBox

    notes = load_notes(path, a4=a4)
    b = score_box(notes)
    if b["a"][0] != b["a"][1]:
        raise _U(f"{path}: its notes use several friction shapes a ({b['a'][0]:g}..{b['a'][1]:g}); one model "
                 f"covers one a: split the score")
    box = ParamBox(b["beta"][0], b["beta"][1], b["vb"][0], b["vb"][1], b["a"][0])
    return api.range_scene(box, b["f0"][0]), box


def _atlas(spec, workers: int, address) -> int:
    """`train --atlas`: the units as tasks, one progress line, a summary; exit 1 where a unit failed."""
    from ..training.atlas import atlas_recipes, run_atlas

    units = atlas_recipes(spec)
    with err.status(f"atlas: 0/{len(units)} units") as status:
        def progress(done, total, running, eta=None):
            left = "" if eta is None else f", about {eta / 60:.0f} min left at the pace so far"
            status.update(f"atlas: {done}/{total} units done, {running} running{left}")
        results = run_atlas(units, workers=workers, address=address, progress=progress)
    failed = 0
    for r in results:
        if "note" in r:
            err.print(f"note: {r['note']}", soft_wrap=True)
            continue
        state = "ok" if r["rc"] == 0 else ("skipped" if r["rc"] is None else "FAILED")
        failed += state != "ok"
        tell(False, f"{state:7} {r['recipe']} ({r['seconds']:.0f} s): {r['said']}")
    tell(False, f"atlas: {sum(1 for r in results if r.get('rc') == 0)} of {len(units)} units trained or up to date"
         + (f", {failed} failed or skipped" if failed else ""))
    return 1 if failed else 0
