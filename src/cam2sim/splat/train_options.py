"""The options and results of splat training (:mod:`cam2sim.splat.train`), as typed records.

Kept apart from the trainer so that what a run is asked to do, and what it reports, reads on one
page; :mod:`cam2sim.splat.train` re-exports every name.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Literal

from cam2sim.core.files import write_text_atomic
from cam2sim.splat.raster import GSPLAT_TILE
from cam2sim.splat.robust import RobustLoss

if TYPE_CHECKING:
    from cam2sim.splat.raster import RasterBackend

__all__ = [
    "DEFAULT_MAX_STEPS",
    "MCMC_GROUND_POINTS",
    "MCMC_MIN_STEPS",
    "MCMC_REFINE_STOP",
    "REFINE_STOP",
    "RESULTS_DIR",
    "DensifyOptions",
    "DensifyStrategy",
    "LearningRates",
    "SceneTrainResult",
    "Stop",
    "TrainOptions",
    "TrainResult",
    "chunk_result_path",
    "resolve_options",
]

DEFAULT_MAX_STEPS: Final = 30_000
"""Training steps a chunk at most, unless a preset or ``--max-steps`` says otherwise."""

Stop = Literal["plateau", "max_steps", "time"]
"""Why a chunk's training ended (``TrainResult.stopped``)."""

DensifyStrategy = Literal["auto", "mcmc", "gsplat", "simple"]
"""The densification rules (``DensifyOptions.strategy``)."""

MCMC_MIN_STEPS = 20_000
"""Step caps from which ``DensifyOptions.strategy="auto"`` densifies by MCMC on gsplat."""

REFINE_STOP = 15_000
"""The 3DGS rules' last refinement step (``DensifyOptions.refine_stop`` left None)."""

MCMC_REFINE_STOP = 25_000
"""MCMC's last relocation and growth step (``DensifyOptions.refine_stop`` left None)."""

MCMC_GROUND_POINTS = 100_000
"""Ground seeds an MCMC run starts with (``TrainOptions.ground_points`` left None)."""


@dataclass(frozen=True)
class LearningRates:
    """Adam learning rates (gsplat ``simple_trainer`` defaults).

    Attributes:
        means: Times the scene scale; decays exponentially to 1 % at ``max_steps`` (or at the
            step cap fitted to the time budget).
        scales: Log scales.
        quats: Quaternions.
        opacities: Opacity logits.
        sh0: Degree-0 SH (base colour); the sky's colours use it too.
        sh_rest: Higher SH bands (``shN``).
        appearance: The per-view affine colour transforms.
        poses: The per-view pose corrections (:mod:`cam2sim.splat.pose_refine`; scene units
            and radians); 0 = poses as recorded.
        tail: Where densification ends before the step cap (``densify.refine_stop`` below
            it), the scene's other rates (scales, quats, opacities, SH, the sky's) decay
            exponentially from there to ``tail`` times their value at the cap (the means'
            follow their own decay). 1 = constant, as gsplat's trainer has them. None = 0.1
            with MCMC densification, else 1 (:func:`resolve_options`).
        tail_views: The per-view colour transforms and pose corrections decay with the tail
            too (each gets a gradient only on the steps that draw its view, and at a constant
            rate keeps wandering about its fit).
    """

    means: float = 1.6e-4
    scales: float = 5e-3
    quats: float = 1e-3
    opacities: float = 5e-2
    sh0: float = 2.5e-3
    sh_rest: float = 2.5e-3 / 20
    appearance: float = 1e-3
    poses: float = 0.0
    tail: float | None = None
    tail_views: bool = True


