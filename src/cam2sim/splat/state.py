"""What a chunk's training has done so far: the record each training step moves forward.

:class:`TrainState` holds the progress of one chunk (its step, its validations, its step cap
and time share, why it stopped), apart from what it trains (the models, the views, the
optimizers, in :mod:`cam2sim.splat.chunk_trainer`). The stop rules of :mod:`cam2sim.splat.stop` read
it; the trainer's step moves it on.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from cam2sim.splat.stop import steps_that_fit

if TYPE_CHECKING:
    from cam2sim.splat.train_options import Stop

__all__ = ["TrainState"]


@dataclass
class TrainState:
    """One chunk's training progress.

    Attributes:
        cap: The step cap: ``max_steps``, or the step where the time share runs out.
        time_share: Seconds this chunk may train; None: no time budget.
        step: Steps done.
        history: ``(step, psnr_db, ssim)`` of every held-in validation.
        done: Training has stopped.
        stopped: Why (``plateau``, ``max_steps``, ``time``).
        seconds: Training time so far (steps and validations).
        pace_mark: ``(step, seconds)`` at the last validation, the pace's reference.
        val_seconds: How long the last validation took (kept back from the time share).
    """

    cap: int
    time_share: float | None = None
    step: int = 0
    history: list[tuple[int, float, float]] = field(default_factory=list)
    done: bool = False
    stopped: Stop = "max_steps"
    seconds: float = 0.0
    pace_mark: tuple[int, float] = (0, 0.0)
    val_seconds: float = 0.0

    @property
    def best(self) -> float | None:
        """The best held-in PSNR so far, dB."""
        return max((psnr for _, psnr, _ in self.history), default=None)

    def out_of_time(self, spent: float) -> bool:
        """One more validation, as long as the last, would overrun the time share."""
        return self.time_share is not None and spent + self.val_seconds >= self.time_share

    def stop(self, why: Stop) -> None:
        """Training ends here, for ``why``."""
        self.done, self.stopped = True, why

    def fit_cap(self, spent: float, max_steps: int) -> int | None:
        """Move the cap to where the time share runs out at the recent pace.

        The share less one validation: the last one, at the cap, is scored within it. Returns
        the new cap, or None when it did not move.
        """
        assert self.time_share is not None
        share = self.time_share - self.val_seconds
        cap = min(max_steps, steps_that_fit(self.step, spent, share, self.pace_mark))
        self.pace_mark = (self.step, spent)
        if cap == self.cap:
            return None
        self.cap = cap
        return cap
