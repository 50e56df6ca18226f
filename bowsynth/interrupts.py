"""Where Ctrl-C and SIGTERM may not land, and work shared over threads that a signal cuts short cleanly.

Python runs a signal's handler in the main thread between two bytecodes, wherever that thread is, and the CLI's raises
(KeyboardInterrupt, errors.Terminated). Most code is safe from that; some is not: threading's own locks and
concurrent.futures' waits are written in Python, and an exception raised half-way through them left a lock held or
released twice. A Ctrl-C at the start of training's FDM data (a thousand-future wait) hung the process for good in
3 of ~150 tries, or ended it with "internal error: RuntimeError: release unlocked lock" (scratch/s52, session 52's
note): the flaky `test_sigint_during_training_ends_in_one_line[during-data-preparation]` of CI.

`held()` keeps the signals from the block and acts on them once it is done; `share()` runs work over threads inside it
and stops taking work when a signal is waiting, so the signal still ends a long job within one item per thread.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

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
    share() were never seen by Python at all (scratch/s52/hang2.py; 0 in 100 with the handlers swapped). Nested
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


def _block_held() -> None:
    # the pool's threads never take the signals: the kernel hands them to the main thread, which acts on them
    try:
        signal.pthread_sigmask(signal.SIG_BLOCK, HELD)
    except (AttributeError, OSError, ValueError):  # no POSIX thread signals here
        pass


_END = object()
_pool = None  # a ThreadPoolExecutor whose threads block the signals (_block_held)


def share(run, items, n_threads: int, on_item=None) -> None:
    """run(item) for each of items on up to n_threads threads: this one and the pool's, each taking the next item as
    it is free (heaviest first is the caller's order to give). The signals are held meanwhile (held()): one that comes
    stops the threads taking items, and its handler raises once they are all back, so a long job still ends within
    one item per thread. on_item(done) runs in this thread after each item it finishes (done: items finished in
    all). A thread's exception is raised here once the others are back."""
    global _pool
    queue = iter(list(items))
    lock = threading.Lock()
    done, stop = [0], [False]

    def take():
        with lock:
            return _END if stop[0] else next(queue, _END)

    def loop(mine: bool) -> None:
        while not pending():
            item = take()
            if item is _END:
                return
            try:
                run(item)
            except BaseException:
                stop[0] = True
                raise
            with lock:
                done[0] += 1
                n = done[0]
            if mine and on_item is not None:
                on_item(n)

    with held():
        others = []
        if n_threads > 1:
            if _pool is None:
                from concurrent.futures import ThreadPoolExecutor

                _pool = ThreadPoolExecutor(max_workers=8, thread_name_prefix="bowsynth-work", initializer=_block_held)
            others = [_pool.submit(loop, False) for _ in range(min(n_threads, 8) - 1)]
        try:
            loop(True)
        except BaseException:
            stop[0] = True
            raise
        finally:
            for f in others:
                f.exception()  # waits: no thread still writes into the caller's arrays when this returns
        for f in others:
            f.result()
    # here only when a signal came and its handler returned (one that records, say): the work is still owed
    for item in queue:
        run(item)
