"""Seeded differences between closed-loop runs, drawn from where real runs differ.

Three runs of one policy in one world are only worth comparing (Min-Fréchet, corridor
violations) if they differ as repeated real drives do. Each run's seed draws, independently:

- **start pose**: the driver never stops at the same spot; a lateral offset (metres, left of
  the recorded start heading) and a heading offset (degrees, counter-clockwise);
- **speed profile**: the target speed is the recorded start speed (or the run's target) times
  a factor ``1 + speed * z``;

each ``z`` normal, truncated at two standard deviations (a driver's repeatability has no
outliers; a 3-sigma start would be a different test);
- **actuation noise**: steering noise each simulator step (the builtin simulator's
  ``steering_noise_std``, seeded by the run);
- **sensor noise**: the truth camera's photographic noise, drawn per pose, so a run that drives
  elsewhere sees other noise (:mod:`cam2sim.render.look`).

The first two live here; each run's draw goes into its ``run.json`` (``variation``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np

__all__ = ["DEMO_RUN_VARIATION", "DrawnVariation", "RunVariation"]

_STREAM: Final = 0x5EED_0F_7A
"""Mixed into the run's seed, so these draws never repeat the simulator's noise stream."""
_CLIP: Final = 2.0
"""Draws are truncated at this many standard deviations."""


@dataclass(frozen=True)
class DrawnVariation:
    """One run's draw: start offset and speed factor."""

    lateral_m: float
    heading_deg: float
    speed_factor: float


@dataclass(frozen=True)
class RunVariation:
    """Standard deviations of the seeded run-to-run differences (0 = none).

    Attributes:
        start_lateral_m: Of the start's lateral offset, metres.
        start_heading_deg: Of the start heading's offset, degrees.
        speed: Of the target speed's relative change (0.03 = 3 %).
    """

    start_lateral_m: float = 0.0
    start_heading_deg: float = 0.0
    speed: float = 0.0

    def __post_init__(self) -> None:
        if min(self.start_lateral_m, self.start_heading_deg, self.speed) < 0 or self.speed >= 0.5:
            msg = f"run variation needs standard deviations >= 0 (speed < 0.5), got {self!r}"
            raise ValueError(msg)

    def draw(self, seed: int) -> DrawnVariation:
        """The differences of the run with ``seed`` (the same seed, the same draw)."""
        rng = np.random.default_rng([seed, _STREAM])
        lateral, heading, speed = np.clip(rng.standard_normal(3), -_CLIP, _CLIP)
        return DrawnVariation(
            lateral_m=float(lateral * self.start_lateral_m),
            heading_deg=float(heading * self.start_heading_deg),
            speed_factor=float(1.0 + speed * self.speed),
        )


DEMO_RUN_VARIATION: Final = RunVariation(start_lateral_m=0.1, start_heading_deg=0.5, speed=0.03)
"""The demo's: 10 cm and half a degree at the start, 3 % of speed (a driver's repeatability)."""