@dataclass(frozen=True)
class DensifyOptions:
    """Densification (3DGS rules; ``strategy="auto"``: gsplat's with gsplat, else ours).

    Attributes:
        enabled: Densify at all.
        strategy: ``"gsplat"`` (DefaultStrategy), ``"simple"`` (ours), ``"mcmc"`` (gsplat's
            ``MCMCStrategy``, 3DGS as Markov chain Monte Carlo, Kheradmand et al. 2024:
            Gaussians that fade are moved onto live ones, the model grows by 5 % every
            ``refine_every`` steps to a fixed ``mcmc_cap``, positions get noise scaled by
            transparency; no opacity resets, no gradient statistics; gsplat backend only) or
            ``"auto"``: ``"mcmc"`` with gsplat for runs of at least :data:`MCMC_MIN_STEPS`
            steps without a time budget, ``"gsplat"`` for shorter ones, ``"simple"`` on the
            torch rasterizer (:func:`resolve_options`). MCMC needs its growth phase, hence
            the step floor.
        refine_start: First step that clones/splits/prunes.
        refine_stop: No refinement from this step on; None = :data:`MCMC_REFINE_STOP` with
            MCMC (the MCMC paper's 25,000 of 30,000), else :data:`REFINE_STOP`
            (:attr:`refine_stop_at`).
        refine_every: Steps between refinements.
        reset_every: Steps between opacity resets (to twice ``prune_opacity``); none within
            ``reset_every`` steps of ``max_steps``, as the model needs about that long to
            recover.
        grow_grad2d: Mean 2-D gradient (normalised screen units) above which a Gaussian grows.
        absgrad: Accumulate the absolute per-pixel gradients instead (AbsGS: finer detail on
            textured surfaces from fewer Gaussians; gsplat backend only; raise ``grow_grad2d``
            about 3-4x with it, gsplat's examples use 8e-4).
        pixel_weighted: Average the 2-D gradients over the views weighted by the Gaussian's
            screen footprint (Pixel-GS, Zhang et al. 2024) instead of counting every view
            alike. Driving forward, a Gaussian on the road near the camera is seen small from
            far away in most of its views, so its plain mean gradient stays low and it is never
            split; weighted, the views where it covers many pixels decide (more Gaussians
            where the road is near, at about twice the cost a step).
        near_damping: With ``pixel_weighted``: a Gaussian's gradient in a view is scaled by
            ``min(1, depth / (near_damping * scene scale)) ** 2`` for these statistics (3 m on
            a metric street), so large Gaussians right in front of the camera do not grow into
            floaters (0 = no damping).
        grow_scale3d: Largest scale (times scene scale) up to which growing clones, above splits.
        prune_opacity: Gaussians below this opacity are removed.
        prune_scale3d: Gaussians larger than this (times scene scale) are removed after the
            first reset.
        max_gaussians: No growth once the street model has this many Gaussians (the refinement
            that crosses it can overshoot by what it grows); pruning goes on, and growth
            resumes if pruning takes the model below it.
        mcmc_cap: With ``strategy="mcmc"``: the number of street Gaussians the model grows to
            (by 5 % every ``refine_every`` steps).
        mcmc_opacity_reg: With ``strategy="mcmc"``: weight of the mean opacity in the loss
            (Gaussians that are not needed fade, and are then moved where others are).
        mcmc_scale_reg: With ``strategy="mcmc"``: weight of the mean scale (scene units).
        mcmc_error_weight: With ``strategy="mcmc"``: how much the image error decides where
            faded Gaussians are moved and new ones added. MCMC draws the Gaussians to copy by
            their opacity alone, so growth follows what is already opaque, not what is still
            wrong; with a weight ``e`` each live Gaussian is drawn with probability
            proportional to ``opacity * (1 - e + e * g / mean(g))``, ``g`` its mean 2-D
            gradient since the last refinement (the statistic the 3DGS rules grow by, with
            ``pixel_weighted`` and ``near_damping`` as set). 0 = the paper's draw.
        mcmc_inherit_moments: With ``strategy="mcmc"``: the Gaussians that relocation and
            growth copy keep their Adam moments, and each copy starts with its original's.
            gsplat zeroes the originals' moments, and a Gaussian whose moments restart at zero
            takes steps several times its learning rate for hundreds of steps (Adam's
            bias correction counts the optimizer's steps, not the Gaussian's), so every
            refinement jolts the Gaussians it copies. False = gsplat's relocation.
    """

    enabled: bool = True
    strategy: DensifyStrategy = "auto"
    refine_start: int = 500
    refine_stop: int | None = None
    refine_every: int = 100
    reset_every: int = 3000
    grow_grad2d: float = 2e-4
    absgrad: bool = False
    pixel_weighted: bool = True
    near_damping: float = 0.3
    grow_scale3d: float = 0.01
    prune_opacity: float = 0.005
    prune_scale3d: float = 0.1
    max_gaussians: int = 6_000_000
    mcmc_cap: int = 1_000_000
    mcmc_opacity_reg: float = 0.01
    mcmc_scale_reg: float = 0.01
    mcmc_error_weight: float = 0.0
    mcmc_inherit_moments: bool = False

    @property
    def refine_stop_at(self) -> int:
        """The step refinement stops at: ``refine_stop``, or its strategy's default."""
        if self.refine_stop is not None:
            return self.refine_stop
        return MCMC_REFINE_STOP if self.strategy == "mcmc" else REFINE_STOP


