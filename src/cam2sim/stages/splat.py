"""Stage splat: prepare the recording for Gaussian splatting, train chunk models, evaluate them.

``WS/splat/prep/`` (frames, masks, initial points: :mod:`cam2sim.splat.prepare`),
``WS/splat/models/chunk_XX.pt`` (:mod:`cam2sim.splat.train`; gsplat on CUDA, the pure-torch
rasterizer on CPU) and ``WS/splat/eval.json`` (:mod:`cam2sim.splat.evaluate`). Where the
workspace has a ground-truth world (``WS/truth/world.json``), the evaluation also scores the
models against it on and off the recorded path (:mod:`cam2sim.splat.envelope`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import shutil
import time
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Final

from cam2sim.core.dataset import Calibration, DatasetInfo, RigCamera
from cam2sim.core.errors import Cam2SimError, StageError
from cam2sim.core.files import file_fingerprint, write_text_atomic
from cam2sim.core.machine import gpu_sharers
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.workspace import Workspace, dataset_paths, hash_inputs
from cam2sim.metrics.lpips import prefetch_lpips_sdist
from cam2sim.render.truth import TruthRenderer, truth_world_path
from cam2sim.scenario.model import Scenario
from cam2sim.splat.distributed import train_scene_on_ray
from cam2sim.splat.envelope import RigView, TruthEnvelopeOptions, TruthReference, rig_scores
from cam2sim.splat.evaluate import EvalOptions, evaluate_splat
from cam2sim.splat.prepare import PrepareOptions, prepare_scene
from cam2sim.splat.render import RenderOptions, SplatRenderer
from cam2sim.splat.scene import SceneRecord
from cam2sim.splat.train import TrainOptions, train_scene
from cam2sim.splat.train_options import (
    RESULTS_DIR,
    DensifyOptions,
    LearningRates,
    SceneTrainResult,
    TrainResult,
)
from cam2sim.stages._runner import stage_run
from cam2sim.stages.cameras import ground_height_at
from cam2sim.stages.rig import rig_offset

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

    import numpy as np
    import numpy.typing as npt

    from cam2sim.splat.evaluate import SplatEval
    from cam2sim.splat.scores import RigScore

__all__ = ["SplatResult", "SplatStageOptions", "run_splat"]

logger = logging.getLogger(__name__)
STAGE = "splat"


DEMO_CPU_SPLAT_BUDGET_S: Final = 300.0
"""Most training seconds of each chunk of the demo's CPU splat: 1,400 steps of a chunk take
about 140 s on the 2-core machine (docs/benchmarks.md); a slower one stops at the budget (a
warning in the report), so a chunk cannot hold the demo up for long."""
DEMO_CPU_MAX_GAUSSIANS: Final = 120_000
"""No more growth of a chunk of the demo's CPU splat once it has this many Gaussians (it starts
from 40k): a safety cap, which the refinement step that crosses it can overshoot (KITTI 03's
chunks: 101-145k). The 3DGS growth rule itself takes the chunks to 71-131k in 1,400 steps
(the same with a cap of 250k on munich route 0), for about 20 % more time on the CPU suite
and closed-loop runs nearer Real's on 3 of its 4 streets (docs/benchmarks.md)."""
DEMO_GPU_SPLAT_STEPS: Final = (2_500, 5_000)
"""Fewest and most training steps of a chunk of the demo's CUDA splat (between them the chunk
stops on its plateau). Up to 2026-12-06 the most was 2,500, and every chunk of the 14-street GPU
suite stopped there still gaining (none reached its plateau); on West-Oakland route 0, whose
splat runs kept 1.92x Real's Min-Fréchet from the recorded line, 5,000 steps took the held-out
splat from 30.0 to 31.3 dB and the ratio to 0.97, the world 289 s alone on an H100
(docs/benchmarks.md, "The GPU suite's splats stopped short")."""
DEMO_GPU_PLATEAU_PATIENCE: Final = 7
"""Validation intervals (of 250 steps) in the plateau trend of the demo's CUDA splat: 1,750
steps. The held-in PSNR and SSIM of a validation scatter about a chunk's curve by 0.26 dB and
0.0019; over the 750 steps of patience 3 that noise alone moves the trend by about 0.5 dB and
0.0035 per 1,000 steps, the size of the minimum gains, so 9 of 12 chunks of four untuned
streets stopped at 3,250-4,750 steps on a dip although their fitted SSIM trend stayed above the
minimum until 4,500-5,500 (``benchmarks/plateau_rule.py``; docs/benchmarks.md, "The GPU demo's
preset on four untuned streets")."""
DEMO_GPU_INIT_POINTS: Final = 250_000
"""About this many starting points a chunk of the demo's CUDA splat (``max_init_points``: far
points thinned, the road within about 20 m of the path kept whole; a chunk with fewer keeps
them all). Seeded with every LiDAR voxel its views see, a chunk of a long straight street
started from up to 0.6M Gaussians, three quarters of a view's tile pairs beyond 50 m, and the
device-bound steps paid for them. From 250,000, on the five untuned streets of
``streets-gpu-alone-thinned.yaml`` alone on an H100: the splats' training 1,314 -> 1,139 s in
all (Munich route 2 373 -> 291 s, chunk 0 55 -> 34 ms a step, 1.03M -> 0.71M Gaussians at the
end), held-out PSNR within 0.3 dB and SSIM within 0.001 of the full start, Real 0/15,
splat 0/15, Sim 12/15, splat within 1.5x of Real's Min-Fréchet on 5 of 5 as before
(docs/benchmarks.md, "Five untuned streets alone on an H100, the far points thinned")."""
DEMO_GPU_MAX_GAUSSIANS: Final = 400_000
"""No more growth of a chunk of the demo's CUDA splat once it has this many Gaussians (pruning
goes on). From :data:`DEMO_GPU_INIT_POINTS` the 3DGS growth rule took a long street's chunks to
0.69-0.75M by 5,000 steps, and a step's device time grows about linearly with the Gaussians.
Capped, Munich route 2 alone on an H100 (the street it was chosen on): its splat 291 -> 220 s,
the world 351 -> 271 s, held-out PSNR 31.69 -> 31.70 dB, SSIM 0.906 -> 0.905, the chunks on
their plateau at 4,250-4,750 steps instead of 5,000, splat runs 0/3 at 0.03 m Min-Fréchet
(Real 0.09); Munich route 3 (not used to choose it): the world in 193 s, 30.8 dB and 0.903
(30.6 and 0.900 on the older preset), splat 0/3, Sim 3/3 (docs/benchmarks.md, "A cap of 400,000
Gaussians a chunk on the GPU")."""
DEMO_GPU_SPLAT_BUDGET_S: Final = 300.0
"""A safety cap on each chunk's training seconds on a GPU of its own, far above what the
preset's steps take (5,000 steps in about 145 s with three chunks of a street sharing an
H100; 120 s when the most was 2,500): it ends only a chunk that something
else slows badly, and such a chunk is a warning in the report. The preset counts steps, not
seconds: a budget of 25 s a chunk gave chunks of one street 444 and 2,907 steps (issue 37). A
GPU shared by N processes (:func:`~cam2sim.core.machine.gpu_sharers`) gives each N times as
long: four benchmark worlds on one H200 stopped 12 of their 25 chunks on the 120 s cap, one
after 570 steps."""

