"""The ``splat`` camera renderer: a world camera pose and a pinhole camera in, an RGB image out.

:class:`SplatRenderer` reads ``WS/splat/models/`` (``chunk_XX.json`` headers at once, the
``chunk_XX.pt`` tensors lazily, at most ``max_loaded`` on the device at a time) and renders with
:func:`cam2sim.splat.raster.rasterize` (gsplat on CUDA, torch elsewhere).

**Choosing chunks.** The pose's camera centre is projected onto the route: the polyline through
all training camera centres in order of their progress (distance driven, metres). Each chunk
``c`` covers ``[start_c, end_c]`` of progress; where chunk ``c`` and the next overlap, their
weights cross over smoothly across the overlap ``[start_next, end_c]``:
``w_c = S((end_c - p) / (end_c - start_next))`` and ``w_next = S((p - start_next) / (end_c -
start_next))`` with ``S(t) = 3t^2 - 2t^3`` on ``[0, 1]``, so the weights sum to 1 and change
smoothly (with a continuous slope) with progress ``p``. Both chunks are rendered and their
images blended with these weights: there is no jump at a chunk border and no warm-up frame.
Chunks that merely touch (no overlap) switch at the border. Before the first and after the last
chunk, the end chunk is used.

**Colour.** With ``appearance="interpolate"`` each chunk applies the affine colour transform
of its training views interpolated linearly in progress between the two training views that
bracket the pose (for a held-out frame between two training frames at equal spacing: their
mean). ``"none"`` renders the model's own colours.

**Coverage** (how far the pose is from what the model was trained on), in ``[0, 1]``::

    coverage = 1 - exp(-0.5 * min_i((d_i / d0)^2 + (a_i / a0)^2))

over all training views ``i`` of all chunks, with ``d_i`` the distance (m) between the camera
centres, ``a_i`` the angle (degrees) between the optical axes, ``d0 = coverage_distance_m``
(1 m) and ``a0 = coverage_angle_deg`` (15 degrees). 0 on a training view; 0.39 at one ``d0``
(or one ``a0``) away; 0.86 at two; 0.99 at three. A high value flags a render that extrapolates
beyond the recorded views and should not be trusted; it does not measure image quality.

**Recorded poses.** Where the preparation adjusted the recorded poses (a bundle adjustment of
GPS fixes, SfM aligned to the record), the models live at the adjusted poses while replays and
closed-loop drives pose the camera in the recording's frame. With ``pose_frame="recorded"``
(the default) a pose is first taken into the model by the smoothed correction of the training
views near it (``ViewRecord.from_recorded``, interpolated in progress): at a recorded pose the
camera sees what the adjusted one saw, and a step sideways stays a step sideways. The splat
evaluation, which renders at the scene's own (adjusted) poses, passes ``pose_frame="model"``.

**Vehicle poses.** A closed-loop vehicle moves in the plane; its camera's height, pitch and
roll come from the recorded pose nearest to it, which for GPS fixes jitter (an altitude by
decimetres) or are estimated (a pitch from the grade). A steering model trained on the
recorded frames reads the horizon: on the KITTI drive as GPS fixes, 10 cm lower changed
DAVE-2's answer by up to 1.3 units and 0.5 degrees of pitch by up to 3.3, where 10 cm sideways
or 0.5 degrees of heading changed it by under 0.1. With ``pose_frame="vehicle"`` (the closed
loop's cameras) a pose is taken into the model as a recorded one and then given the height and
tilt of the training views at its progress (interpolated;
:func:`~cam2sim.splat.geometry.on_route_ground`): its own are the position across the ground
and the heading.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Literal, Self

import numpy as np

from cam2sim.core.errors import WorkspaceError
from cam2sim.splat.geometry import on_route_ground, recorded_to_model
from cam2sim.splat.raster import rasterize, resolve_backend, resolve_device

if TYPE_CHECKING:
    from types import TracebackType

    import numpy.typing as npt
    import torch

    from cam2sim.core.camera import PinholeCamera
    from cam2sim.splat.model import ChunkHeader
    from cam2sim.splat.raster import RasterBackend

__all__ = ["RenderOptions", "RenderResult", "SplatRenderer", "chunk_weights", "smoothstep"]

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RenderOptions:
    """How :class:`SplatRenderer` renders.

    Attributes:
        device: ``"auto"`` (CUDA when available), ``"cpu"``, ``"cuda"``, ...
        backend: Rasterizer (``"auto"``: gsplat on CUDA when installed, else torch).
        appearance: ``"interpolate"`` (training views' colour transforms) or ``"none"``.
        max_loaded: Chunk models kept on the device (least recently used ones are dropped).
        coverage_distance_m: ``d0`` of the coverage formula.
        coverage_angle_deg: ``a0`` of the coverage formula.
        near_plane: Gaussians closer than this (metres) are not drawn.
        street_alpha: Also return the street share of each pixel (costs speed: colours are
            then evaluated for every Gaussian instead of in gsplat's fused SH kernel).
        pose_frame: ``"recorded"``: poses are in the recording's frame (module doc);
            ``"vehicle"``: a planar vehicle's camera in the recording's frame, which takes the
            training views' height and tilt where it is (module doc); ``"model"``: in the
            models' own (the prepared scene's poses).
    """

    device: str = "auto"
    backend: RasterBackend = "auto"
    appearance: Literal["none", "interpolate"] = "interpolate"
    max_loaded: int = 4
    coverage_distance_m: float = 1.0
    coverage_angle_deg: float = 15.0
    near_plane: float = 0.01
    street_alpha: bool = False
    pose_frame: Literal["recorded", "vehicle", "model"] = "recorded"


@dataclass(frozen=True)
class RenderResult:
    """One rendered frame.

    Attributes:
        rgb: ``(H, W, 3)`` uint8 image.
        street_alpha: ``(H, W)`` float32, share of each pixel drawn by street (not sky)
            Gaussians (low values below the horizon are holes); None unless
            ``RenderOptions.street_alpha``.
        coverage: Distance from the training views, ``[0, 1]`` (module doc); 0 = on one.
        distance_m: Camera-centre distance to the nearest training view (by the coverage cost).
        angle_deg: Optical-axis angle to that view.
        progress_m: The pose's progress along the route.
        chunk_weights: Chunk id -> blend weight of the chunks rendered (sum 1).
    """

    rgb: npt.NDArray[np.uint8]
    street_alpha: npt.NDArray[np.float32] | None
    coverage: float
    distance_m: float
    angle_deg: float
    progress_m: float
    chunk_weights: dict[int, float]


def _at_progress(
    progress_m: float, at: npt.NDArray[np.float64], table: npt.NDArray[np.float64]
) -> npt.NDArray[np.float64]:
    """Each column of ``table`` (one row per progress in ``at``) interpolated at ``progress_m``."""
    return np.array([np.interp(progress_m, at, column) for column in table.T])


def smoothstep(t: float) -> float:
    """Return ``3t^2 - 2t^3`` of ``t`` clamped to ``[0, 1]``."""
    t = min(max(t, 0.0), 1.0)
    return t * t * (3.0 - 2.0 * t)


def chunk_weights(extents: list[tuple[int, float, float]], progress_m: float) -> dict[int, float]:
    """Return the blend weight of each chunk at ``progress_m`` (see the module doc).

    Args:
        extents: ``(chunk_id, start_m, end_m)`` per chunk.
        progress_m: Progress along the route.

    Returns:
        Chunk id -> weight, only chunks with a positive weight; the weights sum to 1.
    """
    if not extents:
        return {}
    ordered = sorted(extents, key=lambda e: (e[1], e[2], e[0]))
    raw: dict[int, float] = {}
    for i, (cid, start, end) in enumerate(ordered):
        w = 1.0
        if i > 0:
            ramp = ordered[i - 1][2] - start
            w *= smoothstep((progress_m - start) / ramp) if ramp > 0 else float(progress_m >= start)
        if i < len(ordered) - 1:
            ramp = end - ordered[i + 1][1]
            w *= smoothstep((end - progress_m) / ramp) if ramp > 0 else float(progress_m <= end)
        if w > 0:
            raw[cid] = w
    if not raw:
        nearest = min(ordered, key=lambda e: max(e[1] - progress_m, progress_m - e[2], 0.0))
        return {nearest[0]: 1.0}
    total = sum(raw.values())
    return {cid: w / total for cid, w in raw.items()}


@dataclass(frozen=True)
class _Loaded:
    """A chunk model on the device, activated for rendering."""

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    coeffs: torch.Tensor  # [N, K, 3] SH, street then sky (sky: degree 0, higher bands 0)
    sh_degree: int
    sky_flag: torch.Tensor  # [N, 1]: 0 street, 1 sky
    appearance: npt.NDArray[np.float64]  # [M, 12] affine colour transforms, row-major 3x4
    view_progress: npt.NDArray[np.float64]  # [M]
    background: torch.Tensor  # [1, 4]: RGB, sky share 0
    antialiased: bool = False  # trained with Mip-Splatting's 2-D filter: rendered with it


class SplatRenderer:
    """Render trained chunk models from any camera pose (a ``CameraRenderer`` backend).

    Use as a context manager, or call :meth:`close` to free the device memory.
    """

    RENDERS_ROWS: ClassVar[bool] = True
    """:meth:`render` takes ``rows``: a band of the image for a fraction of the cost."""

    def __init__(self, models_dir: Path, *, options: RenderOptions | None = None) -> None:
        """Read the chunk headers of ``models_dir`` (``WS/splat/models``).

        Raises:
            WorkspaceError: No chunk model in ``models_dir``.
            BackendUnavailableError: The asked device or backend cannot run here.
        """
        from cam2sim.splat.model import load_chunk_header  # noqa: PLC0415 -- lazy: imports torch

        self.models_dir = Path(models_dir)
        self.options = options or RenderOptions()
        files = sorted(self.models_dir.glob("chunk_*.pt"))
        if not files:
            msg = f"no chunk models (chunk_XX.pt) in {self.models_dir}; run the splat stage first"
            raise WorkspaceError(msg)
        self.headers: dict[int, ChunkHeader] = {}
        self._paths: dict[int, Path] = {}
        for path in files:
            header = load_chunk_header(path)
            self.headers[header.chunk_id] = header
            self._paths[header.chunk_id] = path
        self.device = resolve_device(self.options.device)
        self.backend = resolve_backend(self.options.backend, self.device)
        views = {v.index: v for h in self.headers.values() for v in h.train_views}
        ordered = sorted(views.values(), key=lambda v: (v.progress_m, v.index))
        self._route = np.array([v.position for v in ordered], dtype=np.float64)
        self._route_progress = np.array([v.progress_m for v in ordered], dtype=np.float64)
        forwards = np.array([v.forward for v in ordered], dtype=np.float64)
        self._forwards = forwards / np.linalg.norm(forwards, axis=1, keepdims=True)
        self._extents = [(h.chunk_id, h.start_m, h.end_m) for h in self.headers.values()]
        mapped = [v for v in ordered if v.from_recorded is not None]
        self._from_recorded = (
            (
                np.array([v.progress_m for v in mapped], dtype=np.float64),
                np.array([v.from_recorded for v in mapped], dtype=np.float64),
            )
            if mapped and self.options.pose_frame != "model"
            else None
        )
        # The views' height and tilt along the route, for vehicle poses (module doc).
        self._view_z = self._route[:, 2].copy()
        downs = [v.down for v in ordered]
        self._view_down = (
            None if any(d is None for d in downs) else np.array(downs, dtype=np.float64)
        )
        self._loaded: OrderedDict[int, _Loaded] = OrderedDict()
        _log.info(
            "splat renderer: %d chunk(s), %d training views, %s on %s",
            len(self.headers),
            len(ordered),
            self.backend,
            self.device,
        )

    # -- context management ----------------------------------------------------------------
    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Drop every loaded chunk model (idempotent)."""
        self._loaded.clear()

    # -- geometry ----------------------------------------------------------------------------
    def progress_of(self, position: npt.NDArray[np.float64]) -> float:
        """Return the route progress (m) of the point of the route nearest to ``position``."""
        route, prog = self._route, self._route_progress
        if len(route) == 1:
            return float(prog[0])
        a, b = route[:-1], route[1:]
        seg = b - a
        length2 = np.maximum((seg * seg).sum(axis=1), 1e-12)
        t = np.clip(((position - a) * seg).sum(axis=1) / length2, 0.0, 1.0)
        dist = np.linalg.norm(a + t[:, None] * seg - position, axis=1)
        i = int(np.argmin(dist))
        return float(prog[i] + t[i] * (prog[i + 1] - prog[i]))

    def _on_route_ground(
        self, pose: npt.NDArray[np.float64], progress: float
    ) -> npt.NDArray[np.float64]:
        """``pose`` with the training views' height and tilt at ``progress`` (module doc)."""
        at = self._route_progress
        z = float(np.interp(progress, at, self._view_z))
        forward = _at_progress(progress, at, self._forwards)
        down = None if self._view_down is None else _at_progress(progress, at, self._view_down)
        return on_route_ground(pose, z, forward, down)

    def coverage_of(self, T_world_cam: npt.NDArray[np.float64]) -> tuple[float, float, float]:
        """Return ``(coverage, distance_m, angle_deg)`` of a pose (module doc)."""
        opts = self.options
        dist = np.linalg.norm(self._route - T_world_cam[:3, 3], axis=1)
        forward = T_world_cam[:3, 2] / np.linalg.norm(T_world_cam[:3, 2])
        angle = np.degrees(np.arccos(np.clip(self._forwards @ forward, -1.0, 1.0)))
        cost = (dist / opts.coverage_distance_m) ** 2 + (angle / opts.coverage_angle_deg) ** 2
        i = int(np.argmin(cost))
        return float(1.0 - math.exp(-0.5 * cost[i])), float(dist[i]), float(angle[i])

    # -- models ------------------------------------------------------------------------------
    def _load(self, chunk_id: int) -> _Loaded:
        import torch  # noqa: PLC0415

        from cam2sim.splat.model import load_chunk_model  # noqa: PLC0415 -- lazy: imports torch

        if chunk_id in self._loaded:
            self._loaded.move_to_end(chunk_id)
            return self._loaded[chunk_id]
        while len(self._loaded) >= max(1, self.options.max_loaded):
            self._loaded.popitem(last=False)
        model = load_chunk_model(self._paths[chunk_id], device=self.device)
        street, sky = model.gaussians.params, model.sky.params
        n_sky, k = len(sky["means"]), street["shN"].shape[1] + 1
        with torch.no_grad():
            sky_coeffs = torch.zeros((n_sky, k, 3), device=self.device)
            sky_coeffs[:, :1] = sky["sh0"]
            loaded = _Loaded(
                means=torch.cat((street["means"], sky["means"])).contiguous(),
                quats=torch.cat((street["quats"], sky["quats"])).contiguous(),
                scales=torch.exp(torch.cat((street["scales"], sky["scales"]))).contiguous(),
                opacities=torch.sigmoid(torch.cat((street["opacities"], sky["opacities"]))),
                coeffs=torch.cat(
                    (torch.cat((street["sh0"], street["shN"]), dim=1), sky_coeffs)
                ).contiguous(),
                sh_degree=model.gaussians.sh_degree,
                sky_flag=torch.cat(
                    (
                        torch.zeros((len(street["means"]), 1), device=self.device),
                        torch.ones((n_sky, 1), device=self.device),
                    )
                ),
                appearance=model.appearance.reshape(-1, 12).cpu().double().numpy(),
                view_progress=np.array([v.progress_m for v in model.header.train_views]),
                antialiased=model.header.antialiased,
                background=torch.tensor(
                    [[*model.header.background, 0.0]], dtype=torch.float32, device=self.device
                ),
            )
        self._loaded[chunk_id] = loaded
        _log.debug("loaded chunk %d (%d Gaussians)", chunk_id, len(loaded.means))
        return loaded

    def _affine(self, chunk: _Loaded, progress_m: float, mode: str) -> torch.Tensor | None:
        import torch  # noqa: PLC0415

        if mode == "none" or len(chunk.view_progress) == 0:
            return None
        table = chunk.appearance
        row = _at_progress(progress_m, chunk.view_progress, table)
        return torch.tensor(row, dtype=torch.float32, device=self.device).reshape(3, 4)

    def _render_chunk(
        self,
        chunk: _Loaded,
        camera: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
        size: tuple[int, int],
        progress_m: float,
        appearance: str,
        rows: tuple[int, int] | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Return ``[H, W, 3]`` colour and ``[H, W]`` street share (or None) of one chunk.

        Args:
            chunk: The loaded chunk.
            camera: ``[4, 4]`` world -> camera, ``[3, 3]`` K, ``[3]`` camera centre.
            size: ``(width, height)``.
            progress_m: Progress of the pose (for the colour transform).
            appearance: ``"none"`` or ``"interpolate"``.
            rows: Only these rows ``[first, stop)`` of the image (:func:`rasterize`).
        """
        import torch  # noqa: PLC0415

        from cam2sim.splat.raster_torch import rgb_from_sh  # noqa: PLC0415 -- lazy: imports torch

        viewmat, k, campos = camera
        with_street = self.options.street_alpha
        if with_street:
            rgb = rgb_from_sh(chunk.coeffs, chunk.means - campos, chunk.sh_degree)
            colours, degree, background = (
                torch.cat((rgb, chunk.sky_flag), dim=1),
                None,
                chunk.background,
            )
        else:
            colours, degree, background = chunk.coeffs, chunk.sh_degree, chunk.background[:, :3]
        out = rasterize(
            chunk.means,
            chunk.quats,
            chunk.scales,
            chunk.opacities,
            colours,
            viewmat[None],
            k[None],
            size[0],
            size[1],
            near_plane=self.options.near_plane,
            sh_degree=degree,
            backgrounds=background,
            backend=self.backend,
            rows=rows,
            antialiased=chunk.antialiased,
        )
        image = out.colors[0]
        colour = image[..., :3]
        affine = self._affine(chunk, progress_m, appearance)
        if affine is not None:
            colour = colour @ affine[:, :3].T + affine[:, 3]
        return colour, (out.alphas[0, ..., 0] - image[..., 3]) if with_street else None

    def render(
        self,
        T_world_cam: npt.NDArray[np.float64],
        camera: PinholeCamera,
        *,
        appearance: Literal["none", "interpolate"] | None = None,
        rows: tuple[int, int] | None = None,
    ) -> RenderResult:
        """Render the view of a pinhole camera.

        Args:
            T_world_cam: ``(4, 4)`` camera (OpenCV optical axes) -> world, metres, in the
                frame ``options.pose_frame`` names (module doc, "Recorded poses").
            camera: The camera of the wanted image (intrinsics and size, pixels), without lens
                distortion: the image is an undistorted pinhole image, as the models were
                trained on.
            appearance: Overrides ``options.appearance`` for this frame.
            rows: Render only rows ``[first, stop)`` of the image (what the image shows there,
                at a fraction of the cost on the CPU); the result is ``stop - first`` rows high.

        Returns:
            The image, its coverage and the chunk weights used.

        Raises:
            ValueError: A pose that is not ``(4, 4)``, or a camera with lens distortion.
        """
        import torch  # noqa: PLC0415

        pose = np.asarray(T_world_cam, dtype=np.float64)
        if pose.shape != (4, 4):
            msg = f"render needs a (4, 4) pose, got shape {pose.shape}"
            raise ValueError(msg)
        camera.require_undistorted("the splat renderer")
        k, width, height = camera.K(), camera.width, camera.height
        progress = self.progress_of(pose[:3, 3])
        if self._from_recorded is not None:
            at, table = self._from_recorded
            pose = recorded_to_model(pose, _at_progress(progress, at, table))
            progress = self.progress_of(pose[:3, 3])
        if self.options.pose_frame == "vehicle":
            pose = self._on_route_ground(pose, progress)
        weights = chunk_weights(self._extents, progress)
        coverage, distance, angle = self.coverage_of(pose)
        mode = appearance or self.options.appearance
        packed = np.zeros(28, dtype=np.float32)
        packed[:16] = np.linalg.inv(pose).ravel()
        packed[16:25] = k.ravel()
        packed[25:] = pose[:3, 3]
        cam = torch.from_numpy(packed).to(self.device)
        cam_t = (cam[:16].reshape(4, 4), cam[16:25].reshape(3, 3), cam[25:])
        street_alpha = None
        with torch.inference_mode():
            parts = [
                (
                    w,
                    *self._render_chunk(
                        self._load(cid), cam_t, (width, height), progress, mode, rows
                    ),
                )
                for cid, w in weights.items()
            ]
            colour = parts[0][0] * parts[0][1]
            for w, c, _ in parts[1:]:
                colour = colour + w * c
            rgb = (colour.clamp(0.0, 1.0) * 255.0 + 0.5).to(torch.uint8).cpu().numpy()
            shares = [(w, s) for w, _, s in parts if s is not None]
            if shares:
                street = shares[0][0] * shares[0][1]
                for w, s in shares[1:]:
                    street = street + w * s
                street_alpha = street.clamp(0.0, 1.0).cpu().numpy().astype(np.float32)
        return RenderResult(
            rgb=rgb,
            street_alpha=street_alpha,
            coverage=coverage,
            distance_m=distance,
            angle_deg=angle,
            progress_m=progress,
            chunk_weights=weights,
        )
