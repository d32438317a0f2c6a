"""Stage splat, evaluation: image quality on held-out frames and the lateral validity envelope.

Writes ``WS/splat/eval.json`` (:class:`SplatEval`). Everything is rendered through
:class:`cam2sim.splat.render.SplatRenderer`, so chunk choice and blending are those the
simulator sees.

**Held-out frames** (``held_out`` in ``scene.json``, every 8th by default; never trained on):
PSNR, SSIM and LPIPS of the render against the real frame over the pixels whose mask is 255
(:func:`cam2sim.metrics.image_quality.psnr`/``ssim``, :mod:`cam2sim.metrics.lpips`), once with
the appearance transform interpolated from the neighbouring training views and once without.
Reported per frame and as mean, 10th and 90th percentile.

**Lateral offsets** (the validity envelope, relative). No recorded image exists from a camera
shifted sideways, so without a ground-truth world quality there cannot be measured absolutely.
For each offset ``o`` (m, positive = to the camera's right, along its x axis) each held-out
frame is rendered from the shifted pose and compared with the render from the original pose,
on the lower part of the image (``lower_fraction``, default the bottom half: mostly road,
which a lateral shift moves little) and inside the frame's mask:

- ``lpips_vs_centre``: LPIPS between offset and original render;
- ``psnr_vs_centre_db``: PSNR between them;
- ``street_hole_fraction``: share of those pixels that street Gaussians cover less than half
  (holes through which sky Gaussians or the background show), a no-reference defect measure;
- ``coverage``: the renderer's coverage value (0 = on a training view, toward 1 = far away).

Limits: the first two mix real parallax (the view does change when the camera moves) with
render degradation, so they rise with ``|o|`` even for a perfect model and compare runs and
models rather than state an absolute error; the lower image half is an approximation of "road"
(no segmentation is used); holes are counted only where street Gaussians are missing, not where
they are wrong (floaters, stretched textures).

**Against the ground truth** (``truth``, when the workspace has a ground-truth world and the
stage passes its camera): PSNR, SSIM and LPIPS of the render against the truth camera rendered
without sensor noise, on the recorded path and at lateral offsets and yaw turns
(:mod:`cam2sim.splat.envelope`, :class:`TruthEnvelope`): the validity envelope measured
against what the camera would really have seen, which the relative offsets cannot give.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import pydantic

from cam2sim.core.background import BackgroundJobs
from cam2sim.core.errors import Cam2SimError, StageError
from cam2sim.core.images import read_mask, read_rgb, write_rgb
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.schema import Artifact
from cam2sim.metrics.lpips import load_lpips
from cam2sim.splat.envelope import perturbed_pose, truth_envelope
from cam2sim.splat.pose_refine import corrected_pose, interpolated_correction
from cam2sim.splat.render import RenderOptions, RenderResult, SplatRenderer
from cam2sim.splat.scene import FrameRecord, SceneRecord
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
    import numpy.typing as npt

    from cam2sim.metrics.lpips import Lpips, LpipsNet
    from cam2sim.splat.envelope import RenderCache, TruthReference
    from cam2sim.splat.raster import RasterBackend
    from cam2sim.splat.scene import FrameRecord

__all__ = [
    "DEFAULT_OFFSETS_M",
    "EvalOptions",
    "HeldOutFrame",
    "MetricSummary",
    "OffsetScore",
    "PairScores",
    "SplatEval",
    "TruthEnvelope",
    "TruthScore",
    "evaluate_splat",
    "even_picks",
    "frame_exclusion",
    "score_pair",
    "summarise",
]

_log = logging.getLogger(__name__)

_Column = Literal["psnr_db", "ssim", "lpips", "psnr_db_raw", "ssim_raw", "lpips_raw"]

DEFAULT_OFFSETS_M = (-2.0, -1.0, -0.5, 0.5, 1.0, 2.0)
"""Lateral offsets evaluated by default, metres (positive = camera right)."""


class HeldOutFrame(pydantic.BaseModel):
    """Scores of one held-out frame (``*_raw``: rendered without the appearance transform)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    index: int
    psnr_db: float | None
    ssim: float | None
    lpips: float | None
    psnr_db_raw: float | None = None
    ssim_raw: float | None = None
    lpips_raw: float | None = None
    coverage: float
    chunks: dict[int, float]