RUN_GPU_SPLAT_STEPS: Final = 10_000
"""Training steps of each chunk in ``cam2sim run`` on CUDA (MCMC densification to a cap of one
million Gaussians). Twice the Gaussians and 12,000 steps gained 0.022 held-out SSIM on KITTI 03
(0.794) for 19.3 minutes instead of 14.3 (docs/benchmarks.md, "seventh run")."""
RUN_GPU_POSE_RATE: Final = 1e-5
"""Pose refinement in ``cam2sim run``'s CUDA splat (``LearningRates.poses``): on KITTI 03's
weakest chunk it gained 0.64 dB and 0.029 held-out SSIM at 10,000 steps for about 10 % more
time a step (1e-4: no gain), more than twice the Gaussians gained at twice the time a step
(docs/benchmarks.md, "Splat training on chunk 0: pose refinement")."""
RUN_GPU_SSIM_WEIGHT: Final = 0.4
"""Weight of ``1 - SSIM`` in the loss of ``cam2sim run``'s CUDA splat (0.2 elsewhere): on
KITTI 03's chunk 0 it gained 0.006 held-out SSIM for 0.24 dB (docs/benchmarks.md, "Splat
training on chunk 0 for SSIM")."""
RUN_GPU_SPLAT_BUDGET_S: Final = 480.0
"""A safety cap on each chunk's training seconds in ``cam2sim run`` on a GPU of its own:
10,000 MCMC steps of a real chunk with pose refinement take about 235 s beside two others on
an H100 (docs/benchmarks.md); N times as long on a GPU shared by N processes, as
:data:`DEMO_GPU_SPLAT_BUDGET_S`."""


