"""Command-line interface: a thin layer over the Python API. Errors print as one line; --debug shows tracebacks."""

from __future__ import annotations

import os
import signal
import sys
import warnings

from typer.exceptions import Abort, Exit, TyperException

from ..errors import BowsynthError, Terminated, UsageError, interrupt_exit_code
from .app import app, err, run_state

# each module registers its command on `app` when imported; the order here is the order of `--help`
from . import listing, render, train, compare, bench, score, play, fit, dataset  # noqa: E402,F401  isort: skip


def _raise_on_signal(signum, frame):
    # raised in the main thread between bytecodes, so `finally` blocks and temp-file cleanup run; a long compiled
    # call (the core releases the GIL but Python runs handlers between bytecodes) delays it until the call returns
    # (the FDM runs in chunks of well under a second for this)
    run_state["signal"] = signum
    # an import cut by the signal leaves its .pyc open: a "warning: unclosed file" line before "interrupted" (1 run
    # in 27 of a Ctrl-C at start-up); what an interruption leaves unclosed is no news to whoever interrupted
    warnings.filterwarnings("ignore", category=ResourceWarning)
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _install_signal_handlers() -> dict:
    """Install the handlers; returns the previous ones (main() restores them, for callers such as tests)."""
    import threading

    run_state["signal"] = None
    if threading.current_thread() is not threading.main_thread():
        return {}
    old = {signal.SIGTERM: signal.signal(signal.SIGTERM, _raise_on_signal)}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not when started with SIGINT ignored
        old[signal.SIGINT] = signal.signal(signal.SIGINT, _raise_on_signal)
    return old


def _exit_interrupted(code: int) -> None:
    err.print("terminated" if code == 143 else "interrupted")
    # CPython remembers a KeyboardInterrupt that left code run by exec() or eval() of a string (a namedtuple's or a
    # dataclass's generated methods, say) as unhandled even when it was caught, and `python -m bowsynth` then ends
    # killed by SIGINT instead of with this exit code (1 run in 5 of a test under load, Ctrl-C at start-up). Running
    # such code once more, with no interrupt, clears the flag.
    exec("")
    sys.exit(code)


def main() -> None:
    """Entry point: run the app, turning known failures into one line on stderr and an exit code."""
    old = _install_signal_handlers()
    try:
        _run()
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _run() -> None:
    debug = "--debug" in sys.argv[1:]
    # numpy's OpenBLAS runs the rollout's small products on every core; on a busy 2-core machine each product then
    # waited on the other thread (measured 7-12 ms for a 257x64 by 64x64 product, 0.06-0.1 ms on one thread)
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    warnings.simplefilter("default")
    warnings.filterwarnings("ignore", message=".*torch.jit.script.*")  # raised inside pytorch-optimizer
    warnings.formatwarning = lambda msg, cat, *a, **k: f"warning: {msg}\n"
    try:
        # a process's argv cannot hold a NUL byte; main() called in-process can, and typer's path checks then raise
        # ValueError from os.stat
        if any("\x00" in a for a in sys.argv[1:]):
            raise UsageError("an argument contains a NUL byte (\\x00): no option value or file name can")
        rv = app(standalone_mode=False)
    except BowsynthError as e:
        if debug:
            raise
        err.print(f"error: {e}", soft_wrap=True, markup=False)  # messages quote TOML tables: [[voice]]
        sys.exit(e.exit_code)
    except Abort:
        _exit_interrupted(130)
    except KeyboardInterrupt as e:
        _exit_interrupted(interrupt_exit_code(e))
    except TyperException as e:
        if debug:
            raise
        err.print(f"error: {e.format_message()}", soft_wrap=True)
        sys.exit(2)
    except Exit as e:
        sys.exit(e.exit_code)
    except MemoryError:  # past the estimates (--force): what the machine lacks, exit 1, and no half-written file
        if debug:
            raise
        err.print("error: out of memory: the job is larger than this machine can hold (see the estimate without "
                  "--force)", soft_wrap=True)
        sys.exit(1)
    except Exception as e:  # a bug: still one line unless --debug
        if debug:
            raise
        if isinstance(e, OSError) and e.filename:
            # the file system refused a named path (a folder without write permission, a read-only mount, a full
            # disk): what the user must change, not a bug
            other = f" -> {e.filename2}" if e.filename2 else ""
            err.print(f"error: {e.filename}{other}: {e.strerror or type(e).__name__}", soft_wrap=True, markup=False)
            sys.exit(1)
        notes = "".join(f"; {n}" for n in getattr(e, "__notes__", ()))
        err.print(f"internal error: {type(e).__name__}: {e} (rerun with --debug for the traceback){notes}",
                  soft_wrap=True)
        sys.exit(1)
    # with standalone_mode=False typer turns a KeyboardInterrupt inside a command into a *returned* 130 (and an
    # explicit Exit into its returned code): without this check Ctrl-C exited 0
    if run_state.get("signal") is not None:
        _exit_interrupted(143 if run_state["signal"] == signal.SIGTERM else 130)
    if isinstance(rv, int) and rv != 0:
        if rv == 130:
            _exit_interrupted(130)
        sys.exit(rv)