class OffsetScore(pydantic.BaseModel):
    """The validity envelope at one lateral offset (see the module doc)."""

    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)

    offset_m: float
    lpips_vs_centre: MetricSummary
    psnr_vs_centre_db: MetricSummary
    street_hole_fraction: MetricSummary
    coverage: MetricSummary


class SplatEval(Artifact):
    """``WS/splat/eval.json`` (``truth`` is absent in files written before it existed)."""

    models_dir: str
    n_held_out: int
    psnr_db: MetricSummary
    ssim: MetricSummary
    lpips: MetricSummary
    psnr_db_raw: MetricSummary | None = pydantic.Field(
        None, description="Without the appearance transform"
    )
    ssim_raw: MetricSummary | None = None
    lpips_raw: MetricSummary | None = None
    lpips_net: str | None
    lower_fraction: float
    frames: list[HeldOutFrame]
    offsets: list[OffsetScore]
    rig: list[RigScore] = pydantic.Field(
        default_factory=list,
        description="Against the real frames of the rig's other cameras (real pixels off the "
        "path; cam2sim.splat.envelope.rig_scores, added by the splat stage)",
    )
    truth: TruthEnvelope | None = pydantic.Field(
        None, description="Against the ground-truth world; None without one"
    )
    notes: list[str] = pydantic.Field(default_factory=list)


@dataclass(frozen=True)
class EvalOptions:
    """How :func:`evaluate_splat` evaluates.

    Attributes:
        lpips: Compute LPIPS (needs the LPIPS weights, see :func:`cam2sim.metrics.lpips`).
        lpips_net: LPIPS backbone.
        lpips_download: Whether missing LPIPS weights may be downloaded.
        compare_appearance: Also score renders without the appearance transform.
        max_offset_frames: Held-out frames (spread evenly) used for the offsets; None = all.
            12 by default, the frames the truth envelope picks
            (:class:`~cam2sim.splat.envelope.TruthEnvelopeOptions`), so it reuses their
            renders: six offsets of every held-out frame were three quarters of the
            evaluation's renders (on the 450 m paper street on 2 cores, 78 s of it), and the
            quality gate reads the truth envelope or the held-out frames, not these.
        lower_fraction: Bottom share of the image compared at the offsets.
        device: torch device (``"auto"``: CUDA when available).
        backend: Rasterizer.
        renders_dir: Also write each held-out frame's render there, as the frame's index in
            lossless WebP (``000123.webp``): to look at, or to score elsewhere (LPIPS on
            another machine, ``benchmarks/lpips_renders.py``). None = not written.
    """

    lpips: bool = True
    lpips_net: LpipsNet = "alex"
    lpips_download: bool = True
    compare_appearance: bool = True
    max_offset_frames: int | None = 12
    lower_fraction: float = 0.5
    device: str = "auto"
    backend: RasterBackend = "auto"
    renders_dir: Path | None = None


def frame_exclusion(prep_dir: Path, frame: FrameRecord) -> npt.NDArray[np.bool_] | None:
    """``(H, W)`` bool, True where the frame's mask leaves a pixel out; None without a mask."""
    path = prep_dir / "masks" / f"{frame.index:06d}.png"
    if not path.is_file():
        return None
    mask = read_mask(path, keep_nonzero=True)
    if mask.shape != (frame.height, frame.width):
        msg = f"{path} is not {frame.width}x{frame.height}; re-run splat preparation"
        raise StageError(msg)
    return mask