@dataclass(frozen=True)
class SplatStageOptions:
    """What ``cam2sim splat`` does; None options take each step's defaults.

    Attributes:
        prepare: Preparation options.
        train: Training options.
        evaluate: Write ``eval.json``.
        lpips_weights: LPIPS weights for the evaluation (None: the cache).
        offsets_m: Lateral offsets of the relative envelope (render against render).
        truth_envelope: Also score against the ground-truth world when the workspace has one.
        truth: What that measures (None: :class:`~cam2sim.splat.envelope.TruthEnvelopeOptions`
            defaults: +-0.5, 1, 2 m and +-5 degrees at 12 held-out frames).
        steps: Steps to run.
    """

    prepare: PrepareOptions | None = None
    train: TrainOptions | None = None
    evaluate: bool = True
    lpips_weights: Path | None = None
    offsets_m: tuple[float, ...] = (-2.0, -1.0, -0.5, 0.5, 1.0, 2.0)
    truth_envelope: bool = True
    truth: TruthEnvelopeOptions | None = None
    steps: tuple[str, ...] = field(default=("prepare", "train", "evaluate"))

    @classmethod
    def demo(cls, *, cuda: bool = False) -> SplatStageOptions:
        """The demo's splat preset: each chunk trains to its own plateau, counted in steps.

        After ``min_steps`` a chunk stops when its held-in PSNR gains less than ``min_gain_db``
        per 1,000 steps (:func:`cam2sim.splat.stop.plateau_reached`), else at ``max_steps``;
        the time budget a chunk is a safety cap only (docs/benchmarks.md, "The street
        benchmark": a time rule starved the chunks with the most Gaussians).

        ``cuda``: gsplat at full size with densification, :data:`DEMO_GPU_SPLAT_STEPS` steps a
        chunk (the plateau trend over :data:`DEMO_GPU_PLATEAU_PATIENCE` validations), from LiDAR
        points on a 0.2 m grid (about :data:`DEMO_GPU_INIT_POINTS` a chunk, growing to at most
        :data:`DEMO_GPU_MAX_GAUSSIANS`), at most
        :data:`DEMO_GPU_SPLAT_BUDGET_S` seconds a chunk (times the processes sharing the GPU:
        :func:`~cam2sim.core.machine.gpu_sharers`).
        CPU: a frame every 0.5 m, 40k LiDAR points, nearly opaque starting Gaussians,
        700-1,400 steps a chunk at half size, at most :data:`DEMO_CPU_SPLAT_BUDGET_S` seconds a
        chunk; from step 500 our densification grows each chunk (to 70-130k Gaussians; no
        growth past :data:`DEMO_CPU_MAX_GAUSSIANS`) (the thin lane markings and kerbs 10-30 m
        ahead, which DAVE-2 steers by, are what 40k Gaussians leave out: docs/benchmarks.md,
        "Where the CPU splat's runs leave the recorded line"). The 1,400 binds: 2,800 steps took
        l-street's splat runs from 1.6x Real's Min-Fréchet to 1.02x at twice the time, which a
        2-core demo cannot spend (docs/benchmarks.md, "The GPU suite's splats stopped short").
        """
        if cuda:
            train = TrainOptions(
                min_steps=DEMO_GPU_SPLAT_STEPS[0], max_steps=DEMO_GPU_SPLAT_STEPS[1],
                val_every=250, patience=DEMO_GPU_PLATEAU_PATIENCE,
                min_gain_db=0.5, min_gain_ssim=0.005,
                time_budget_s=DEMO_GPU_SPLAT_BUDGET_S * gpu_sharers(), budget_per_chunk=True,
                max_init_points=DEMO_GPU_INIT_POINTS,
                densify=DensifyOptions(max_gaussians=DEMO_GPU_MAX_GAUSSIANS),
            )  # fmt: skip
            return cls(prepare=PrepareOptions(triangulate=False, lidar_voxel_m=0.2), train=train)
        prepare = PrepareOptions(spacing_m=0.5, triangulate=False, lidar_voxel_m=0.25)
        train = TrainOptions(
            max_steps=1_400,
            min_steps=700,
            val_every=175,
            patience=2,
            min_gain_db=1.0,  # dB per 1,000 steps: a chunk gaining less has what it can get here
            min_gain_ssim=0.02,
            n_val_views=8,
            downscale=2,
            max_init_points=40_000,
            sky_points=2_000,
            init_opacity=0.5,
            densify=DensifyOptions(strategy="simple", max_gaussians=DEMO_CPU_MAX_GAUSSIANS),
            time_budget_s=DEMO_CPU_SPLAT_BUDGET_S,  # a slow machine trains fewer steps
            budget_per_chunk=True,
        )
        return cls(prepare=prepare, train=train, offsets_m=(-1.0, 1.0))

    @classmethod
    def for_run(
        cls,
        *,
        cuda: bool,
        lidar: bool,
        gsplat: bool | None = None,
        bundle_adjust: bool | None = None,
    ) -> SplatStageOptions:
        """``cam2sim run``'s splat: 10,000 MCMC steps a chunk on CUDA, the CPU demo preset else.

        ``cuda``: :data:`RUN_GPU_SPLAT_STEPS` steps a chunk with MCMC densification (a cap
        of one million Gaussians), pose refinement (:data:`RUN_GPU_POSE_RATE`) and
        :data:`RUN_GPU_SSIM_WEIGHT`, at most
        :data:`RUN_GPU_SPLAT_BUDGET_S` seconds a chunk, times the processes sharing the GPU
        (the default 30,000 steps would take half an hour on a recording of 5 chunks). On real
        frames MCMC beats the default densification at these lengths and its steps are cheaper
        (a fixed cap where the default grows to 3-5M): ``docs/splat-options.md``. CPU:
        :meth:`demo`'s.
        Either way the starting points are triangulated from the frames (pycolmap) when the
        recording has no LiDAR. MCMC needs gsplat (``gsplat``; None: whether it can run here):
        on CUDA without it the torch rasterizer trains with its own densification.
        ``bundle_adjust`` is :attr:`PrepareOptions.refine_poses
        <cam2sim.splat.prepare.PrepareOptions.refine_poses>` (None: a real recording's poses).
        """
        if cuda:
            if gsplat is None:
                from cam2sim.splat.raster import has_gsplat  # noqa: PLC0415 -- lazy: imports torch

                gsplat = has_gsplat()
            train = TrainOptions(
                max_steps=RUN_GPU_SPLAT_STEPS, val_every=1_000, ssim_weight=RUN_GPU_SSIM_WEIGHT,
                lr=LearningRates(poses=RUN_GPU_POSE_RATE),
                densify=DensifyOptions(strategy="mcmc" if gsplat else "auto"),
                time_budget_s=RUN_GPU_SPLAT_BUDGET_S * gpu_sharers(), budget_per_chunk=True,
            )  # fmt: skip
            opts = cls(prepare=PrepareOptions(), train=train)
        else:
            opts = cls.demo()
        assert opts.prepare is not None  # both presets set it
        prepare = replace(opts.prepare, triangulate=not lidar, refine_poses=bundle_adjust)
        return replace(opts, prepare=prepare)


