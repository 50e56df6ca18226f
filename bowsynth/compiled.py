"""The compiled core's thin wrapper (`bowsynth._core`, C++ in src/core, built at install by scikit-build-core with
nanobind): the FDM step, the operator's rollout loops and the live engine's voice loop (`Voices`, over the arrays of
engines.operator.bank), with the GIL released and no allocation after a process's first call of a size. Nothing is
compiled at run time.

`load()` imports it once and refuses, in one line (CoreError), a module that does not belong to this package: not
built, built for another Python (its file name carries the interpreter's tag, so Python does not find it), of another
ABI, or built from other sources than the src/core beside the package (a stale build in a source tree: the digest of
the sources is compiled in and compared here). A module that imports at all has passed these checks; the kernels
check every array's dtype, rank and shape before touching it (TypeError / ValueError).
"""

from __future__ import annotations

import hashlib
import signal
import threading
from pathlib import Path

from .errors import HELD, BowsynthError, held, pending

ABI = 4  # src/core/core.h: bowsynth::ABI
_REBUILD = "rebuild it with `pip install -e .` (or `make core` in a source tree run with PYTHONPATH)"


class CoreError(BowsynthError, ImportError):
    """The compiled core is missing or does not match this package."""


def source_digest(core_dir: Path) -> str | None:
    """The digest CMakeLists.txt compiles in: sha256 over 'name:sha256(file)' lines of src/core/*.cpp, *.h sorted by
    path; None where the sources are not there (an installed wheel carries none)."""
    files = sorted([*core_dir.glob("*.cpp"), *core_dir.glob("*.h")])
    if not files:
        return None
    text = "".join(f"{f.name}:{hashlib.sha256(f.read_bytes()).hexdigest()}\n" for f in files)
    return hashlib.sha256(text.encode()).hexdigest()


def usable_cores() -> int:
    """The cores this process may run the compiled loops on (they release the GIL): its CPU affinity, what a
    container or `taskset` grants, else the machine's count."""
    import os

    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # not on Linux
        return max(1, os.cpu_count() or 1)


def _block_held() -> None:
    # the pool's threads never take the signals: the kernel hands them to the main thread, which acts on them
    try:
        signal.pthread_sigmask(signal.SIG_BLOCK, HELD)
    except (AttributeError, OSError, ValueError):  # no POSIX thread signals here
        pass


SHARE_THREADS = 8  # the most threads share() runs work on, the caller's included
_END = object()
_pool = None  # a ThreadPoolExecutor whose threads block the signals (_block_held)


def share(run, items, n_threads: int, on_item=None) -> None:
    """run(item) for each of items on up to n_threads threads: this one and the pool's, each taking the next item as
    it is free (heaviest first is the caller's order to give). The signals are held meanwhile (held()): one that comes
    stops the threads taking items, and its handler raises once they are all back, so a long job still ends within
    one item per thread. on_item(done) runs in this thread after each item it finishes (done: items finished in
    all), and with the whole count once every thread is back. A thread's exception is raised here once the others
    are back."""
    global _pool
    queue = iter(list(items))
    lock = threading.Lock()
    done, stop, told = [0], [False], [0]

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
                told[0] = n
                on_item(n)

    with held():
        others = []
        if n_threads > 1:
            if _pool is None:
                from concurrent.futures import ThreadPoolExecutor

                _pool = ThreadPoolExecutor(max_workers=SHARE_THREADS - 1, thread_name_prefix="bowsynth-work",
                                           initializer=_block_held)
            others = [_pool.submit(loop, False) for _ in range(min(n_threads, SHARE_THREADS) - 1)]
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
        if on_item is not None and told[0] != done[0]:  # the last items were the pool's
            on_item(done[0])
    # here only when a signal came and its handler returned (one that records, say): the work is still owed
    for item in queue:
        run(item)


_module = None


def load():
    """The compiled module, checked once per process (see the module's docstring)."""
    global _module
    if _module is not None:
        return _module
    pkg = Path(__file__).resolve().parent  # bowsynth/
    try:
        from . import _core
    except ImportError as e:  # not built, or built for another interpreter (the file name carries its tag)
        raise CoreError(f"bowsynth's compiled core (bowsynth._core) could not be imported ({e}): {_REBUILD}") from None
    if getattr(_core, "ABI", None) != ABI:
        raise CoreError(f"bowsynth's compiled core ({_core.__file__}) has ABI {getattr(_core, 'ABI', None)}, the "
                        f"package expects {ABI} (a stale build): {_REBUILD}")
    want = source_digest(pkg.parent / "src" / "core")
    if want is not None and getattr(_core, "DIGEST", None) != want:
        raise CoreError(f"bowsynth's compiled core ({_core.__file__}) was built from other sources than "
                        f"{pkg.parent / 'src' / 'core'} (a stale build): {_REBUILD}")
    _module = _core
    return _core


def fdm_run(*args):
    """`_core.fdm_run`: steps of the FDM; see engines.fdm.run_fdm_raw."""
    return load().fdm_run(*args)


def roll(batch: bool, *args) -> None:
    """The rollout loop: `_core.roll_batch` (every voice one window at a time) or `_core.roll_voices` (one voice
    after another); arguments as engines.operator.rollout._roll_numpy, then rows (B,) int64: voice b's row of
    q_out, p_out and fail."""
    core = load()
    (core.roll_batch if batch else core.roll_voices)(*args)


def resample_rows(x, w, k0: int, up: int, down: int, y) -> None:
    """`_core.resample_rows`: float32 rows held, continued and resampled into y in one pass; see
    engines.operator.grid.to_output."""
    load().resample_rows(x, w, k0, up, down, y)


def polyphase(x, w, up: int, down: int, y) -> None:
    """`_core.polyphase`: rows of x resampled by up / down into y, the filter w given per phase; see
    engines.operator.grid.to_output."""
    load().polyphase(x, w, up, down, y)
