"""Errors a user can act on (the CLI prints them as one line; anything else is a bug), and interruptions: Ctrl-C and
SIGTERM raised as exceptions, and held where one raised between two bytecodes would break what runs.

Python runs a signal's handler in the main thread between two bytecodes, wherever that thread is, and the CLI's raises
(KeyboardInterrupt, Terminated). Most code is safe from that; some is not: threading's locks and concurrent.futures'
waits are written in Python, and an exception raised half-way through them left a lock held or released twice. A
Ctrl-C at the start of training's FDM data (a wait on 15625 futures) hung the process for good (CI), or
ended it with "internal error: RuntimeError: release unlocked lock". `held()` keeps the signals from such a block and
acts on them once it is done; `compiled.share()` runs work over threads inside it.
"""

import signal
import threading
from contextlib import contextmanager


class BowsynthError(Exception):
    """A runtime failure with a message meant for the user (CLI exit code 1)."""

    exit_code = 1


class UsageError(BowsynthError):
    """Bad input from the user: a value, a path, a flag (CLI exit code 2)."""

    exit_code = 2


class SceneError(UsageError):
    """A scene value outside its allowed range."""


class ModelFileError(BowsynthError):
    """A model file that is missing, corrupt, foreign or of another format version."""


class DomainError(BowsynthError):
    """A scene or a rollout outside the domain a model was trained on."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread like Ctrl-C so that every cleanup path runs (finally blocks, temp files,
    training's checkpoint); the CLI exits 143 (130 for Ctrl-C)."""

    exit_code = 143


def interrupt_exit_code(e: BaseException) -> int:
    """The exit code for an interruption: 143 for SIGTERM, 130 for Ctrl-C."""
    return getattr(e, "exit_code", 130)


HELD = (signal.SIGINT, signal.SIGTERM)
_caught: list[int] = []  # signals a held block's stand-in handler took, oldest first
_holding = [False]  # a held() block is on in the main thread


def _record(signum, frame) -> None:
    _caught.append(signum)


@contextmanager
def held():
    """SIGINT and SIGTERM wait until the block is done, then act as they would have (their handlers raise where the
    block ends): a checkpoint is written whole, an import is not cut half-way, threads are not left holding a lock.

    Done in the main thread (where Python runs handlers) by swapping the handlers for one that only records, whichever
    thread the kernel hands the signal to (torch's threads do not block it); elsewhere a no-op. Not by blocking the
    signals in this thread: the kernel then hands them to another thread, and 3 in 100 signals sent that way during
    share() were never seen by Python at all (0 in 100 with the handlers swapped). Nested
    blocks hold once, for the outermost."""
    if threading.current_thread() is not threading.main_thread() or _holding[0]:
        yield
        return
    _caught.clear()
    old = {}
    _holding[0] = True
    try:
        for sig in HELD:
            h = signal.getsignal(sig)
            if h is not signal.SIG_IGN and h is not None:
                old[sig] = signal.signal(sig, _record)
        yield
    finally:
        _holding[0] = False
        for sig, h in old.items():
            signal.signal(sig, h)
        caught, _caught[:] = list(_caught), []
        if caught:  # even over an exception of the block's: what the user asked for comes first
            h = old[caught[0]]
            if callable(h):
                h(caught[0], None)  # raises, as the handler would have (KeyboardInterrupt, errors.Terminated)
            else:
                signal.raise_signal(caught[0])


def pending() -> bool:
    """Whether a held signal waits to be acted on (inside held() in the main thread; callable from any thread)."""
    return bool(_caught)
