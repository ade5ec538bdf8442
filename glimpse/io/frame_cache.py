"""Per-frame data read from disk on demand, a bounded number of frames kept: stages 04 and 06 train on
videos of any length in the memory of ``capacity`` frames.

``FrameCache(load, capacity)`` keeps the ``capacity`` frames used last (least recently used dropped);
``prefetch(ids)`` reads frames that will be asked for soon on a background thread (decoding a PNG
releases the GIL), so a training loop that knows its view order rarely waits for the disk. What
``load`` returns for a frame is the same whether it came from the cache, a prefetch or a fresh read:
results do not depend on the capacity.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, Generic, Iterable, TypeVar

from glimpse.errors import ConfigError

Item = TypeVar("Item")


@dataclass(frozen=True)
class FrameCacheSize:
    """How many frames a stage keeps decoded (``compute.frame_cache``) and reads ahead
    (``compute.frame_read_ahead``), and how many MB of values derived from them it may keep with them
    (``compute.lpips_target_cache_mb``: stage 06's LPIPS target features)."""

    frames: int
    read_ahead: int
    derived_mb: float

    def __post_init__(self) -> None:
        if self.frames < 1 or not 0 <= self.read_ahead < self.frames:
            raise ConfigError(f"compute.frame_cache must be >= 1 and compute.frame_read_ahead in [0, frame_cache), "
                              f"found {self.frames} and {self.read_ahead}")
        if not self.derived_mb >= 0:
            raise ConfigError(f"compute.lpips_target_cache_mb must be >= 0, found {self.derived_mb}")


class FrameCache(Generic[Item]):
    """frame id -> ``load(frame id)``, at most ``capacity`` (>= 1) items kept."""

    def __init__(self, load: Callable[[int], Item], capacity: int):
        if capacity < 1:
            raise ValueError(f"a frame cache holds at least one frame, asked for {capacity}")
        self.load, self.capacity = load, capacity
        self.items: OrderedDict[int, Item] = OrderedDict()
        self.pending: dict[int, Future] = {}
        self.lock = threading.Lock()
        self.reader: ThreadPoolExecutor | None = None

    def get(self, frame_id: int) -> Item:
        with self.lock:
            if frame_id in self.items:
                self.items.move_to_end(frame_id)
                return self.items[frame_id]
            pending = self.pending.pop(frame_id, None)
        item = pending.result() if pending is not None else self.load(frame_id)
        with self.lock:
            self.items[frame_id] = item
            self.items.move_to_end(frame_id)
            while len(self.items) > self.capacity:
                self.items.popitem(last=False)
        return item

    def prefetch(self, frame_ids: Iterable[int]) -> None:
        """Start reading these frames in the background (those not held or on their way already); at most
        ``capacity - 1`` are read ahead, so a prefetch never pushes out the frame in use."""
        with self.lock:
            wanted = [f for f in dict.fromkeys(frame_ids) if f not in self.items and f not in self.pending]
            room = max(0, self.capacity - 1 - len(self.pending))
            if not wanted or room == 0:
                return
            if self.reader is None:
                self.reader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="frame-reader")
            for frame_id in wanted[:room]:
                self.pending[frame_id] = self.reader.submit(self.load, frame_id)

    def close(self) -> None:
        """Wait for reads in flight and stop the reader thread."""
        if self.reader is not None:
            self.reader.shutdown(wait=True)
            self.reader = None
        self.pending.clear()
