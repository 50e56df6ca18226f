"""Independent work on Ray (the `cluster` extra): a local cluster of N workers or one at an address, tasks retried
where a worker dies, results as they finish; with one worker the same work in this process, and without Ray N
worker processes of this machine (concurrent.futures).

Why Ray: a corpus of notes, a table of measured bows and an atlas's units are thousands of independent jobs, and Ray
runs them over the cores of one machine or many with the same code, retrying the tasks of a worker that dies.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Iterable, Iterator

from ..errors import BowsynthError, UsageError

RETRIES = 3  # a task whose worker dies runs again, this many times


class ClusterError(BowsynthError):
    """No cluster at the address asked for (exit 1, nothing started)."""


def has_ray() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def _reachable(address: str) -> bool:
    """Does something listen at host:port (a Ray head's GCS)? Checked before ray.init, which waits a minute for one
    that is not there."""
    host, _, port = address.rpartition(":")
    try:
        with socket.create_connection((host or "127.0.0.1", int(port)), timeout=3):
            return True
    except (OSError, ValueError):
        return False


class Pool:
    """Where tasks run: `map(fn, items)` yields (item index, result) as each finishes.

    workers 1 and no address: this process, in order. Else Ray: a local cluster of `workers` CPUs, or the cluster at
    `address` (or RAY_ADDRESS); without Ray installed, `workers` processes here. A task raising an exception stops
    the run with it; on Ray a task whose worker process dies is retried RETRIES times. `fn` must be a module-level
    function (it is pickled to the workers)."""

    def __init__(self, workers: int = 1, address: str | None = None):
        if workers < 1:
            raise UsageError(f"--workers must be at least 1, got {workers}")
        address = address or os.environ.get("RAY_ADDRESS") or None
        self.workers, self.address = workers, address
        self.local = workers == 1 and address is None
        self.processes = False
        self.note = ""
        if not self.local and not has_ray():
            if address is not None:
                raise UsageError("--address needs Ray: pip install 'bowsynth[cluster]'")
            self.processes = True
            self.note = f"Ray is not installed ('bowsynth[cluster]'): {workers} processes of this machine"
        if not self.local and not self.processes:
            self._start()

    def _start(self) -> None:
        import ray

        if ray.is_initialized():
            return
        if self.address is not None:
            if self.address != "auto" and not _reachable(self.address):
                raise ClusterError(f"no Ray cluster at {self.address}: nothing started (start one with "
                                   f"`ray start --head`, or leave --address out to run here)")
            ray.init(address=self.address, log_to_driver=False, logging_level="ERROR")
        else:
            ray.init(num_cpus=self.workers, log_to_driver=False, logging_level="ERROR", include_dashboard=False)

    def map(self, fn: Callable, items: Iterable) -> Iterator[tuple[int, object]]:
        items = list(items)
        if self.local:
            for i, item in enumerate(items):
                yield i, fn(item)
            return
        if self.processes:
            from concurrent.futures import ProcessPoolExecutor, as_completed

            with ProcessPoolExecutor(self.workers) as ex:
                futures = {ex.submit(fn, item): i for i, item in enumerate(items)}
                try:
                    for f in as_completed(futures):
                        yield futures[f], f.result()
                finally:
                    for f in futures:
                        f.cancel()
            return
        import ray

        task = ray.remote(max_retries=RETRIES, num_cpus=1)(fn)
        pending = {task.remote(item): i for i, item in enumerate(items)}
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                ref = done[0]
                yield pending.pop(ref), ray.get(ref)
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)

    def close(self) -> None:
        if not self.local and not self.processes:
            import ray

            if ray.is_initialized():
                ray.shutdown()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False
