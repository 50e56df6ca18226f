"""Command-line interface: a thin layer over the Python API. Errors print as one line; --debug shows tracebacks."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path
from typing import Optional

import typer
from typer.exceptions import Abort, Exit, TyperException
from rich.console import Console

from .errors import BowsynthError, UsageError

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="bowsynth: a bowed mass-spring synthesizer driven by a physics-informed DeepONet.")
err = Console(stderr=True, highlight=False)
out = Console(highlight=False)
_state = {"debug": False}

# Scene flags shared by render / train / compare. None means "take the preset's value, else the default".
PresetOpt = typer.Option(None, "--preset", help="Preset scene name (see `bowsynth presets`); flags override it.")
F0Opt = typer.Option(None, "--f0", help="Pitch of the mass-spring, Hz (default 100).")
FbOpt = typer.Option(None, "--fb", help="Bow force per unit mass F_B, m/s^2 (default 100).")
VbOpt = typer.Option(None, "--vb", help="Bow velocity v_B, m/s (default 0.2).")
AOpt = typer.Option(None, "--a", help="Friction shape a, s^2/m^2 (default 100).")
DurOpt = typer.Option(None, "--duration", "-d", help="Duration, s (default 1.0).")
RateOpt = typer.Option(None, "--sample-rate", "--sr", help="Sample rate, Hz (default 44100).")
Q0Opt = typer.Option(None, "--q0", help="Initial q = w u(0), m/s (default 0).")
P0Opt = typer.Option(None, "--p0", help="Initial velocity u_t(0), m/s (default 0).")


def _scene(preset, f0, fb, vb, a, duration, sample_rate, q0, p0):
    from .scene import make_scene

    return make_scene(preset, f0=f0, fb=fb, vb=vb, a=a, duration=duration, sample_rate=sample_rate, q0=q0, p0=p0)


def _say(quiet: bool, msg: str) -> None:
    if not quiet:
        out.print(msg, soft_wrap=True)


@app.callback()
def _main(debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors.")):
    _state["debug"] = debug


@app.command()
def presets():
    """List the preset scenes."""
    from .scene import list_presets, load_preset, preset_description

    for name in list_presets():
        fields = " ".join(f"{k}={v:g}" for k, v in load_preset(name).items())
        out.print(f"[bold]{name}[/bold]  {fields}\n    {preset_description(name)}")


@app.command()
def render(
    output: Path = typer.Argument(..., help="WAV file to write (32-bit float)."),
    method: str = typer.Option("operator", "--method", "-m", help="Engine: operator (trained PI-DeepONet) or fdm."),
    preset: Optional[str] = PresetOpt, f0: Optional[float] = F0Opt, fb: Optional[float] = FbOpt,
    vb: Optional[float] = VbOpt, a: Optional[float] = AOpt, duration: Optional[float] = DurOpt,
    sample_rate: Optional[int] = RateOpt, q0: Optional[float] = Q0Opt, p0: Optional[float] = P0Opt,
    oversample: int = typer.Option(1, "--oversample", help="FDM only: render at this multiple of the sample rate."),
    model: Optional[Path] = typer.Option(None, "--model", help="Operator model file (default: the model covering the scene)."),
    signal: str = typer.Option("u", "--signal", help="Signal to write: u (displacement, as the paper) or p (velocity)."),
    fallback: str = typer.Option("none", "--fallback", help="If the operator leaves its domain: none (stop) or fdm."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing on success."),
):
    """Render a scene to a WAV file."""
    from . import api
    from .wav import check_output_path, write_wav

    if method not in ("operator", "fdm"):
        raise UsageError(f"--method must be operator or fdm, got {method!r}")
    if signal not in ("u", "p"):
        raise UsageError(f"--signal must be u or p, got {signal!r}")
    if fallback not in ("none", "fdm"):
        raise UsageError(f"--fallback must be none or fdm, got {fallback!r}")
    if oversample < 1:
        raise UsageError(f"--oversample must be >= 1, got {oversample}")
    scene = _scene(preset, f0, fb, vb, a, duration, sample_rate, q0, p0)
    check_output_path(output)
    if method == "fdm":
        r = api.render_fdm(scene, oversample=oversample)
    else:
        r = api.render_operator(scene, model=model, fallback=fallback)
    write_wav(output, r, signal=signal)
    model_note = f", model {r.info['model_id']}" if r.info.get("model_id") else ""
    _say(quiet, f"wrote {output}: {scene.duration:g} s at {scene.sample_rate} Hz, method {r.method}{model_note}; "
                f"rendered in {r.seconds * 1e3:.1f} ms ({r.realtime_factor:.0f}x real time)")
    for note in r.info.get("notes", []):
        _say(quiet, note)


@app.command()
def bench(
    what: str = typer.Argument("all", help="What to benchmark: fdm, or all (FDM and operators, speed against error)."),
    quick: bool = typer.Option(False, "--quick", help="A small, fast run."),
    json_out: bool = typer.Option(False, "--json", help="Print JSON instead of Markdown."),
):
    """Benchmark speed against error."""
    import json

    from . import bench as B

    if what not in ("fdm", "all"):
        raise UsageError(f"bench target must be fdm or all, got {what!r}")
    rows = B.bench_fdm(quick=quick)
    out.print(json.dumps(rows, indent=2) if json_out else B.fdm_table(rows), soft_wrap=True)


def main() -> None:
    """Entry point: run the app, turning known failures into one line on stderr and an exit code."""
    debug = "--debug" in sys.argv[1:]
    warnings.simplefilter("default")
    warnings.formatwarning = lambda msg, cat, *a, **k: f"warning: {msg}\n"
    try:
        app(standalone_mode=False)
    except BowsynthError as e:
        if debug:
            raise
        err.print(f"error: {e}", soft_wrap=True)
        sys.exit(e.exit_code)
    except Abort:
        err.print("aborted")
        sys.exit(130)
    except KeyboardInterrupt:
        err.print("interrupted")
        sys.exit(130)
    except TyperException as e:
        if debug:
            raise
        err.print(f"error: {e.format_message()}", soft_wrap=True)
        sys.exit(2)
    except Exit as e:
        sys.exit(e.exit_code)
    except Exception as e:  # a bug: still one line unless --debug
        if debug:
            raise
        err.print(f"internal error: {type(e).__name__}: {e} (rerun with --debug for the traceback)", soft_wrap=True)
        sys.exit(1)
