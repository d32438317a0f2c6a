"""Reconstruction quality: rendered images and the simulated world against the real ones.

Two comparisons at recorded poses, written under ``WS/report/`` where the report finds them:

- **image quality** (:func:`evaluate_replay_images`): every camera of a replay run (``splat``,
  ``raster`` = the simulator's images) against the recorded frames, paired by frame number, with
  PSNR, SSIM and, when its weights are on the machine, LPIPS (skipped with a note otherwise);
  ``images/<camera>/images.json`` and ``images.csv``;
- **steering agreement** (:func:`evaluate_replay_steering`): the policy the drives use
  (DAVE-2) on each camera's replay frames and on the recorded frames of the same poses, the gap
  frame by frame: does the rendered image change what the system under test does, on real
  data; ``images/<camera>/steering.json``;
- **semantic IoU** (:func:`evaluate_world_semantics`): at every ``every``-th recorded pose, the
  labels of the ground-truth world (``truth`` camera, ``WS/truth/world.json``) against the labels
  of the simulated world the pipeline built (map, detected parked cars, OSM buildings; the
  raster renderer draws labels in the same pass as colours), per class and mIoU;
  ``semantic/semantic.json``, the label images and comparison images.
"""

from __future__ import annotations

import logging
from functools import partial
from typing import TYPE_CHECKING, Any

import numpy as np

from cam2sim.core.background import BackgroundJobs
from cam2sim.core.errors import Cam2SimError, StageError
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.workspace import dataset_paths
from cam2sim.metrics.image_quality import (
    ImageQualityOptions,
    evaluate_image_folders,
    write_image_quality,
)
from cam2sim.metrics.lpips import load_lpips
from cam2sim.metrics.semantic import SemanticOptions, evaluate_semantic_folders
from cam2sim.render.raster import raster_palette
from cam2sim.stages.cameras import (
    TRUTH_CAMERA,
    Cameras,
    camera_poses,
    first_decision,
    load_run_context,
    scaled_intrinsics,
    view_policy,
    write_png,
)

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    from cam2sim.core.workspace import Workspace
    from cam2sim.metrics.lpips import Lpips
    from cam2sim.sim.interface import SteeringPolicy

__all__ = ["evaluate_replay_images", "evaluate_replay_steering", "evaluate_world_semantics"]

logger = logging.getLogger(__name__)


def _lpips() -> tuple[Lpips | None, str]:
    """The LPIPS network from the local cache, or None and why (it is never downloaded here)."""
    try:
        return load_lpips("alex", download=False), ""
    except (Cam2SimError, OSError, RuntimeError) as err:
        return None, f"LPIPS skipped: its weights are not on this machine ({err})"


def evaluate_replay_images(
    ws: Workspace, replay_run: Path, out: Path, *, progress: ProgressCallback | None = None
) -> tuple[list[Path], str]:
    """Score every camera folder of a replay run against the recorded frames.

    Returns:
        The ``images.json`` paths written (one per camera) and a note (LPIPS skipped, or "").
    """
    real_dir = dataset_paths(ws.dataset_dir).frames_dir
    cameras = sorted(p for p in (replay_run / "frames").glob("*") if p.is_dir())
    if not cameras:
        msg = f"replay run {replay_run.name} saved no frames; replay with save_frames"
        raise StageError(msg)
    model, note = _lpips()
    options = ImageQualityOptions(lpips_net=None)
    written = []
    for cam in cameras:
        result = evaluate_image_folders(
            real_dir, cam, options=options, lpips_model=model, progress=progress or no_progress
        )
        written.append(write_image_quality(result, out / cam.name)[0])
    if note:
        logger.info("%s", note)
    return written, note


def evaluate_replay_steering(
    ws: Workspace,
    replay_run: Path,
    out: Path,
    policy: Path,
    *,
    progress: ProgressCallback | None = None,
) -> list[Path]:
    """The policy's steering on every camera's replay frames against the recorded frames.

    Each frame pair (same frame number) is shown to the policy as the first decision of a run;
    ``out/<camera>/steering.json`` holds both series and their gaps
    (:mod:`cam2sim.metrics.steering_agreement`).

    Returns:
        The ``steering.json`` paths written (one per camera with frame pairs).

    Raises:
        StageError: The replay saved no frames, or the policy cannot be loaded.
    """
    from cam2sim.metrics.steering_agreement import steering_agreement  # noqa: PLC0415

    real_dir = dataset_paths(ws.dataset_dir).frames_dir
    cameras = sorted(p for p in (replay_run / "frames").glob("*") if p.is_dir())
    if not cameras:
        msg = f"replay run {replay_run.name} saved no frames; replay with save_frames"
        raise StageError(msg)
    if not real_dir.is_dir():
        msg = f"{real_dir} does not exist: no recorded frames to compare the replay's with"
        raise StageError(msg)
    real = {f.stem: f for f in real_dir.iterdir() if f.is_file()}
    model = view_policy(str(policy), load_run_context(ws).scenario)
    on_recorded: dict[str, float] = {}  # every camera is compared with the same frames
    written = []
    try:
        with BackgroundJobs[Any](name="cam2sim-steering") as reader:
            for cam in cameras:
                pairs = sorted((f.stem, f) for f in cam.iterdir() if f.stem in real)
                if not pairs:
                    continue
                report = partial(progress or no_progress, f"DAVE-2 on {cam.name} and recorded")
                steer_real, steer_sim = _pair_steering(
                    model, [(real[stem], f) for stem, f in pairs], on_recorded, reader, report
                )
                held = _held_out_pairs(ws) if cam.name == "splat" else []
                result = steering_agreement(
                    cam.name, str(policy), [stem for stem, _ in pairs], steer_real, steer_sim,
                    held_out=_pair_steering(
                        model, held, {}, reader, partial(no_progress, "held out")
                    ),
                )  # fmt: skip
                path = out / cam.name / "steering.json"
                path.parent.mkdir(parents=True, exist_ok=True)
                result.save(path)
                written.append(path)
    finally:
        model.close()
    return written