@dataclass(frozen=True)
class TrainOptions:
    """How to train chunk models (see the module doc for what each part does).

    Each setting's docstring says what it does; the measurements behind the defaults are in
    ``docs/splat-options.md``.

    Attributes:
        max_steps: Step cap per chunk.
        min_steps: No plateau stop before this step.
        val_every: Steps between held-in validations.
        patience: Validation intervals in the plateau trend (``patience + 1`` validations).
        min_gain_db: Held-in PSNR trend, dB per 1,000 steps, below which PSNR has plateaued.
        min_gain_ssim: Held-in SSIM trend per 1,000 steps below which SSIM has plateaued.
        n_val_views: Training views used for validation (spread along the chunk).
        ssim_weight: Weight ``w`` of ``1 - SSIM`` in the photometric loss.
        sh_degree: Highest SH degree of the street model (0-3).
        sh_degree_interval: Steps per SH degree added (degree 0 first).
        appearance: Learn per-view colour transforms.
        sky_points: Number of sky Gaussians (0 = none).
        sky_radius_m: Sky sphere radius; None = automatic.
        sky_weight: Weight of the sky-share loss (used when ``sky/`` masks exist); None =
            0.05, or 0 with MCMC densification (measured as one recipe on real frames, where
            the classical sky masks mark sunlit trunks and bright hillsides as sky).
        init_opacity: Opacity of new street Gaussians; None = 0.1, or 0.5 with MCMC
            densification (the MCMC paper's).
        max_init_points: About this many of the chunk's points to start from, thinned with the
            distance from the cameras (``splat.model.screen_density_keep``); None = all.
        ground_points: About this many extra starting Gaussians on the ground under the
            cameras, where SfM leaves the near road and verges bare (:mod:`cam2sim.splat.ground`:
            the plane at the cameras' height, from the points on the road ahead; the pixels'
            colours); 0 = none; None = :data:`MCMC_GROUND_POINTS` with MCMC densification,
            else 0 (they help a long MCMC run, not a short run of the 3DGS rules).
        clear_path: Radius, as a share of the cameras' height over the road, of the tube
            around the training cameras' path inside which Gaussians are made transparent at
            every refinement step (:mod:`cam2sim.splat.clearance`: the car drove through that
            space, so nothing is there; a floater there blocks every pose near the path, which
            is what a closed-loop drive renders). 0 = off.
        background: RGB in ``[0, 1]`` behind everything.
        scene_scale: Scale (scene units) of the means' learning rate and of densification's
            size thresholds (``grow_scale3d``, ``prune_scale3d``). None = automatic:
            :data:`STREET_SCALE_M` for metric scenes, the spread of the chunk's cameras for
            scale-ambiguous (images-only SfM) ones. The spread is gsplat's rule, made for
            cameras around an object; along a street it grows with the chunk's length (about
            60 m for a 117 m chunk) while detail stays at the viewing distance, so Gaussians of
            half a metre were cloned instead of split.
        downscale: Integer image downscale for training (1 = full size).
        coarse_levels: Coarse-to-fine training: the first ``coarse_every`` steps see the views
            at ``1/2**coarse_levels`` of their size, each further ``coarse_every`` steps at
            twice the size, up to full size (nerfstudio's splatfacto does 2 levels every 3,000
            steps); validation is always at full size. 0 = full size throughout. Coarse steps
            are cheaper on the torch rasterizer and on large images; with gsplat on small ones
            they can cost more (too few tiles to fill the GPU).
        coarse_every: Steps per coarse level.
        lr: Learning rates.
        densify: Densification settings.
        robust: Robust weighting that leaves transient objects out of the loss
            (:mod:`cam2sim.splat.robust`).
        device: ``"auto"`` (CUDA when available), ``"cpu"``, ``"cuda"``, ``"cuda:1"``, ...
        backend: Rasterizer, see :mod:`cam2sim.splat.raster`.
        tile_size: gsplat's tile side in pixels while training (the images do not depend on
            it, only the work).
        antialiased: Train (and so render) with Mip-Splatting's 2-D filter
            (:func:`cam2sim.splat.raster.rasterize`); the chunk header records it.
        write_ply: Also write ``chunk_XX.ply`` (3DGS layout) beside each model.
        seed: Seeds view order, subsets and splits.
        profile: Time each step's phases (host and CUDA-event device time) into
            ``TrainResult.phase_ms``; also on with ``CAM2SIM_SPLAT_PROFILE=1``.
        concurrent_chunks: Chunks trained at a time by :func:`train_scene`, each in its own
            worker process on the one device; 1 = all in one interleaved loop in this process;
            None = 2 or 3 on CUDA (processes overlap on one GPU; how many by the chunks and the
            GPU's memory: :func:`cam2sim.splat.parallel.cuda_slots`; on a GPU other processes
            share 2 or 1: :func:`~cam2sim.splat.parallel.shared_gpu_slots`), 1 elsewhere.
        time_budget_s: Seconds of training for all the chunks of one call (their steps and
            validations; not loading them, nor gsplat's one-time build), shared out by
            :func:`time_share`; each chunk fits its step cap to its share (module doc).
            None = no budget: the plateau or ``max_steps`` ends training.
        budget_per_chunk: ``time_budget_s`` is each chunk's seconds, not all chunks' together:
            a longer route (more chunks) trains longer, each chunk as long as a short route's
            (the demo on CUDA, whose 183 m street has 2 chunks and the 450 m one 4).
    """

    max_steps: int = DEFAULT_MAX_STEPS
    min_steps: int = 7_000
    val_every: int = 1_000
    patience: int = 3
    min_gain_db: float = 0.05
    min_gain_ssim: float = 0.002
    n_val_views: int = 16
    ssim_weight: float = 0.2
    sh_degree: int = 3
    sh_degree_interval: int = 1_000
    appearance: bool = True
    sky_points: int = 10_000
    sky_radius_m: float | None = None
    sky_weight: float | None = None
    init_opacity: float | None = None
    max_init_points: int | None = None
    ground_points: int | None = None
    clear_path: float = 0.0
    background: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scene_scale: float | None = None
    downscale: int = 1
    coarse_levels: int = 0
    coarse_every: int = 3_000
    lr: LearningRates = field(default_factory=LearningRates)
    densify: DensifyOptions = field(default_factory=DensifyOptions)
    robust: RobustLoss = field(default_factory=RobustLoss)
    device: str = "auto"
    backend: RasterBackend = "auto"
    tile_size: int = GSPLAT_TILE
    antialiased: bool = True
    write_ply: bool = False
    seed: int = 0
    profile: bool = False
    concurrent_chunks: int | None = None
    time_budget_s: float | None = None
    budget_per_chunk: bool = False

    def __post_init__(self) -> None:
        problems = []
        if self.max_steps < 1:
            problems.append(f"max_steps={self.max_steps} (need >= 1)")
        if not 0 <= self.sh_degree <= 3:
            problems.append(f"sh_degree={self.sh_degree} (need 0-3)")
        if not 0.0 <= self.ssim_weight <= 1.0:
            problems.append(f"ssim_weight={self.ssim_weight} (need 0-1)")
        if self.downscale < 1:
            problems.append(f"downscale={self.downscale} (need >= 1)")
        if self.scene_scale is not None and self.scene_scale <= 0:
            problems.append(f"scene_scale={self.scene_scale} (need > 0 or None)")
        if self.coarse_levels < 0 or self.coarse_every < 1:
            problems.append(
                f"coarse_levels={self.coarse_levels}, coarse_every={self.coarse_every} "
                "(need >= 0 and >= 1)"
            )
        dens = self.densify
        ranges = (
            (dens.near_damping >= 0, f"densify.near_damping={dens.near_damping} (need >= 0)"),
            (self.clear_path >= 0, f"clear_path={self.clear_path} (need >= 0)"),
            (
                0.0 <= dens.mcmc_error_weight <= 1.0,
                f"densify.mcmc_error_weight={dens.mcmc_error_weight} (need 0-1)",
            ),
            (
                self.lr.tail is None or 0.0 < self.lr.tail <= 1.0,
                f"lr.tail={self.lr.tail} (need 0 < tail <= 1 or None)",
            ),
        )
        problems += [message for ok, message in ranges if not ok]
        if self.concurrent_chunks is not None and self.concurrent_chunks < 1:
            problems.append(f"concurrent_chunks={self.concurrent_chunks} (need >= 1 or None)")
        if self.time_budget_s is not None and not self.time_budget_s > 0:
            problems.append(f"time_budget_s={self.time_budget_s} (need > 0 or None)")
        if self.val_every < 1 or self.patience < 1 or self.n_val_views < 1:
            problems.append("val_every, patience and n_val_views must be >= 1")
        if problems:
            msg = "invalid TrainOptions: " + "; ".join(problems)
            raise ValueError(msg)


