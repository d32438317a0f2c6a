"""Steering agreement: does the system under test act on rendered frames as on recorded ones?

Image metrics say how a rendered frame differs from the recorded frame of the same pose; the
question the paper asks is whether the difference changes what the driving model does. The
replay renders every camera at the recorded poses, so each rendered frame has a recorded twin:
the policy's steering on both, and its gap (rendered minus recorded), frame by frame, answer it
on real data, with no ground-truth world. :func:`steering_agreement` summarises the gaps:
their mean, 95th percentile and largest magnitude (and where), the correlation of the two
steering series, and the spread of the recorded steering as the scale to read them against.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pydantic

from cam2sim.core.schema import Artifact

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

__all__ = ["SteeringAgreement", "steering_agreement"]


class SteeringAgreement(Artifact):
    """``steering.json``: a policy's steering on rendered frames against recorded ones.

    Steering values are in the recording's steering units; gaps are rendered minus recorded.
    """

    camera: str
    policy: str
    frames: list[str]
    recorded: list[float]
    rendered: list[float]
    mean_abs_gap: float
    p95_abs_gap: float
    max_abs_gap: float
    max_gap_frame: str
    correlation: float | None = pydantic.Field(
        description="Pearson correlation of the two series (None: fewer than 3 frames, or one "
        "series constant)"
    )
    recorded_std: float = pydantic.Field(
        description="Spread of the steering on the recorded frames: the scale of the gaps"
    )
    held_out_frames: int = pydantic.Field(
        0, description="Frames the renderer never trained on (the splat's held-out views)"
    )
    held_out_mean_abs_gap: float | None = None
    held_out_correlation: float | None = None


def _correlation(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64]) -> float | None:
    if a.size >= 3 and np.ptp(a) > 0 and np.ptp(b) > 0:
        return float(np.corrcoef(a, b)[0, 1])
    return None


def steering_agreement(
    camera: str,
    policy: str,
    frames: Sequence[str],
    recorded: npt.ArrayLike,
    rendered: npt.ArrayLike,
    *,
    held_out: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
) -> SteeringAgreement:
    """Summarise a policy's steering on ``rendered`` frames against the ``recorded`` ones.

    ``held_out`` is the steering on the recorded and the rendered image of every frame the
    renderer did not train on (a splat's held-out views): summarised on its own, the fair test
    of a trained renderer.

    Raises:
        ValueError: No frame, or the three sequences differ in length.
    """
    real = np.asarray(recorded, dtype=np.float64)
    sim = np.asarray(rendered, dtype=np.float64)
    if not (len(frames) == real.size == sim.size) or real.size == 0:
        msg = (
            f"steering agreement of {camera}: {len(frames)} frames, {real.size} recorded and "
            f"{sim.size} rendered values; give one of each per frame"
        )
        raise ValueError(msg)
    gap = np.abs(sim - real)
    worst = int(np.argmax(gap))
    held_real = np.asarray(held_out[0] if held_out else [], dtype=np.float64)
    held_sim = np.asarray(held_out[1] if held_out else [], dtype=np.float64)
    if held_real.shape != held_sim.shape:
        msg = f"steering agreement of {camera}: held-out series of different lengths"
        raise ValueError(msg)
    return SteeringAgreement(
        camera=camera,
        policy=policy,
        frames=list(frames),
        recorded=[round(float(v), 5) for v in real],
        rendered=[round(float(v), 5) for v in sim],
        mean_abs_gap=float(gap.mean()),
        p95_abs_gap=float(np.percentile(gap, 95)),
        max_abs_gap=float(gap[worst]),
        max_gap_frame=str(frames[worst]),
        correlation=_correlation(real, sim),
        recorded_std=float(np.std(real)),
        held_out_frames=int(held_real.size),
        held_out_mean_abs_gap=float(np.abs(held_sim - held_real).mean())
        if held_real.size
        else None,
        held_out_correlation=_correlation(held_real, held_sim),
    )