def _offset_scores(
    renderer: SplatRenderer,
    frames: list[tuple[FrameRecord, npt.NDArray[np.uint8], npt.NDArray[np.bool_] | None]],
    offsets: tuple[float, ...],
    lpips: Lpips | None,
    lower_fraction: float,
    cache: RenderCache,
) -> list[OffsetScore]:
    """Each frame rendered at each lateral offset and scored against its centre render.

    The scores are taken on the upper ``1 - lower_fraction`` of the image (and outside the
    frame's exclusion), where a sideways step changes little; they run on worker threads while
    this one renders (LPIPS keeps them to one).
    """

    def score(
        frame: FrameRecord,
        centre: npt.NDArray[np.uint8],
        r: RenderResult,
        exclude: npt.NDArray[np.bool_] | None,
    ) -> tuple[float | None, float | None, float | None]:
        lower = np.ones((frame.height, frame.width), dtype=bool)
        lower[round(frame.height * (1.0 - lower_fraction)) :] = False
        if exclude is not None:
            lower |= exclude
        scores = score_pair(centre, r.rgb, lower, lpips)
        kept = ~lower
        street = r.street_alpha
        hole = float((street[kept] < 0.5).mean()) if street is not None and kept.any() else None
        return scores.lpips, scores.psnr, hole

    coverage: list[float] = []
    with BackgroundJobs[tuple[float | None, float | None, float | None]](
        _scoring_workers(lpips), name="cam2sim-splat-offsets"
    ) as jobs:
        for offset in offsets:
            for frame, centre, exclude in frames:
                pose = perturbed_pose(frame.T(), lateral_m=offset)
                r = renderer.render(pose, frame.camera())
                cache[frame.index, float(offset), 0.0] = (r.rgb, r.coverage)
                coverage.append(r.coverage)
                jobs.submit(score, frame, centre, r, exclude)
        scored = jobs.results()
    out = []
    n = len(frames)
    for k, offset in enumerate(offsets):
        lp, ps, holes = zip(*scored[k * n : (k + 1) * n], strict=True) if n else ((), (), ())
        out.append(
            OffsetScore(
                offset_m=offset,
                lpips_vs_centre=summarise(list(lp)),
                psnr_vs_centre_db=summarise(list(ps)),
                street_hole_fraction=summarise(list(holes)),
                coverage=summarise(coverage[k * n : (k + 1) * n]),
            )
        )
    return out


def _scoring_workers(lpips: Lpips | None) -> int | None:
    """Worker threads for scoring pairs: one where LPIPS runs on the CPU, else every CPU.

    LPIPS on the CPU already spreads over the cores (torch's own threads); scoring beside it
    would fight them. On a GPU the pairs' reading, lossless WebP writing (about 0.1 s a
    KITTI frame), PSNR and SSIM are CPU work that threads share (OpenCV and numpy release
    the GIL; torch's CUDA calls may come from any thread).
    """
    return 1 if lpips is not None and lpips.device.type == "cpu" else None


def _load_lpips(
    opts: EvalOptions, weights: Path | None, device: str
) -> tuple[Lpips | None, list[str]]:
    """The LPIPS network, or None and a note saying why not.

    Weights that are not cached (and cannot be downloaded) leave LPIPS out with a note; weights
    given explicitly must load.
    """
    if not opts.lpips:
        return None, ["LPIPS not computed (lpips=False)"]
    try:
        net = load_lpips(
            opts.lpips_net, weights=weights, device=device, download=opts.lpips_download
        )
    except (Cam2SimError, OSError) as err:
        if weights is not None:
            raise
        return None, [f"LPIPS not computed: its weights are not on this machine ({err})"]
    return net, []


def _aligned(held: list[FrameRecord], renderer: SplatRenderer) -> list[FrameRecord]:
    """The held-out frames with the training views' pose corrections interpolated onto them."""
    views = [
        (v.index, v.correction)
        for h in renderer.headers.values()
        for v in h.train_views
        if v.correction is not None
    ]
    if not views:
        return held
    out = []
    for frame in held:
        pose = corrected_pose(frame.T(), interpolated_correction(frame.index, views))
        out.append(frame.model_copy(update={"T_world_cam": pose.tolist()}))
    return out


