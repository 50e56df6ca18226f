"""Work and memory a request will take, estimated before any work: past a sane bound the CLI and the API refuse with
the estimate (one line, exit 2) unless forced, instead of running for hours or dying of memory half-way.

The rates are measured on this project's 2-core machine (shared by others at the time; see docs/bad_inputs.md):
the compiled FDM runs about 13 million scheme steps per second (a 20 s render at x200: 176 M steps in 13.3 s), so
FDM_STEPS_PER_S errs on the slow side.
"""

from __future__ import annotations

from ..errors import UsageError

FDM_STEPS_PER_S = 1.0e7
MAX_SECONDS = 120.0  # estimated FDM wall time beyond which --force is needed
MAX_BYTES = 2 * 1024**3  # estimated memory beyond which --force is needed
BYTES_PER_SAMPLE = 96  # measured peak RSS per output sample of a 200 s render to a file: 86 (FDM), 105 (operator)


def _human_seconds(s: float) -> str:
    if s < 120:
        return f"{s:.0f} s"
    if s < 7200:
        return f"{s / 60:.0f} min"
    return f"{s / 3600:.1f} h"


def fdm_seconds(scene, oversample: int) -> float:
    """Estimated wall time of an FDM render of `scene` at `oversample` (after any raise for the step bounds)."""
    return scene.n_samples * oversample / FDM_STEPS_PER_S


def check_fdm(scene, oversample: int = 1, force: bool = False, what: str = "this FDM render") -> None:
    """Refuse an FDM render estimated beyond MAX_SECONDS unless forced (the oversampling the FDM would raise to
    for its step bounds counts, not just the one asked for)."""
    from .fdm import check_oversample

    os_ = check_oversample(scene, oversample, warn=False)
    secs = fdm_seconds(scene, os_)
    if secs > MAX_SECONDS and not force:
        raise UsageError(f"{what} would take about {_human_seconds(secs)} ({scene.n_samples * os_:.3g} scheme steps at "
                         f"x{os_}, ~{FDM_STEPS_PER_S:.0e} steps/s); pass --force to run it anyway")


def check_fdm_voices(scenes, force: bool = False) -> None:
    """Refuse FDM renders of many voices (one after another) whose total estimate passes MAX_SECONDS."""
    from .fdm import check_oversample

    secs = sum(fdm_seconds(s, check_oversample(s, 1, warn=False)) for s in scenes)
    if secs > MAX_SECONDS and not force:
        raise UsageError(f"the FDM renders of these {len(scenes)} voices would take about {_human_seconds(secs)} "
                         f"(~{FDM_STEPS_PER_S:.0e} steps/s); use the operator, or pass --force to run them anyway")


def check_memory(n_samples: int, voices: int = 1, force: bool = False, what: str = "this render") -> None:
    """Refuse a render whose arrays would pass MAX_BYTES unless forced."""
    need = n_samples * voices * BYTES_PER_SAMPLE
    if need > MAX_BYTES and not force:
        raise UsageError(f"{what} would need about {need / 1024**3:.1f} GB of memory ({voices} voice(s) x "
                         f"{n_samples} samples); shorten it, or pass --force to try anyway")


MIX_BYTES_PER_SAMPLE = 48  # measured: a 0.1 s note at start 3000 s peaked at 6.4 GB (132 M mix samples)


def check_mix(starts, scenes, force: bool = False) -> None:
    """Refuse a mix whose buffers (as long as the latest note's end, whatever the notes' own lengths) would pass
    MAX_BYTES unless forced: a note far into the piece costs the mix, not its voice."""
    n = max((int(round(t * s.sample_rate)) + s.n_samples for t, s in zip(starts, scenes)), default=0)
    need = n * MIX_BYTES_PER_SAMPLE
    if need > MAX_BYTES and not force:
        end = n / scenes[0].sample_rate
        raise UsageError(f"the mix would be {_human_seconds(end)} long (the last note ends at {end:.4g} s) and need "
                         f"about {need / 1024**3:.3g} GB of memory; pass --force to try anyway")


def check_request(scene, engine: str = "operator", oversample: int = 1, force: bool = False, extra_voices: int = 0
                  ) -> None:
    """Every estimate for rendering a Scene or a list of Scenes with `engine` ('operator' or 'fdm'); `extra_voices`
    counts buffers beside the voices (a mix)."""
    scenes = list(scene) if isinstance(scene, (list, tuple)) else [scene]
    if not scenes:
        return
    what = "this render" if len(scenes) == 1 else f"these {len(scenes)} voices"
    check_memory(max(s.n_samples for s in scenes), len(scenes) + extra_voices, force, what)
    if str(getattr(engine, "value", engine)) == "fdm":
        if len(scenes) == 1:
            check_fdm(scenes[0], oversample, force)
        else:
            check_fdm_voices(scenes, force)
