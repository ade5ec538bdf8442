"""The frame cache of stages 04 and 06: bounded, read ahead in the background, and invisible in results."""

import threading

import pytest

from glimpse.errors import ConfigError
from glimpse.gaussians.trainer import GaussianTrainer
from glimpse.gaussians.training import view_for_step, view_order
from glimpse.io.frame_cache import FrameCache, FrameCacheSize


class Recorder:
    def __init__(self):
        self.calls: list[int] = []
        self.threads: set[str] = set()

    def __call__(self, frame_id: int) -> tuple[int, list[float]]:
        self.calls.append(frame_id)
        self.threads.add(threading.current_thread().name)
        return frame_id, [float(frame_id)] * 3


def test_it_keeps_the_frames_used_last_and_reads_the_others_again():
    read = Recorder()
    cache = FrameCache(read, capacity=2)
    assert [cache.get(f)[0] for f in (0, 1, 0, 2, 1, 0)] == [0, 1, 0, 2, 1, 0]
    assert read.calls == [0, 1, 2, 1, 0]  # 0 survived 2's arrival (used more recently than 1)
    assert len(cache.items) == 2
    with pytest.raises(ValueError, match="at least one frame"):
        FrameCache(read, capacity=0)


def test_read_ahead_happens_on_another_thread_and_gives_the_same_items():
    read = Recorder()
    cache = FrameCache(read, capacity=4)
    cache.prefetch([5, 6, 7, 8, 9])  # room for capacity - 1
    assert [cache.get(f) for f in (5, 6, 7)] == [read(f) for f in (5, 6, 7)]
    cache.close()
    assert read.calls[:3] == [5, 6, 7] and any(name.startswith("frame-reader") for name in read.threads)
    assert 8 not in read.calls[:3] and 9 not in read.calls


def test_sizes_are_checked():
    FrameCacheSize(1, 0, 0.0)
    for frames, ahead in ((0, 0), (4, 4), (4, -1)):
        with pytest.raises(ConfigError, match="compute.frame_cache"):
            FrameCacheSize(frames, ahead, 0.0)


class _CountingTrainer(GaussianTrainer):
    name = "test"

    def __init__(self, views, total):
        super().__init__(total, 10**6, None, "key")
        self.views, self.seen = views, []

    def _iteration(self):
        self.step += 1
        self.seen.append(self._view(self.views, 3, self.step))
        return {"total": 0.0}

    def _state(self):
        return {}

    def _restore(self, state):
        pass

    def _history_entry(self, values):
        return self.step

    def _counts(self):
        return ""


class _View:
    def __init__(self, frame_id):
        self.frame_id = frame_id


def test_a_trainer_asks_for_the_frames_of_its_next_iterations(tmp_path):
    views = [_View(10 + k) for k in range(5)]
    trainer = _CountingTrainer(views, total=12)
    trainer.checkpoint = tmp_path / "none.pt"
    asked: list[list[int]] = []
    trainer.read_ahead(asked.append, 3)
    trainer.run()
    order = [view_for_step(3, step, 5) for step in range(1, 13)]
    assert order[:5] == list(view_order(3, 0, 5)) and sorted(order[:5]) == list(range(5))
    assert [v.frame_id for v in trainer.seen] == [10 + k for k in order]
    assert asked[0] == [10 + k for k in order[1:4]] and asked[-1] == []  # never beyond the last iteration
    assert asked[9] == [10 + k for k in order[10:12]]
