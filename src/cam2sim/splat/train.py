"""Stage splat, training: one Gaussian-splat model per route chunk of a prepared scene.

Reads ``WS/splat/prep/`` (:mod:`cam2sim.splat.scene`), writes ``WS/splat/models/chunk_XX.pt``
(+ ``.json`` header, :mod:`cam2sim.splat.model`). How one chunk trains (initialisation, loss,
appearance, densification, stopping, time budget) is :mod:`cam2sim.splat.chunk_trainer`.

:func:`train_scene` trains several chunks at a time on one device, each in its own worker
process (``concurrent_chunks``; on CUDA by default 2 or 3, by the number of chunks:
:func:`~cam2sim.splat.parallel.cuda_slots`), or, with
``concurrent_chunks=1`` (the default on CPU), all chunks in one loop, one step of each in turn.
Each chunk stops on its own plateau. torch and gsplat are imported inside functions only.
The options and results are typed records in :mod:`cam2sim.splat.train_options` (re-exported
here).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path

from cam2sim.core.errors import StageError
from cam2sim.core.machine import gpu_sharers
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.splat.chunk_trainer import STREET_SCALE_M, ChunkTrainer
from cam2sim.splat.parallel import cuda_slots, shared_gpu_slots, train_chunks_in_processes
from cam2sim.splat.raster import build_gsplat, resolve_backend, resolve_device
from cam2sim.splat.scene import SceneRecord, load_points
from cam2sim.splat.stop import time_share
from cam2sim.splat.train_options import (
    MCMC_MIN_STEPS,
    DensifyOptions,
    LearningRates,
    SceneTrainResult,
    TrainOptions,
    TrainResult,
    chunk_result_path,
    resolve_options,
)

__all__ = [
    "MCMC_MIN_STEPS",
    "STREET_SCALE_M",
    "DensifyOptions",
    "LearningRates",
    "SceneTrainResult",
    "TrainOptions",
    "TrainResult",
    "resolve_options",
    "train_chunk",
    "train_scene",
]

_log = logging.getLogger(__name__)


def train_chunk(
    scene: SceneRecord,
    chunk_id: int,
    prep_dir: Path,
    options: TrainOptions | None = None,
    progress: ProgressCallback = no_progress,
    *,
    models_dir: Path | None = None,
) -> TrainResult:
    """Train the model of one chunk and write ``models_dir/chunk_XX.pt``.

    Args:
        scene: The prepared scene (``prep_dir/scene.json``).
        chunk_id: Which chunk.
        prep_dir: ``WS/splat/prep``.
        options: Training options (defaults: :class:`TrainOptions`).
        progress: Called with ``("splat steps", done, cap)``.
        models_dir: Output folder; default ``prep_dir/../models`` (``WS/splat/models``).

    Returns:
        The chunk's result.

    Raises:
        StageError: Unknown chunk, or inputs that cannot be trained on.
    """
    result = train_scene(
        prep_dir,
        options=options,
        chunk_ids=(chunk_id,),
        models_dir=models_dir,
        progress=progress,
        scene=scene,
    )
    return result.chunks[0]


def _default_slots(device: str, n_chunks: int) -> int:
    """Chunks at a time when the options leave it open.

    :func:`cuda_slots` on a GPU of its own; on a GPU other processes share
    (:func:`~cam2sim.core.machine.gpu_sharers`) 2 or 1, as its memory allows
    (:func:`~cam2sim.splat.parallel.shared_gpu_slots`); 1 on the CPU.
    """
    if not device.startswith("cuda"):
        return 1
    import torch  # noqa: PLC0415

    gib = torch.cuda.get_device_properties(device).total_memory / 2**30
    sharers = gpu_sharers()
    return shared_gpu_slots(n_chunks, gib, sharers) if sharers > 1 else cuda_slots(n_chunks, gib)


def train_scene(
    prep_dir: Path,
    *,
    options: TrainOptions | None = None,
    chunk_ids: tuple[int, ...] | None = None,
    models_dir: Path | None = None,
    progress: ProgressCallback = no_progress,
    scene: SceneRecord | None = None,
) -> SceneTrainResult:
    """Train every chunk (or ``chunk_ids``) of a prepared scene side by side on one device.

    With ``options.concurrent_chunks`` above 1, or left open on CUDA (2 or 3 at a time:
    :func:`~cam2sim.splat.parallel.cuda_slots`; 1 or 2 on a shared GPU:
    :func:`~cam2sim.splat.parallel.shared_gpu_slots`), and several chunks, each
    chunk trains in its own worker process, that many at a time
    (:func:`cam2sim.splat.parallel.train_chunks_in_processes`); a worker trains its chunk
    exactly as this function trains one chunk alone. Otherwise one step of each unfinished
    chunk runs in turn in this process. Either way a chunk that reaches its plateau (or step
    cap) is written at once.

    Args:
        prep_dir: ``WS/splat/prep``.
        options: Training options.
        chunk_ids: Chunks to train; None = all.
        models_dir: Output folder; default ``prep_dir/../models``.
        progress: Called with ``("splat steps", done, cap)`` (cap = chunks times max_steps).
        scene: The scene record, if already loaded.

    Returns:
        Per-chunk results and totals.

    Raises:
        StageError: No such chunk, or inputs that cannot be trained on (with worker
            processes: raised after the other chunks finished, naming each failed chunk).
        BackendUnavailableError: The gsplat backend was asked for where it cannot run.
    """
    import torch  # noqa: PLC0415

    start = time.perf_counter()
    options = options or TrainOptions()
    prep_dir = Path(prep_dir)
    models_dir = prep_dir.parent / "models" if models_dir is None else Path(models_dir)
    scene = SceneRecord.load(prep_dir / "scene.json") if scene is None else scene
    known = {c.id: c for c in scene.chunks}
    wanted = sorted(known) if chunk_ids is None else list(chunk_ids)
    unknown = [c for c in wanted if c not in known]
    if unknown or not wanted:
        msg = f"no chunk {unknown or wanted} in {prep_dir / 'scene.json'}; known: {sorted(known)}"
        raise StageError(msg)
    device = resolve_device(options.device)
    backend = resolve_backend(options.backend, device)
    in_flight = options.concurrent_chunks or _default_slots(device, len(wanted))
    # Left open on CUDA, chunks train in worker processes even one at a time (a shared GPU's
    # slot rule may give one): a worker holds one chunk's Gaussians, the interleaved loop below
    # all of a street's at once, and the next chunk loads while one trains.
    one_by_one = options.concurrent_chunks is None and device.startswith("cuda")
    if len(wanted) > 1 and (in_flight > 1 or one_by_one):
        slots = min(in_flight, len(wanted))
        return train_chunks_in_processes(
            train_scene,
            prep_dir,
            scene,
            tuple(wanted),
            replace(
                options,
                device=device,
                backend=backend,
                time_budget_s=time_share(
                    options.time_budget_s, len(wanted), slots, per_chunk=options.budget_per_chunk
                ),
                budget_per_chunk=True,  # the share above is each worker's chunk's
            ),
            models_dir=models_dir,
            in_flight=slots,
            progress=progress,
        )
    if backend == "gsplat":
        build_gsplat()  # before the clock of the first step starts
    torch.manual_seed(options.seed)
    if device.startswith("cuda"):
        torch.cuda.reset_peak_memory_stats(device)
    points = load_points(prep_dir / "points.npz")[:2]
    share = time_share(options.time_budget_s, len(wanted), 1, per_chunk=options.budget_per_chunk)
    trainers = [
        ChunkTrainer(known[c], scene, prep_dir, points, options, device, backend, share)
        for c in wanted
    ]
    _log.info("training %d chunk(s) on %s with the %s rasterizer", len(trainers), device, backend)
    results = _train_in_turn(trainers, options.max_steps, models_dir, progress)
    peak = int(torch.cuda.max_memory_allocated(device)) if device.startswith("cuda") else None
    return SceneTrainResult(
        chunks=tuple(results[c] for c in wanted),
        seconds=time.perf_counter() - start,
        peak_memory_bytes=peak,
    )


def _train_in_turn(
    trainers: list[ChunkTrainer], max_steps: int, models_dir: Path, progress: ProgressCallback
) -> dict[int, TrainResult]:
    """One step of each unfinished chunk in turn; a chunk is written as soon as it is done."""
    results: dict[int, TrainResult] = {}
    cap = len(trainers) * max_steps
    done_steps = 0
    active = list(trainers)
    while active:
        for trainer in list(active):
            trainer.step()
            done_steps += 1
            if trainer.done:
                results[trainer.chunk.id] = result = trainer.save(models_dir)
                result.save(chunk_result_path(models_dir, trainer.chunk.id))
                active.remove(trainer)
                done_steps += max_steps - trainer.step_no
        progress("splat steps", done_steps, cap)
    return results