def resolve_options(options: TrainOptions, backend: str) -> TrainOptions:
    """``options`` with what ``"auto"`` and None leave open decided for the ``backend``.

    ``densify.strategy="auto"`` becomes ``"mcmc"`` on gsplat for a run of at least
    :data:`MCMC_MIN_STEPS` steps and no time budget (a budget may end it long before),
    ``"gsplat"`` for a shorter gsplat run, ``"simple"`` on the torch rasterizer. With MCMC,
    ``init_opacity`` and ``sky_weight`` default to 0.5 and 0 (else 0.1 and 0.05), and the run
    has no plateau stop (``min_steps`` becomes ``max_steps``: its held-in score rises late and
    still rises at the end). MCMC also relocates and grows until :data:`MCMC_REFINE_STOP`,
    then lets the scene's learning rates decay to a tenth (``lr.tail``, the per-view colour
    transforms with them: ``lr.tail_views``), and starts with :data:`MCMC_GROUND_POINTS`
    ground seeds. Why each default is what it is: ``docs/splat-options.md``.
    """
    dens = options.densify
    strategy = dens.strategy
    if strategy == "auto":
        if backend != "gsplat":
            strategy = "simple"
        elif options.max_steps >= MCMC_MIN_STEPS and options.time_budget_s is None:
            strategy = "mcmc"
        else:
            strategy = "gsplat"
    mcmc = dens.enabled and strategy == "mcmc"
    min_steps = options.min_steps
    if mcmc:
        min_steps = max(min_steps, options.max_steps)
    dens = replace(dens, strategy=strategy)
    tail = options.lr.tail if options.lr.tail is not None else (0.1 if mcmc else 1.0)
    ground = options.ground_points
    return replace(
        options,
        densify=replace(dens, refine_stop=dens.refine_stop_at),
        lr=replace(options.lr, tail=tail),
        init_opacity=_or(options.init_opacity, 0.5 if mcmc else 0.1),
        sky_weight=_or(options.sky_weight, 0.0 if mcmc else 0.05),
        ground_points=ground if ground is not None else (MCMC_GROUND_POINTS if mcmc else 0),
        min_steps=min_steps,
    )