def evaluate_splat(
    prep_dir: Path,
    models_dir: Path,
    *,
    offsets: tuple[float, ...] = DEFAULT_OFFSETS_M,
    lpips_weights: Path | None = None,
    options: EvalOptions | None = None,
    out_path: Path | None = None,
    truth: TruthReference | None = None,
    progress: ProgressCallback = no_progress,
) -> SplatEval:
    """Score the chunk models on the held-out frames and at lateral offsets; write the result.

    Args:
        prep_dir: ``WS/splat/prep``.
        models_dir: ``WS/splat/models``.
        offsets: Lateral offsets, metres (positive = camera right); empty to skip.
        lpips_weights: LPIPS weights (see :func:`cam2sim.metrics.lpips.load_lpips`); None =
            the cache (downloaded into it when ``options.lpips_download``; without them LPIPS
            is left out with a note).
        options: Further options.
        out_path: Where to write; default ``prep_dir/../eval.json`` (``WS/splat/eval.json``).
        truth: The ground-truth camera to score against on and off the path (the ``truth``
            section, :func:`cam2sim.splat.envelope.truth_envelope`); None: no such section.
        progress: Called with ``("splat eval frames", done, total)``, and with
            ``("splat truth envelope", done, total)`` when ``truth`` is given.

    Returns:
        The evaluation (also written to ``out_path``).

    Raises:
        StageError: The scene has no held-out frame, or a mask does not fit its frame.
        WorkspaceError: Missing models or images.
    """
    opts = options or EvalOptions()
    prep_dir, models_dir = Path(prep_dir), Path(models_dir)
    out_path = prep_dir.parent / "eval.json" if out_path is None else Path(out_path)
    scene = SceneRecord.load(prep_dir / "scene.json")
    held = [f for f in scene.frames if f.held_out]
    if not held:
        msg = f"{prep_dir / 'scene.json'} marks no frame held_out; re-run splat preparation"
        raise StageError(msg)
    # The held-out frames are scored at the scene's own (adjusted) poses: the models' frame.
    render_options = RenderOptions(
        device=opts.device, backend=opts.backend, street_alpha=True, pose_frame="model"
    )
    cache: RenderCache = {}
    envelope = None
    with SplatRenderer(models_dir, options=render_options) as renderer:
        lpips, notes = _load_lpips(opts, lpips_weights, renderer.device)
        held = _aligned(held, renderer)
        n_offset = len(held) if opts.max_offset_frames is None else opts.max_offset_frames
        pick = set(even_picks(len(held), n_offset))
        kept_for_offsets = []
        masks = []
        total = len(held) + len(pick) * len(offsets)
        # This thread renders (the GPU); reading, scoring and writing run on worker threads.
        with BackgroundJobs[HeldOutFrame](
            _scoring_workers(lpips), name="cam2sim-splat-eval"
        ) as jobs:
            for n, frame in enumerate(held):
                exclude = frame_exclusion(prep_dir, frame)
                masks.append((frame, exclude))
                rgb = _render_held_out(renderer, frame, opts, cache, jobs, prep_dir, exclude, lpips)
                if n in pick:
                    kept_for_offsets.append((frame, rgb, exclude))
                progress("splat eval frames", jobs.collected, total)
            rows = jobs.results()
        progress("splat eval frames", len(held), total)
        offset_rows = _offset_scores(
            renderer, kept_for_offsets, tuple(offsets), lpips, opts.lower_fraction, cache
        )
        progress("splat eval frames", total, total)
    if truth is not None:
        envelope = _truth_scores(models_dir, truth, masks, lpips, opts, cache, progress)

    def column(name: _Column) -> MetricSummary:
        return summarise([getattr(r, name) for r in rows])

    result = SplatEval(
        models_dir=str(models_dir),
        n_held_out=len(held),
        psnr_db=column("psnr_db"),
        ssim=column("ssim"),
        lpips=column("lpips"),
        psnr_db_raw=column("psnr_db_raw") if opts.compare_appearance else None,
        ssim_raw=column("ssim_raw") if opts.compare_appearance else None,
        lpips_raw=column("lpips_raw") if opts.compare_appearance else None,
        lpips_net=opts.lpips_net if lpips is not None else None,
        lower_fraction=opts.lower_fraction,
        frames=rows,
        offsets=offset_rows,
        truth=envelope,
        notes=notes,
    )
    result.save(out_path)
    _log.info(
        "splat eval: %d held-out frames, PSNR %s dB, SSIM %s, LPIPS %s -> %s",
        len(held),
        _fmt(result.psnr_db.mean),
        _fmt(result.ssim.mean),
        _fmt(result.lpips.mean),
        out_path,
    )
    return result


