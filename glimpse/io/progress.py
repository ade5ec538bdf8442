"""Progress that shows wherever the output goes: a tqdm bar on a terminal, and on anything else (a log file,
nohup, Slurm) a line through ``logging`` every ``LINE_EVERY_S`` seconds and one at the end, so that a stage's
log.txt and a batch job's output say how far it got and how fast."""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")
LINE_EVERY_S = 30.0  # seconds between progress lines when the output is not a terminal

log = logging.getLogger("glimpse.progress")


def on_terminal() -> bool:
    """Whether stderr (where tqdm draws) is an interactive terminal."""
    return hasattr(sys.stderr, "isatty") and sys.stderr.isatty()


class Progress:
    """Counts units of work as ``update(n)`` reports them: a bar on a terminal, timed log lines elsewhere.
    ``postfix`` (short text, e.g. the loss) is shown on the bar and appended to the lines."""

    def __init__(self, total: int | None, desc: str, unit: str, initial: int = 0, leave: bool = False):
        self.total, self.desc, self.unit, self.done = total, desc, unit, initial
        self.postfix = ""
        self._bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, leave=leave) if on_terminal() else None
        self._started = self._last_line = time.perf_counter()
        self._first = initial

    def update(self, count: int = 1, postfix: dict[str, str] | None = None) -> None:
        self.done += count
        if postfix is not None:
            self.postfix = ", ".join(f"{k} {v}" for k, v in postfix.items())
        if self._bar is not None:
            self._bar.update(count)
            if postfix is not None:
                self._bar.set_postfix(postfix, refresh=False)
        elif time.perf_counter() - self._last_line >= LINE_EVERY_S:
            self._line()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
        elif self.done > self._first:
            self._line()

    def _line(self) -> None:
        now = time.perf_counter()
        self._last_line = now
        rate = (self.done - self._first) / max(now - self._started, 1e-9)
        of = f"/{self.total}" if self.total is not None else ""
        log.info("%s: %d%s %s (%.1f %s/s)%s", self.desc, self.done, of, self.unit + "s", rate, self.unit,
                 f"; {self.postfix}" if self.postfix else "")


def progress(items: Iterable[T], desc: str, unit: str, total: int | None = None, leave: bool = False
             ) -> Iterator[T]:
    """``items`` one by one, with progress shown as :class:`Progress` does (``total``: len(items) if it has one)."""
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    shown = Progress(total, desc, unit, leave=leave)
    try:
        for item in items:
            yield item
            shown.update(1)
    finally:
        shown.close()