def _pair_steering(
    model: SteeringPolicy,
    pairs: list[tuple[Path, Path]],
    on_recorded: dict[str, float],
    reader: BackgroundJobs[Any],
    report: Callable[[int, int | None], None],
) -> tuple[list[float], list[float]]:
    """The policy's first decision on each (recorded, replayed) frame pair.

    The frames are read ahead on ``reader``'s worker threads while the policy answers on this
    one; a recorded frame's answer is kept in ``on_recorded`` (by its stem) and not asked
    again.
    """
    from cam2sim.core.images import read_rgb  # noqa: PLC0415 -- lazy: cv2

    def read(pair: tuple[Path, Path]) -> tuple[Any, Any]:
        recorded, replayed = pair  # the recorded frame only where its answer is not known yet
        known = recorded.stem in on_recorded
        return (None if known else read_rgb(recorded)), read_rgb(replayed)

    steer_real, steer_sim = [], []
    for k, ((recorded, _), (real_rgb, sim_rgb)) in enumerate(
        zip(pairs, reader.imap(read, pairs), strict=True)
    ):
        if real_rgb is not None:
            on_recorded[recorded.stem] = first_decision(model, real_rgb)
        steer_real.append(on_recorded[recorded.stem])
        steer_sim.append(first_decision(model, sim_rgb))
        report(k + 1, len(pairs))
    return steer_real, steer_sim


def _held_out_pairs(ws: Workspace) -> list[tuple[Path, Path]]:
    """The splat's held-out views: (its prepared recorded image, its render), when kept.

    The splat stage renders every held-out frame (``splat/renders/NNNNNN.webp``, by the
    prepared frame's number) beside the prepared image it is scored against
    (``splat/prep/images/NNNNNN.png``): same pose, same lens, never trained on.
    """
    renders = ws.splat_files.renders_dir
    images = ws.splat_files.prep_images_dir
    if not renders.is_dir():
        return []
    pairs = [(images / f"{r.stem}.png", r) for r in sorted(renders.glob("*.webp"))]
    return [(a, b) for a, b in pairs if a.is_file()]


def evaluate_world_semantics(
    ws: Workspace, out: Path, *, every: int = 10, progress: ProgressCallback | None = None
) -> Path:
    """Semantic IoU of the simulated world against the ground-truth world at recorded poses.

    Returns:
        The ``semantic.json`` path.

    Raises:
        StageError: No scenario, or no ground-truth world (``WS/truth/world.json``).
    """
    report = progress or no_progress
    ctx = load_run_context(ws)
    sc = ctx.scenario
    tr = sc.trajectory
    idx = np.arange(0, len(tr.frame), max(every, 1))
    ref = np.asarray(tr.reference, dtype=np.float64)[idx]
    heading = np.asarray(tr.heading, dtype=np.float64)[idx]
    # Both worlds' road is z = 0: the camera stands at its mount height above it.
    z = np.full(idx.size, sc.vehicle.reference_xyz[2])
    poses = camera_poses(sc, ref[:, :2], heading, z)
    camera = scaled_intrinsics(sc, None)
    with Cameras(ctx, ("raster", TRUTH_CAMERA)) as cameras:
        sim, truth = cameras.renderers["raster"], cameras.renderers[TRUTH_CAMERA]
        for k, i in enumerate(idx.tolist()):
            stem = f"{tr.frame[i]:06d}.png"
            write_png(out / "real" / stem, truth.render(poses[k], camera).semantic_rgb())
            write_png(out / "sim" / stem, sim.render(poses[k], camera).semantic_rgb())
            report("semantic frames", k + 1, int(idx.size))
    result = evaluate_semantic_folders(
        out / "real",
        out / "sim",
        options=SemanticOptions(palette=raster_palette()),
        comparison_dir=out / "comparison",
        progress=report,
    )
    result.save(out / "semantic.json")
    return out / "semantic.json"