def _truth_scores(
    models_dir: Path,
    truth: TruthReference,
    masks: list[tuple[FrameRecord, npt.NDArray[np.bool_] | None]],
    lpips: Lpips | None,
    opts: EvalOptions,
    cache: RenderCache,
    progress: ProgressCallback,
) -> TruthEnvelope:
    """The models against the ground-truth camera on and off the path (``eval.json``'s truth)."""
    # Colours only (no street share): a 320x200 demo frame on 2 CPU cores takes 0.22 s
    # instead of 0.31 s.
    plain = RenderOptions(device=opts.device, backend=opts.backend, pose_frame="model")
    with SplatRenderer(models_dir, options=plain) as renderer:
        return truth_envelope(
            renderer,
            truth,
            masks,
            lpips=lpips,
            lpips_net=opts.lpips_net,
            cache=cache,
            progress=progress,
        )


def _render_held_out(
    renderer: SplatRenderer,
    frame: FrameRecord,
    opts: EvalOptions,
    cache: RenderCache,
    jobs: BackgroundJobs[HeldOutFrame],
    prep_dir: Path,
    exclude: npt.NDArray[np.bool_] | None,
    lpips: Lpips | None,
) -> npt.NDArray[np.uint8]:
    """Render one held-out frame, submit its scoring to ``jobs``, return the render.

    With ``opts.compare_appearance`` it is also rendered without the colour transforms. The
    render is kept in ``cache`` (the truth envelope's on-path view) and, with
    ``opts.renders_dir``, written there.
    """
    camera = frame.camera()
    r = renderer.render(frame.T(), camera)
    cache[frame.index, 0.0, 0.0] = (r.rgb, r.coverage)
    raw = (
        renderer.render(frame.T(), camera, appearance="none").rgb
        if opts.compare_appearance
        else None
    )
    jobs.submit(_score_held_out, prep_dir, frame, r, raw, exclude, lpips, opts.renders_dir)
    return r.rgb


def _score_held_out(
    prep_dir: Path,
    frame: FrameRecord,
    r: RenderResult,
    raw_rgb: npt.NDArray[np.uint8] | None,
    exclude: npt.NDArray[np.bool_] | None,
    lpips: Lpips | None,
    renders_dir: Path | None,
) -> HeldOutFrame:
    """One held-out frame's row: its renders scored against the recorded frame.

    ``r`` is the render, ``raw_rgb`` the render without the colour transforms (or None); ``r``
    is written to ``renders_dir`` when given.
    """
    real = read_rgb(prep_dir / "images" / f"{frame.index:06d}.png")
    if renders_dir is not None:
        write_rgb(Path(renders_dir) / f"{frame.index:06d}.webp", r.rgb)
    s = score_pair(real, r.rgb, exclude, lpips)
    raw = (
        score_pair(real, raw_rgb, exclude, lpips)
        if raw_rgb is not None
        else PairScores(None, None, None)
    )
    return HeldOutFrame(
        index=frame.index,
        psnr_db=s.psnr,
        ssim=s.ssim,
        lpips=s.lpips,
        psnr_db_raw=raw.psnr,
        ssim_raw=raw.ssim,
        lpips_raw=raw.lpips,
        coverage=r.coverage,
        chunks=r.chunk_weights,
    )


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"
