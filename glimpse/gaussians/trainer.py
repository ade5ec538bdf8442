"""The training loop every Gaussian optimisation shares (stage 04's background; stage 06's people and background).

A trainer derives from :class:`GaussianTrainer` and says what one iteration does and what state changes; the
loop here runs the iterations to the end, resumes from the checkpoint when one of the same inputs and parameters
exists, saves one every ``checkpoint_every`` iterations (atomically, glimpse.io.checkpoint), shows progress
(tqdm; a log line with every checkpoint), keeps the loss history and times the run. Everything a trainer draws
at random must be a function of (seed, iteration), so that a resumed run ends where an uninterrupted one does.
"""

from __future__ import annotations

import logging
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence, TypeVar

import torch

from glimpse.gaussians.phases import PhaseTimer
from glimpse.gaussians.training import view_for_step
from glimpse.io.checkpoint import load_checkpoint, save_checkpoint
from glimpse.io.progress import Progress

View = TypeVar("View")

log = logging.getLogger("glimpse")
LOSS_HISTORY_EVERY = 10  # iterations between entries of the loss history in the report


@dataclass
class TrainingLog:
    """What a run did: its loss history (an entry every LOSS_HISTORY_EVERY iterations and at the last, in the
    trainer's own form), densification events, where it resumed from, how long this process took and where
    that time went (seconds per phase of the iterations, glimpse.gaussians.phases)."""

    losses: list = field(default_factory=list)
    densify_events: list[dict] = field(default_factory=list)
    resumed_from: int = 0
    iterations_run: int = 0  # in this process (not counting those before a resume)
    seconds: float = 0.0
    phase_seconds: dict[str, float] = field(default_factory=dict)

    @property
    def iterations_per_s(self) -> float:
        return self.iterations_run / self.seconds if self.seconds > 0 else 0.0


class GaussianTrainer(ABC):
    """Runs ``total_iterations`` iterations of :meth:`_iteration`; ``checkpoint`` (a path) is read at start and
    written every ``checkpoint_every`` iterations; ``key`` fingerprints the inputs and parameters (a checkpoint
    of another key is not resumed). ``name`` labels the progress bar and the log lines."""

    name: str

    def __init__(self, total_iterations: int, checkpoint_every: int, checkpoint: Path, key: str,
                 device: torch.device | None = None):
        self.total_iterations, self.checkpoint_every = total_iterations, checkpoint_every
        self.phases = PhaseTimer(device)  # _iteration marks its phases: `with self.phases("render"): ...`
        self.checkpoint, self.key = checkpoint, key
        self.log = TrainingLog()
        self.step = 0  # iterations done
        self.prefetch: Callable[[list[int]], None] | None = None
        self.frames_ahead = 0

    def read_ahead(self, prefetch: Callable[[list[int]], None], frames: int) -> None:
        """While an iteration runs, have ``prefetch`` (the stage's FrameCache) read the frames of the views
        of the next ``frames`` iterations."""
        self.prefetch, self.frames_ahead = prefetch, frames

    def _view(self, views: Sequence[View], seed: int, step: int) -> View:
        """The view iteration ``step`` trains on (``view_for_step``); starts reading the next ones' frames."""
        if self.prefetch is not None and self.frames_ahead > 0:
            last = min(step + self.frames_ahead, self.total_iterations)
            self.prefetch([views[view_for_step(seed, s, len(views))].frame_id for s in range(step + 1, last + 1)])
        return views[view_for_step(seed, step, len(views))]

    @abstractmethod
    def _iteration(self) -> dict[str, float]:
        """Run iteration ``step + 1`` and advance ``step``; the iteration's loss values, ``total`` among them."""

    @abstractmethod
    def _state(self) -> dict[str, Any]:
        """Everything the trainer changes, on the CPU (parameters, optimiser moments, statistics)."""

    @abstractmethod
    def _restore(self, state: dict[str, Any]) -> None:
        """Put back what :meth:`_state` returned."""

    @abstractmethod
    def _history_entry(self, values: dict[str, float]) -> Any:
        """The loss history's entry for the iteration just run."""

    @abstractmethod
    def _counts(self) -> str:
        """How many Gaussians there are now, for the log lines."""

    def _progress(self, values: dict[str, float]) -> dict[str, str]:
        """The progress bar's fields after an iteration."""
        return {"loss": f"{values['total']:.4f}"}

    def run(self) -> TrainingLog:
        total = self.total_iterations
        state = load_checkpoint(self.checkpoint, self.key)
        if state is not None:
            self._restore(state["trainer"])
            self.log.losses, self.log.densify_events = list(state["losses"]), list(state["densify_events"])
            self.step = self.log.resumed_from = int(state["step"])
            log.info("resuming %s from iteration %d (%s)", self.name, self.step, self.checkpoint)
        started = time.perf_counter()
        bar = Progress(total, self.name, "iteration", initial=self.step)
        while self.step < total:
            with self.phases.iteration():
                values = self._iteration()
            if self.step % LOSS_HISTORY_EVERY == 0 or self.step == total:
                self.log.losses.append(self._history_entry(values))
            bar.update(1, postfix=self._progress(values))
            if self.step % self.checkpoint_every == 0 and self.step < total:
                save_checkpoint(self.checkpoint, self.key, {
                    "step": self.step, "losses": self.log.losses, "densify_events": self.log.densify_events,
                    "trainer": self._state()})
                log.info("iteration %d/%d: loss %.4f, %s (checkpoint saved)", self.step, total, values["total"],
                         self._counts())
            self.log.iterations_run += 1
        bar.close()
        self.log.seconds = time.perf_counter() - started
        self.log.phase_seconds = {name: round(s, 3) for name, s in self.phases.seconds().items()}
        return self.log