@dataclass(frozen=True)
class SplatResult:
    """Paths and outcomes of the splat stage."""

    prep_dir: Path
    models_dir: Path
    trained: SceneTrainResult | None
    evaluation: SplatEval | None
    seconds: dict[str, float] = field(default_factory=dict)
    """Wall seconds of each step that ran (``prepare``, ``train``, ``evaluate``)."""


def run_splat(
    ws: Workspace,
    *,
    options: SplatStageOptions | None = None,
    force: bool = False,
    progress: ProgressCallback | None = None,
    ray: str | None = None,
) -> SplatResult:
    """Run preparation, training and evaluation of the workspace's splat models.

    ``ray`` (a Ray address, or ``local``) trains the chunks in parallel, one Ray task and GPU
    each (:mod:`cam2sim.splat.distributed`); the models folder is the same.

    Raises:
        StageError: No dataset, or a step failed (the message says which).
        BackendUnavailableError: pycolmap, torch or gsplat (on CUDA) is missing.
    """
    opts = options or SplatStageOptions()
    report = progress or no_progress
    record = ws.stage_record("extract")
    if record is None or record.state != "done":
        msg = f"{ws.root} has no dataset; run `cam2sim extract {ws.root}` (or import) first"
        raise StageError(msg)
    prep_dir = ws.splat_files.prep_dir
    models_dir = ws.splat_files.models_dir
    inputs = hash_inputs({"dataset": record.inputs_hash, "options": repr(opts)})
    if not force and ws.is_up_to_date(STAGE, inputs):
        logger.info("splat: up to date; skipping")
        return SplatResult(prep_dir, models_dir, None, None)
    trained = evaluation = None
    seconds: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(step: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        seconds[step] = now - clock
        clock = now

    with stage_run(ws, STAGE, inputs_hash=inputs, config=None):
        if opts.evaluate and "evaluate" in opts.steps and opts.lpips_weights is None:
            prefetch_lpips_sdist()  # the evaluation's LPIPS weights, while the splat trains
        if "prepare" in opts.steps:
            prepare_scene(ws, options=opts.prepare, progress=report)
            lap("prepare")
        if not (prep_dir / "scene.json").is_file():
            msg = f"{prep_dir} holds no prepared scene; run `cam2sim splat {ws.root}` fully"
            raise StageError(msg)
        scene = SceneRecord.load(prep_dir / "scene.json")
        if "train" in opts.steps:
            kept = _trained_before(models_dir, _training_key(inputs, prep_dir), force=force)
            train = (
                train_scene if ray is None else functools.partial(train_scene_on_ray, address=ray)
            )
            trained = _train_rest(train, prep_dir, models_dir, scene, opts.train, kept, report)
            lap("train")
        if opts.evaluate and "evaluate" in opts.steps:
            notes: list[str] = []
            with _truth_reference(ws, opts, scene, notes) as truth:
                evaluation = evaluate_splat(
                    prep_dir,
                    models_dir,
                    offsets=() if scene.scale_ambiguous else opts.offsets_m,
                    lpips_weights=opts.lpips_weights,
                    # the held-out renders the report shows beside the real frames
                    options=EvalOptions(renders_dir=ws.splat_files.renders_dir),
                    out_path=ws.splat_files.eval_json,
                    truth=truth,
                    progress=report,
                )
            rig = _rig_views(ws)
            if rig:  # the rig's other cameras: real pixels off the recorded path
                rows = _score_rig(models_dir, scene, rig)
                evaluation = evaluation.model_copy(update={"rig": rows})
            if notes or rig:
                evaluation = evaluation.model_copy(update={"notes": [*evaluation.notes, *notes]})
                evaluation.save(ws.splat_files.eval_json)
            lap("evaluate")
    return SplatResult(prep_dir, models_dir, trained, evaluation, seconds)


def _training_key(inputs: str, prep_dir: Path) -> str:
    """What a chunk's model depends on: the stage's inputs and the prepared scene and points."""
    files = {
        name: file_fingerprint(prep_dir / name)
        for name in ("scene.json", "points.npz")
        if (prep_dir / name).is_file()
    }
    return hash_inputs({"stage": inputs, "prep": files})


def _trained_before(models_dir: Path, key: str, *, force: bool) -> dict[int, TrainResult]:
    """Chunks that a failed or interrupted training of the same ``key`` finished, by id.

    Each chunk's result is kept beside its model as soon as it is written
    (:func:`~cam2sim.splat.train_options.chunk_result_path`), under ``results/inputs.txt``
    naming what they were trained from. Another key (or ``force``) starts a new training: the
    kept results are removed and the key written.
    """
    results = models_dir / RESULTS_DIR
    marker = results / "inputs.txt"
    if not force and marker.is_file() and marker.read_text(encoding="utf-8") == key:
        kept = {}
        for path in sorted(results.glob("chunk_*.json")):
            result = TrainResult.load(path)
            model = models_dir / result.model_path.name  # where it is now (a moved workspace)
            if model.is_file():
                kept[result.chunk_id] = dataclasses.replace(result, model_path=model)
        return kept
    shutil.rmtree(results, ignore_errors=True)
    results.mkdir(parents=True, exist_ok=True)
    write_text_atomic(marker, key)
    return {}


def _train_rest(
    train: Callable[..., SceneTrainResult],
    prep_dir: Path,
    models_dir: Path,
    scene: SceneRecord,
    options: TrainOptions | None,
    kept: dict[int, TrainResult],
    progress: ProgressCallback,
) -> SceneTrainResult:
    """Train the chunks not in ``kept`` with ``train`` (here or on Ray); all results, by chunk id.

    A splat stage that failed after some chunks finished (a chunk out of memory, a diverged
    one, Ctrl-C) keeps those on the next run: five benchmark worlds on one H100 trained their
    other chunks for up to 12 minutes after one ran out of memory, all of it trained again on
    a resume before.
    """
    missing = tuple(c.id for c in scene.chunks if c.id not in kept)
    if kept:
        logger.info(
            "splat: chunk(s) %s trained before from the same inputs are kept; training %s",
            sorted(kept), list(missing) or "none",
        )  # fmt: skip
    if not missing:
        return SceneTrainResult(
            chunks=tuple(kept[c] for c in sorted(kept)), seconds=0.0, peak_memory_bytes=None
        )
    new = train(
        prep_dir, options=options, chunk_ids=missing, models_dir=models_dir, progress=progress,
        scene=scene,
    )  # fmt: skip
    chunks = sorted((*kept.values(), *new.chunks), key=lambda r: r.chunk_id)
    return dataclasses.replace(new, chunks=tuple(chunks))


def _rig_views(ws: Workspace) -> list[RigView]:
    """The dataset's rig cameras as the splat evaluation scores them."""
    paths = dataset_paths(ws.dataset_dir)
    info = DatasetInfo.load(paths.dataset_json)
    front = Calibration.load(paths.calibration_json).camera
    if not info.rig or front is None:
        return []
    views = []
    for name in info.rig:
        record = RigCamera.load(paths.rig_camera_json(name))
        lateral, yaw = rig_offset(record)
        views.append(
            RigView(
                name=name,
                T_front_cam=record.T(),
                camera=dataclasses.replace(
                    record.intrinsics.camera(), distortion=(), distortion_model="plumb_bob"
                ),
                front_width=front.width,
                frame_file=functools.partial(paths.rig_frame_file, name, fmt=info.frame_format),
                lateral_m=lateral,
                yaw_deg=yaw,
            )
        )
    return views


def _score_rig(models_dir: Path, scene: SceneRecord, rig: list[RigView]) -> list[RigScore]:
    """PSNR and SSIM at the rig cameras' real frames (LPIPS left out: PSNR, SSIM suffice)."""
    held = [f for f in scene.frames if f.held_out]
    with SplatRenderer(models_dir, options=RenderOptions(pose_frame="model")) as renderer:
        return rig_scores(renderer, rig, held, lpips=None)


@contextlib.contextmanager
def _truth_reference(
    ws: Workspace, opts: SplatStageOptions, scene: SceneRecord, notes: list[str]
) -> Iterator[TruthReference | None]:
    """The workspace's truth camera for the evaluation, or None (and why, in ``notes``)."""
    if not opts.truth_envelope or not truth_world_path(ws.root).is_file():
        yield None
        return
    if scene.scale_ambiguous:
        notes.append("not scored against the ground truth: the scene's scale is unknown (SfM)")
        yield None
        return
    frame = ws.world_frame()
    try:
        camera = TruthRenderer.open(ws.root, frame.proj_string if frame else None)
    except Cam2SimError as err:  # no headless OpenGL here, say: the rest of eval.json stands
        logger.warning("splat: not scored against the ground truth: %s", err)
        notes.append(f"not scored against the ground truth: {err}")
        yield None
        return
    with camera:
        yield TruthReference(
            camera,
            ground_z=_recorded_ground(ws),
            options=opts.truth or TruthEnvelopeOptions(),
        )


def _recorded_ground(ws: Workspace) -> Callable[[npt.NDArray[np.float64]], float] | None:
    """Ground height under a world ``(x, y)`` from the scenario; None without a scenario."""
    path = ws.scenario_path
    if not path.is_file():
        return None
    scenario = Scenario.load(path)
    return lambda xy: ground_height_at(scenario, xy)
