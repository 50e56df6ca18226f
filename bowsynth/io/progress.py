"""Progress that fits where it goes: a rich bar with the loss terms and the ETA in a terminal; elsewhere (a pipe,
a log file, CI, a notebook) one plain line at least every `every` seconds, never cut at 80 columns.

    with Reporter(console, enabled=True) as rep:
        rep.update("FDM data", 0.4)                      # phase and its fraction done
        rep.update("training", 0.5, "step 900 loss 1e-3")  # with details
"""

from __future__ import annotations

import threading
import time


def _clock(seconds: float) -> str:
    seconds = max(0, int(seconds))
    return f"{seconds // 60}:{seconds % 60:02d}"


class Reporter:
    def __init__(self, console=None, enabled: bool = True, every: float = 10.0, title: str = ""):
        self.console, self.every, self.title = console, every, title
        self.enabled = enabled and console is not None
        self.tty = self.enabled and console.is_terminal
        self._lock = threading.Lock()
        self._state = ("starting", 0.0, "")
        self._phase_t0 = self._t0 = time.monotonic()
        self._last_line = -float("inf")
        self._stop = threading.Event()
        self._bar = self._task = None
        self._thread = None

    # --- context -------------------------------------------------------------------------------------------------
    def __enter__(self):
        if not self.enabled:
            return self
        if self.tty:
            from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

            self._bar = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
                                 TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(),
                                 TextColumn("{task.fields[info]}"), console=self.console, transient=False)
            self._bar.start()
        else:  # the first update prints at once (a new phase): a log shows life from the first second
            self._thread = threading.Thread(target=self._heartbeat, daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        if self._bar is not None:
            self._bar.stop()
        if self._thread is not None:
            self._thread.join(timeout=2)
        return False

    # --- reporting -----------------------------------------------------------------------------------------------
    def update(self, phase: str, fraction: float, info: str = "") -> None:
        if not self.enabled:
            return
        fraction = min(max(float(fraction), 0.0), 1.0)
        with self._lock:
            new_phase = phase != self._state[0]
            if new_phase:
                self._phase_t0 = time.monotonic()
            self._state = (phase, fraction, info)
        if self._bar is not None:
            if new_phase or self._task is None:
                if self._task is not None:
                    self._bar.update(self._task, completed=1000)
                self._task = self._bar.add_task(phase, total=1000, info="")
            self._bar.update(self._task, completed=1000 * fraction, info=info)
        elif new_phase or time.monotonic() - self._last_line >= self.every:
            self._line()

    def _line(self) -> None:
        with self._lock:
            phase, frac, info = self._state
            now = time.monotonic()
            spent = now - self._phase_t0
            eta = f"eta {_clock(spent / frac - spent)}" if 0.02 < frac < 1 else "eta ?" if frac < 1 else "done"
            text = (f"{self.title}{phase}: {100 * frac:.0f}%, elapsed {_clock(now - self._t0)}, {eta}"
                    + (f", {info}" if info else ""))
            self._last_line = now
            f = self.console.file
            f.write(text + "\n")  # straight to the stream: no wrapping, no markup
            f.flush()

    def _heartbeat(self) -> None:
        # phases without callbacks (an FDM reference, validation) still print at least every `every` seconds
        while not self._stop.wait(1.0):
            if time.monotonic() - self._last_line >= self.every:
                self._line()
