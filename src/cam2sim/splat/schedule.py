"""The learning-rate schedules of a chunk's training, as small pieces of their own.

- :class:`MeansDecay`: the Gaussian centres' rate decays exponentially to 1 % of its start at
  the step cap (gsplat's recipe), and is re-aimed at a new cap when a time budget moves it.
- :func:`tail_factor`: after densification the scene's other rates fall geometrically to
  ``LearningRates.tail`` times their value at the step cap, so the model settles instead of
  jittering around its optimum.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

__all__ = ["MEANS_END_SHARE", "MeansDecay", "tail_factor"]

MEANS_END_SHARE: Final = 0.01
"""The means' rate at the step cap, as a share of its start."""


@dataclass
class MeansDecay:
    """The means' learning rate, one step at a time.

    Attributes:
        lr: The rate of the current step.
        end: The rate at the step cap.
        gamma: The factor from one step to the next.
    """

    lr: float
    end: float
    gamma: float

    @classmethod
    def over(cls, start: float, steps: int) -> MeansDecay:
        """From ``start`` to :data:`MEANS_END_SHARE` of it in ``steps`` steps."""
        return cls(start, MEANS_END_SHARE * start, MEANS_END_SHARE ** (1.0 / steps))

    def advance(self) -> float:
        """The next step's rate."""
        self.lr *= self.gamma
        return self.lr

    def aim(self, step: int, cap: int) -> None:
        """Reach :attr:`end` at ``cap`` from ``step`` (the cap moved)."""
        self.gamma = (self.end / self.lr) ** (1.0 / (cap - step))


def tail_factor(step: int, start: int, cap: int, tail: float) -> float | None:
    """The factor on the tail's rates at ``step``: 1 at ``start``, ``tail`` at ``cap`` and after.

    None before ``start`` (and when the cap is not past it): the rates are left as they are.
    """
    if step <= start or cap <= start:
        return None
    return float(tail ** min(1.0, (step - start) / (cap - start)))