def _or(value: float | None, default: float) -> float:
    return default if value is None else value


@dataclass(frozen=True)
class TrainResult:
    """Outcome of training one chunk.

    Attributes:
        chunk_id: The chunk.
        model_path: The written ``chunk_XX.pt``.
        steps: Steps run.
        stopped: ``"plateau"``, ``"max_steps"`` or ``"time"`` (the time budget ended it).
        n_gaussians: Street Gaussians at the end.
        n_initial_gaussians: Street Gaussians at the start (one per visible point).
        n_sky: Sky Gaussians.
        n_train_views: Views trained on.
        best_val_psnr_db: Best held-in validation PSNR, dB.
        val_history: ``(step, psnr_db, ssim)`` of every validation.
        train_seconds: Wall time spent in this chunk's steps and validations.
        backend: Rasterizer that ran.
        device: torch device.
        phase_ms: Per-step host and device milliseconds by phase when phase timing was on
            (``TrainOptions.profile``, see :mod:`cam2sim.splat.profiling`), else empty.
        robust_outlier_share: Mean share of used pixels the robust weighting left out, over
            the steps it ran (None when it was off).
        pose_correction: The learned pose corrections' mean and largest translation (scene
            units) and rotation (degrees), when pose refinement was on (``lr.poses``).
        densify_strategy: The densification that ran (``"mcmc"``, ``"gsplat"``, ``"simple"``;
            ``"off"``), after :func:`resolve_options`.
        non_finite_steps: Steps on which a gradient had NaN or inf values (skipped on CUDA;
            those values zeroed before the update on the CPU, :mod:`cam2sim.splat.optim`).
    """

    chunk_id: int
    model_path: Path
    steps: int
    stopped: Stop
    n_gaussians: int
    n_initial_gaussians: int
    n_sky: int
    n_train_views: int
    best_val_psnr_db: float | None
    val_history: tuple[tuple[int, float, float], ...]
    train_seconds: float
    backend: str
    device: str
    phase_ms: dict[str, float] = field(default_factory=dict)
    robust_outlier_share: float | None = None
    pose_correction: tuple[float, float, float, float] | None = None
    densify_strategy: str = ""
    non_finite_steps: int = 0

    def save(self, path: Path) -> None:
        """Write this result as JSON, atomically (beside its model: :func:`chunk_result_path`)."""
        data = dataclasses.asdict(self) | {"model_path": str(self.model_path)}
        write_text_atomic(Path(path), json.dumps(data, indent=1) + "\n")

    @classmethod
    def load(cls, path: Path) -> TrainResult:
        """Read a result :meth:`save` wrote."""
        data: dict[str, Any] = json.loads(Path(path).read_text(encoding="utf-8"))
        data["model_path"] = Path(data["model_path"])
        data["val_history"] = tuple(tuple(v) for v in data["val_history"])
        if data.get("pose_correction") is not None:
            data["pose_correction"] = tuple(data["pose_correction"])
        return cls(**data)


RESULTS_DIR: Final = "results"
"""Folder of the models folder that keeps each trained chunk's :class:`TrainResult`."""


def chunk_result_path(models_dir: Path, chunk_id: int) -> Path:
    """Where chunk ``chunk_id``'s :class:`TrainResult` is kept (``models_dir/results/``).

    Written as soon as the chunk's model is, so a stage that fails or is interrupted after some
    chunks finished resumes from them (:func:`cam2sim.stages.splat.run_splat`).
    """
    return Path(models_dir) / RESULTS_DIR / f"chunk_{chunk_id:02d}.json"


@dataclass(frozen=True)
class SceneTrainResult:
    """Outcome of :func:`train_scene`.

    Attributes:
        chunks: One result per chunk, by chunk id.
        seconds: Wall time of the whole run (loading included).
        peak_memory_bytes: Peak CUDA memory allocated, or None on CPU (with worker processes:
            the largest of one worker's).
    """

    chunks: tuple[TrainResult, ...]
    seconds: float
    peak_memory_bytes: int | None
