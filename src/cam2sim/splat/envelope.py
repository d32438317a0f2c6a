"""Stage splat, evaluation against the ground truth: the validity envelope, measured.

Where a workspace has a ground-truth world (``WS/truth/world.json``, the ``truth`` camera of
:mod:`cam2sim.render.truth`), the splat models can be scored against what the camera would
really have seen, on the recorded path and off it. :func:`truth_envelope` renders, at held-out
recorded poses (never trained on) and at perturbations of them:

- the splat models (:class:`~cam2sim.splat.render.SplatRenderer`, with the appearance
  transform, as the simulator sees them);
- the truth camera **without sensor noise** (``TruthRenderer.render(sensor_noise=False)``):
  the same textures, blur, grading and vignetting as the recording, no per-frame noise, so a
  perfect model would score the same everywhere (the noise would cap PSNR near 39 dB);

and scores the pair with PSNR, SSIM and LPIPS over the frame's mask (the ego hood left out),
with the renderer's coverage of each pose. The perturbations (:class:`TruthEnvelopeOptions`)
are lateral offsets along the camera's x axis (metres, positive = right; as the relative
offsets of :mod:`cam2sim.splat.evaluate`) and yaw turns about the world z axis through the
camera centre (degrees, positive = counter-clockwise, to the left), each alone, plus the
recorded pose itself (on path). Each row of the result summarises one perturbation over the
same frames, so rows compare directly: how fast the splat degrades off the path it was trained
on, in absolute terms.

Poses go from the workspace world frame to the truth frame as the truth camera maps them
(through the two projections); the truth world's road is at z = 0, so each pose is first
lowered by the recorded ground height under it (``TruthReference.ground_z``, from the
scenario's trajectory where there is one; 0 otherwise, as in the demo).

Cost: one splat render (about 0.3 s a 320x200 frame on a CPU), one truth render (about 60 ms)
and one LPIPS pass per frame and perturbation; renders the held-out evaluation already made
(on path, and its own lateral offsets) are reused. ``max_frames`` (default 12, spread evenly
over the held-out frames) bounds it: 9 perturbations of 12 frames take about 30 s on 2 cores.

Limits: the truth world is only as true as its description (a synthetic recording's is exact;
a hand-made one is not); perturbations are applied one at a time (no combined offset and yaw);
beyond the recorded road the truth may show what no recording could have trained (the scores
then measure extrapolation, which is the point, but a model cannot be expected to get it right).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, TypeAlias

import numpy as np

from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.splat.scores import (
    MetricSummary,
    PairScores,
    RigScore,
    TruthEnvelope,
    TruthScore,
    even_picks,
    score_pair,
    summarise,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

    import numpy.typing as npt

    from cam2sim.core.camera import PinholeCamera
    from cam2sim.metrics.lpips import Lpips
    from cam2sim.splat.render import SplatRenderer
    from cam2sim.splat.scene import FrameRecord

__all__ = [
    "DEFAULT_TRUTH_LATERAL_M",
    "DEFAULT_TRUTH_YAW_DEG",
    "RenderCache",
    "RigView",
    "TruthCamera",
    "TruthEnvelopeOptions",
    "TruthReference",
    "even_picks",
    "perturbed_pose",
    "rig_scores",
    "truth_envelope",
]

_log = logging.getLogger(__name__)

DEFAULT_TRUTH_LATERAL_M = (-2.0, -1.0, -0.5, 0.5, 1.0, 2.0)
"""Lateral offsets scored against the truth by default, metres (positive = camera right)."""
DEFAULT_TRUTH_YAW_DEG = (-5.0, 5.0)
"""Yaw turns scored against the truth by default, degrees (positive = counter-clockwise)."""

RenderCache: TypeAlias = dict[tuple[int, float, float], tuple["npt.NDArray[np.uint8]", float]]
"""Splat renders by ``(frame index, lateral_m, yaw_deg)``: RGB and coverage."""


@dataclass(frozen=True)
class TruthEnvelopeOptions:
    """What :func:`truth_envelope` measures.

    Attributes:
        lateral_m: Lateral offsets, metres (positive = camera right); 0 is always added.
        yaw_deg: Yaw turns about the world z axis, degrees (positive = counter-clockwise).
        max_frames: Held-out frames used (spread evenly); None = all.
    """

    lateral_m: tuple[float, ...] = DEFAULT_TRUTH_LATERAL_M
    yaw_deg: tuple[float, ...] = DEFAULT_TRUTH_YAW_DEG
    max_frames: int | None = 12

    def __post_init__(self) -> None:
        if self.max_frames is not None and self.max_frames < 1:
            msg = f"max_frames must be >= 1 or None, got {self.max_frames}"
            raise ValueError(msg)

    def perturbations(self) -> list[tuple[float, float]]:
        """``(lateral_m, yaw_deg)`` pairs: on path first, then the offsets, then the turns."""
        out = [(0.0, 0.0)]
        out += [(float(o), 0.0) for o in self.lateral_m if o != 0.0]
        out += [(0.0, float(y)) for y in self.yaw_deg if y != 0.0]
        return list(dict.fromkeys(out))


class _HasRgb(Protocol):
    @property
    def rgb(self) -> npt.NDArray[np.uint8]: ...


class TruthCamera(Protocol):
    """The truth camera :func:`truth_envelope` renders with (``TruthRenderer`` is one)."""

    def render(
        self,
        T_world_cam: npt.NDArray[np.float64],
        camera: PinholeCamera,
        *,
        sensor_noise: bool = True,
    ) -> _HasRgb:
        """RGB of a (distortion-free) camera at a world-frame pose."""
        ...


@dataclass(frozen=True)
class TruthReference:
    """The truth camera of a workspace and how the splat poses reach it.

    Attributes:
        camera: The truth camera (poses in the workspace world frame).
        ground_z: Ground height (m, world z) under a world ``(x, y)``; subtracted from the pose
            before the truth camera sees it (its road is z = 0). None: 0 everywhere.
        options: The perturbations and the frame budget.
    """

    camera: TruthCamera
    ground_z: Callable[[npt.NDArray[np.float64]], float] | None = None
    options: TruthEnvelopeOptions = field(default_factory=TruthEnvelopeOptions)


def perturbed_pose(
    T_world_cam: npt.NDArray[np.float64], *, lateral_m: float = 0.0, yaw_deg: float = 0.0
) -> npt.NDArray[np.float64]:
    """A camera pose moved sideways and turned about the vertical.

    Args:
        T_world_cam: ``(4, 4)`` camera (optical axes: x right, y down, z forward) -> world.
        lateral_m: Shift along the camera's x axis, metres (positive = right).
        yaw_deg: Turn of the orientation about the world z axis through the camera centre,
            degrees (positive = counter-clockwise seen from above, i.e. to the left).

    Returns:
        The ``(4, 4)`` moved pose (the input is not changed).
    """
    pose = np.array(T_world_cam, dtype=np.float64)
    if lateral_m:
        pose[:3, 3] += lateral_m * pose[:3, 0] / np.linalg.norm(pose[:3, 0])
    if yaw_deg:
        a = math.radians(yaw_deg)
        c, s = math.cos(a), math.sin(a)
        pose[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ pose[:3, :3]
    return pose


def truth_envelope(
    renderer: SplatRenderer,
    reference: TruthReference,
    frames: Sequence[tuple[FrameRecord, npt.NDArray[np.bool_] | None]],
    *,
    lpips: Lpips | None,
    lpips_net: str | None,
    cache: RenderCache | None = None,
    progress: ProgressCallback = no_progress,
) -> TruthEnvelope:
    """Score the splat models against the noise-free truth at and around held-out poses.

    Args:
        renderer: The splat models.
        reference: The truth camera, the ground heights and the perturbations.
        frames: Held-out frames (all of them; ``reference.options.max_frames`` are picked) and
            their excluded pixels (``(H, W)`` bool, True = left out; None = none).
        lpips: LPIPS network (None: LPIPS not computed).
        lpips_net: Its backbone name, recorded in the result.
        cache: Splat renders already made (reused, and filled).
        progress: Called with ``("splat truth envelope", done, total)``.

    Returns:
        One row per perturbation (on path first), summarised over the picked frames.
    """
    opts = reference.options
    picked = [frames[i] for i in even_picks(len(frames), opts.max_frames)]
    perturbations = opts.perturbations()
    renders = {} if cache is None else cache
    total = len(picked) * len(perturbations)
    rows: list[TruthScore] = []
    done = 0
    for lateral, yaw in perturbations:
        scores: list[PairScores] = []
        coverage: list[float | None] = []
        for frame, exclude in picked:
            pose = perturbed_pose(frame.T(), lateral_m=lateral, yaw_deg=yaw)
            camera = frame.camera()
            key = (frame.index, lateral, yaw)
            if key not in renders:
                r = renderer.render(pose, camera)
                renders[key] = (r.rgb, r.coverage)
            splat, cov = renders[key]
            truth_pose = pose.copy()
            if reference.ground_z is not None:
                truth_pose[2, 3] -= reference.ground_z(pose[:2, 3])
            truth = reference.camera.render(truth_pose, camera, sensor_noise=False).rgb
            scores.append(score_pair(truth, splat, exclude, lpips))
            coverage.append(cov)
            done += 1
            progress("splat truth envelope", done, total)
        rows.append(
            TruthScore(
                lateral_m=lateral,
                yaw_deg=yaw,
                psnr_db=summarise([s.psnr for s in scores]),
                ssim=summarise([s.ssim for s in scores]),
                lpips=summarise([s.lpips for s in scores]),
                coverage=summarise(coverage),
            )
        )
        _log.debug("truth envelope %s: %s", rows[-1].label(), _means(rows[-1]))
    notes = [] if lpips is not None else ["LPIPS not computed against the truth"]
    envelope = TruthEnvelope(
        frames=[f.index for f, _ in picked],
        sensor_noise=False,
        lpips_net=lpips_net if lpips is not None else None,
        scores=rows,
        notes=notes,
    )
    on_path = envelope.on_path()
    if on_path is not None:
        _log.info(
            "splat vs truth: %d frames x %d poses; on path %s",
            len(picked),
            len(perturbations),
            _means(on_path),
        )
    return envelope


def _means(row: TruthScore) -> str:
    def fmt(s: MetricSummary, spec: str) -> str:
        return "n/a" if s.mean is None else format(s.mean, spec)

    return (
        f"PSNR {fmt(row.psnr_db, '.2f')} dB, SSIM {fmt(row.ssim, '.3f')}, "
        f"LPIPS {fmt(row.lpips, '.3f')}, coverage {fmt(row.coverage, '.2f')}"
    )


@dataclass(frozen=True)
class RigView:
    """A rig camera whose real frames score the splat off the path (:mod:`cam2sim.stages.rig`).

    Attributes:
        name: The camera's name.
        T_front_cam: ``(4, 4)`` its optical axes -> the front camera's.
        camera: Its intrinsics at full size (a pinhole: rig frames are taken as rectified).
        front_width: The front camera's full width: the prepared frames' scale is taken from it.
        frame_file: Its image at a dataset frame number.
        lateral_m: Its offset from the front camera along the front camera's x, m (+ right).
        yaw_deg: Its turn from the front camera, degrees (+ left).
    """

    name: str
    T_front_cam: npt.NDArray[np.float64]
    camera: PinholeCamera
    front_width: int
    frame_file: Callable[[int], Path]
    lateral_m: float = 0.0
    yaw_deg: float = 0.0


def rig_scores(
    renderer: SplatRenderer,
    rig: Sequence[RigView],
    frames: Sequence[FrameRecord],
    *,
    lpips: Lpips | None,
    max_frames: int | None = 12,
) -> list[RigScore]:
    """The splat against each rig camera's real frames at held-out front poses.

    At each picked held-out frame (``max_frames`` spread evenly) the splat renders the rig
    camera's view (the front pose times ``T_front_cam``, its intrinsics at the prepared frames'
    scale) and is scored against that camera's recorded frame, resized to the same size: real
    pixels where the front camera never was.
    """
    import cv2  # noqa: PLC0415

    from cam2sim.core.images import read_rgb  # noqa: PLC0415

    picked = [frames[i] for i in even_picks(len(frames), max_frames)]
    rows: list[RigScore] = []
    for view in rig:
        scores: list[PairScores] = []
        coverage: list[float | None] = []
        for frame in picked:
            scale = frame.width / view.front_width
            size = (round(view.camera.width * scale), round(view.camera.height * scale))
            camera = view.camera.scaled(*size)
            pose = frame.T() @ view.T_front_cam
            real = read_rgb(view.frame_file(frame.dataset_frame))
            if (real.shape[1], real.shape[0]) != size:
                real = np.asarray(cv2.resize(real, size, interpolation=cv2.INTER_AREA), np.uint8)
            rendered = renderer.render(pose, camera)
            scores.append(score_pair(real, rendered.rgb, None, lpips))
            coverage.append(rendered.coverage)
        rows.append(
            RigScore(
                name=view.name,
                lateral_m=view.lateral_m,
                yaw_deg=view.yaw_deg,
                frames=[f.index for f in picked],
                psnr_db=summarise([s.psnr for s in scores]),
                ssim=summarise([s.ssim for s in scores]),
                lpips=summarise([s.lpips for s in scores]),
                coverage=summarise(coverage),
            )
        )
        _log.info("splat vs rig camera %s: %s", view.name, _means_rig(rows[-1]))
    return rows


def _means_rig(row: RigScore) -> str:
    psnr = f"{row.psnr_db.mean:.1f} dB" if row.psnr_db.mean is not None else "- dB"
    ssim = f"SSIM {row.ssim.mean:.3f}" if row.ssim.mean is not None else "SSIM -"
    return f"{row.label()}: {psnr}, {ssim}, {len(row.frames)} frames"
