"""Splat chunks trained in parallel on a Ray cluster: one task per chunk, one GPU each.

``cam2sim splat WS --ray ADDRESS`` trains every chunk of the prepared scene as its own Ray task
calling :func:`cam2sim.splat.train.train_chunk`, so the models folder is what
:func:`cam2sim.splat.train.train_scene` writes (``WS/splat/models/chunk_XX.pt`` and its
``.json``). Ray gives each task its GPU (``CUDA_VISIBLE_DEVICES``), so ``device: auto`` trains on
it. The workspace must sit on a file system every node sees at the same path. A chunk that
fails does not stop the others; the stage fails afterwards, naming it. A chunk that ran out of
GPU memory (tasks given fractions of one GPU) trains once more, as one whose worker died.

One chunk per GPU trains each model alone, as :func:`train_scene`'s worker processes on one GPU
do. Failures are collected and reported as there (:class:`cam2sim.splat.parallel.ChunkOutcomes`).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cam2sim.core.cluster import LOST_WORKER_RETRIES, ray_session
from cam2sim.core.errors import StageError
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.splat.parallel import ChunkOutcomes
from cam2sim.splat.scene import SceneRecord
from cam2sim.splat.stop import time_share
from cam2sim.splat.train import train_chunk

if TYPE_CHECKING:
    from cam2sim.splat.train import SceneTrainResult, TrainOptions, TrainResult

__all__ = ["train_scene_on_ray"]

logger = logging.getLogger(__name__)


def _train_one(
    scene: SceneRecord, chunk_id: int, prep_dir: str, options: TrainOptions | None, models: str
) -> tuple[TrainResult, int | None]:
    """Ray task: train one chunk; its result and the peak CUDA memory (None on CPU)."""
    import torch  # noqa: PLC0415

    result = train_chunk(scene, chunk_id, Path(prep_dir), options, models_dir=Path(models))
    device = result.device
    peak = int(torch.cuda.max_memory_allocated(device)) if device.startswith("cuda") else None
    return result, peak


def train_scene_on_ray(
    prep_dir: Path,
    *,
    address: str = "local",
    options: TrainOptions | None = None,
    models_dir: Path | None = None,
    progress: ProgressCallback = no_progress,
    scene: SceneRecord | None = None,
    gpus_per_chunk: float | None = None,
    chunk_ids: tuple[int, ...] | None = None,
) -> SceneTrainResult:
    """Train every chunk of a prepared scene, one Ray task (and ``gpus_per_chunk`` GPUs) each.

    Args:
        prep_dir: ``WS/splat/prep``.
        address: Ray cluster address (``auto``, ``HOST:PORT``) or ``local``.
        options: Training options.
        models_dir: Output folder; default ``prep_dir/../models``.
        progress: Called with ``("splat chunks", done, chunks)``.
        scene: The scene record, if already loaded.
        gpus_per_chunk: GPUs a task asks for; None: 1, or 0 with ``device="cpu"``.
        chunk_ids: Chunks to train; None = all.

    Returns:
        Per-chunk results and totals (peak memory: the largest of one chunk's GPU).

    Raises:
        StageError: The scene has no chunks, the cluster has no GPU, or chunks failed (after
            the others finished).
        BackendUnavailableError: Ray is not installed.
    """
    start = time.perf_counter()
    prep_dir = Path(prep_dir).resolve()
    models = prep_dir.parent / "models" if models_dir is None else Path(models_dir).resolve()
    scene = SceneRecord.load(prep_dir / "scene.json") if scene is None else scene
    ids = sorted(c.id for c in scene.chunks if chunk_ids is None or c.id in chunk_ids)
    if not ids:
        msg = f"{prep_dir / 'scene.json'} has no chunks; run `cam2sim splat WS` to prepare it"
        raise StageError(msg)
    outcomes = ChunkOutcomes(ids, "on Ray")
    cpu = options is not None and options.device == "cpu"
    gpus = (0.0 if cpu else 1.0) if gpus_per_chunk is None else gpus_per_chunk
    with ray_session(address) as ray:
        have = float(ray.cluster_resources().get("GPU", 0.0))
        if gpus > have:
            msg = f"the Ray cluster at {address} has {have:g} GPUs, a chunk needs {gpus:g}; "
            msg += "add GPU nodes, or train on CPU workers with --device cpu"
            raise StageError(msg)
        # A chunk whose worker or node died, or that ran out of GPU memory (a GPU shared by
        # fractional tasks), trains once more (Ray counts both alike; its model is written
        # atomically, so nothing half-written is read); one that fails otherwise (diverges) is
        # reported.
        import torch  # noqa: PLC0415 -- the exception type Ray retries on

        task = ray.remote(_train_one).options(
            num_gpus=gpus,
            num_cpus=1,
            max_retries=LOST_WORKER_RETRIES,
            retry_exceptions=[torch.OutOfMemoryError],
        )
        if options is not None and options.time_budget_s is not None:
            # Each chunk's share of the budget: as many run at once as the cluster has room for.
            slots = int(have // gpus) if gpus > 0 else int(ray.cluster_resources().get("CPU", 1))
            share = time_share(
                options.time_budget_s, len(ids), slots, per_chunk=options.budget_per_chunk
            )
            options = dataclasses.replace(options, time_budget_s=share, budget_per_chunk=True)
        pending: dict[Any, int] = {
            task.remote(scene, c, str(prep_dir), options, str(models)): c for c in ids
        }
        logger.info("training %d chunk(s) on Ray (%s)", len(ids), address)
        progress("splat chunks", 0, len(ids))
        while pending:
            ready, _ = ray.wait(list(pending), num_returns=1)
            for ref in ready:
                chunk = pending.pop(ref)
                try:
                    outcomes.succeeded(chunk, *ray.get(ref))
                except ray.exceptions.RayError as err:
                    # A chunk's own error (RayTaskError wraps it) says what to fix; Ray's
                    # wrapper only where the worker or node died.
                    cause = getattr(err, "cause", None) or err
                    outcomes.failed(chunk, f"{type(cause).__name__}: {cause}")
                progress("splat chunks", outcomes.finished, len(ids))
    hint = "see the Ray logs and run `cam2sim splat WS --ray ...` again"
    return outcomes.scene_result(start, hint=hint)
