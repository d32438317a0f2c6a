"""Scores of splat renders shared by the held-out evaluation and the truth envelope.

:mod:`cam2sim.splat.evaluate` (held-out frames, relative offsets, ``eval.json``) and
:mod:`cam2sim.splat.envelope` (against the ground truth) both score image pairs and summarise
them; these records and helpers sit below both, so neither imports the other's internals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import pydantic

from cam2sim.metrics.image_quality import psnr, ssim
from cam2sim.metrics.summary import MetricSummary, summarise

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from cam2sim.metrics.lpips import Lpips

__all__ = [
    "MetricSummary",
    "PairScores",
    "TruthEnvelope",
    "TruthScore",
    "even_picks",
    "score_pair",
    "summarise",
]


class TruthScore(pydantic.BaseModel):
    """Scores against the noise-free truth at one perturbation of the held-out poses.

    ``lateral_m`` and ``yaw_deg`` are both 0 on the recorded path; otherwise one of them is set
    (see :func:`cam2sim.splat.envelope.perturbed_pose`).
    """

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    lateral_m: float = pydantic.Field(description="Along the camera x axis, m (+ = right)")
    yaw_deg: float = pydantic.Field(description="About the world z axis, degrees (+ = left)")
    psnr_db: MetricSummary
    ssim: MetricSummary
    lpips: MetricSummary
    coverage: MetricSummary

    @property
    def on_path(self) -> bool:
        """Whether this row is the recorded poses themselves."""
        return self.lateral_m == 0.0 and self.yaw_deg == 0.0

    def label(self) -> str:
        """``on path``, ``+0.5 m`` or ``yaw -5 deg``."""
        if self.lateral_m:
            return f"{self.lateral_m:+g} m"
        return f"yaw {self.yaw_deg:+g} deg" if self.yaw_deg else "on path"


class RigScore(pydantic.BaseModel):
    """The splat against a rig camera's real frames: real-pixel truth off the recorded path."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    name: str = pydantic.Field(description="The rig camera (dataset/cameras/<name>/)")
    lateral_m: float = pydantic.Field(description="From the front camera along its x, m (+ right)")
    yaw_deg: float = pydantic.Field(description="Turned from the front camera, degrees (+ left)")
    frames: list[int] = pydantic.Field(description="Held-out frames scored (scene indices)")
    psnr_db: MetricSummary
    ssim: MetricSummary
    lpips: MetricSummary
    coverage: MetricSummary

    def label(self) -> str:
        """``camera right (+0.54 m)``."""
        turn = f", yaw {self.yaw_deg:+.0f} deg" if abs(self.yaw_deg) >= 0.5 else ""
        return f"camera {self.name} ({self.lateral_m:+.2f} m{turn})"


class TruthEnvelope(pydantic.BaseModel):
    """The splat models against the ground truth, on and off the path (module doc)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    frames: list[int] = pydantic.Field(description="Held-out frames scored (scene indices)")
    sensor_noise: bool = pydantic.Field(
        default=False, description="Whether the truth had sensor noise"
    )
    lpips_net: str | None
    scores: list[TruthScore] = pydantic.Field(description="On path first")
    notes: list[str] = pydantic.Field(default_factory=list)

    def on_path(self) -> TruthScore | None:
        """The row of the recorded poses, if measured."""
        return next((row for row in self.scores if row.on_path), None)


@dataclass(frozen=True)
class PairScores:
    """PSNR (dB), SSIM and LPIPS of one image pair; None where not computed."""

    psnr: float | None
    ssim: float | None
    lpips: float | None


def even_picks(n: int, k: int | None) -> list[int]:
    """Indices of at most ``k`` of ``n`` items spread evenly, first and last included."""
    if n <= 0:
        return []
    if k is None or k >= n:
        return list(range(n))
    return sorted({round(i * (n - 1) / max(1, k - 1)) for i in range(k)})


def score_pair(
    real: npt.NDArray[np.uint8],
    sim: npt.NDArray[np.uint8],
    exclude: npt.NDArray[np.bool_] | None,
    lpips: Lpips | None,
) -> PairScores:
    """Score ``sim`` against ``real`` (``(H, W, 3)`` uint8) outside ``exclude`` (True: out)."""
    lp = None
    if lpips is not None:
        batch_exclude = None if exclude is None else exclude[None]
        lp = lpips.distance_from_images(real[None], sim[None], exclude=batch_exclude)[0]
    return PairScores(psnr(real, sim, exclude=exclude), ssim(real, sim, exclude=exclude), lp)
