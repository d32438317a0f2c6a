"""The ``raster`` camera renderer: simulator-style RGB and semantic labels in one pass.

:class:`RasterScene` turns a :class:`~cam2sim.map.query.RoadMap`, parked vehicles and optional
building footprints into one static triangle mesh (:mod:`cam2sim.render.meshes`).
:class:`RasterRenderer` draws it with OpenGL 3.3 through ``moderngl`` on a headless EGL context
(Mesa llvmpipe on CPU, the GPU driver elsewhere); it takes the same arguments as
:meth:`cam2sim.splat.render.SplatRenderer.render` (a pose and a
:class:`~cam2sim.core.camera.PinholeCamera`) and returns a :class:`RasterResult` with
``rgb`` (and ``labels``), so the two backends are interchangeable.

**One pass.** The framebuffer has one RGBA8 colour attachment: RGB is the shaded colour and A
the :class:`~cam2sim.render.meshes.Label` id (written unblended, read back exactly). A
full-screen sky pass (gradient by the elevation of each pixel's ray, labelled sky; rays below
the horizon get the ground colour, labelled background) runs last, at the far plane with the
depth test ``<=``, so it fills only the pixels the scene left empty; one ``glReadPixels``
returns both images.

**Projection.** Poses are ``T_world_cam`` with OpenCV optical axes (x right, y down,
z forward). Pixel ``(u, v)`` (centre of the top-left pixel at ``(0, 0)``) is drawn at window
position ``(u + 0.5, v + 0.5)``: GL's first row is the image's top row, so the read-back needs
no flip. The clip matrix from ``K = [[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` is::

    [[2fx/W, 2s/W,  2(cx+0.5)/W - 1,  0          ],
     [0,     2fy/H, 2(cy+0.5)/H - 1,  0          ],
     [0,     0,     (f+n)/(f-n),      -2fn/(f-n) ],
     [0,     0,     1,                0          ]]

with near ``n`` and far ``f`` planes (metres along the optical axis). Vertices are stored
relative to the scene's centre (float32 keeps millimetres over kilometres).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final, Self

import numpy as np

from cam2sim.core.errors import BackendUnavailableError
from cam2sim.core.grid import grid_cells
from cam2sim.core.labels import Palette
from cam2sim.render.meshes import (
    BuildingFootprint,
    Label,
    Mesh,
    building_mesh,
    car_mesh,
    ground_mesh,
    lane_mesh,
    marking_mesh,
)

if TYPE_CHECKING:
    from collections.abc import Sequence
    from types import TracebackType

    import numpy.typing as npt

    from cam2sim.core.camera import PinholeCamera
    from cam2sim.map.query import RoadMap
    from cam2sim.scenario.model import ScenarioVehicle

__all__ = [
    "BuildingFootprint",
    "Label",
    "RasterOptions",
    "RasterRenderer",
    "RasterResult",
    "RasterScene",
    "projection_matrix",
    "raster_palette",
]

_log = logging.getLogger(__name__)

_VERTEX: Final = np.dtype([("pos", np.float32, 3), ("rgba", np.uint8, 4)])

_SCENE_VS: Final = """
#version 330
uniform mat4 mvp;
in vec3 in_pos;
in vec4 in_rgba;
out vec3 v_rgb;
flat out float v_label;
void main() {
    gl_Position = mvp * vec4(in_pos, 1.0);
    v_rgb = in_rgba.rgb;
    v_label = in_rgba.a;
}
"""
_SCENE_FS: Final = """
#version 330
in vec3 v_rgb;
flat in float v_label;
out vec4 f_out;
void main() { f_out = vec4(v_rgb, v_label); }
"""
_SKY_VS: Final = """
#version 330
uniform mat3 ray;  // world direction of pixel (u, v): ray * (u, v, 1)
uniform vec2 size;
noperspective out vec3 v_dir;
void main() {
    vec2 p = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
    v_dir = ray * vec3((p * 0.5 + 0.5) * size - 0.5, 1.0);
    gl_Position = vec4(p, 1.0, 1.0);  // at the far plane: drawn where nothing else is
}
"""
_SKY_FS: Final = f"""
#version 330
noperspective in vec3 v_dir;
out vec4 f_out;
void main() {{
    float e = v_dir.z * inversesqrt(dot(v_dir, v_dir));
    vec3 c = mix(vec3(0.78, 0.85, 0.92), vec3(0.30, 0.50, 0.80), sqrt(max(e, 0.0)));
    f_out = e < 0.0 ? vec4(0.40, 0.45, 0.36, {int(Label.BACKGROUND)}.0 / 255.0)
                    : vec4(c, {int(Label.SKY)}.0 / 255.0);
}}
"""


def raster_palette() -> Palette:
    """Return the Cityscapes colours of the labels (label ``i`` = class ``i - 1``, 0 background).

    Road and car come first, as in :meth:`~cam2sim.core.labels.Palette.cityscapes`.
    """
    return Palette.from_mapping(
        {
            "road": (128, 64, 128),
            "car": (0, 0, 142),
            "sidewalk": (244, 35, 232),
            "building": (70, 70, 70),
            "sky": (70, 130, 180),
        }
    )


@dataclass(frozen=True)
class RasterOptions:
    """How :class:`RasterRenderer` renders.

    Attributes:
        near_m: Near clipping plane, metres along the optical axis.
        far_m: Far clipping plane.
        draw_distance_m: Scene tiles farther than this from the camera are not drawn (the
            ground plane always is); like a simulator's culling distance.
        tile_m: Edge of the square tiles the scene is cut into for culling.
        kerb_height_m: Height of sidewalks above the road.
        ground_margin_m: How far the ground plane reaches beyond the map.
        lane_markings: Draw the dashed markings between driving lanes (False: an unmarked
            roadway, as many residential streets are).
    """

    near_m: float = 0.1
    far_m: float = 1000.0
    draw_distance_m: float = 250.0
    tile_m: float = 20.0
    kerb_height_m: float = 0.15
    ground_margin_m: float = 300.0
    lane_markings: bool = True


@dataclass(frozen=True)
class RasterResult:
    """One rendered frame.

    Attributes:
        rgb: ``(H, W, 3)`` uint8 image.
        labels: ``(H, W)`` uint8 :class:`~cam2sim.render.meshes.Label` ids.
    """

    rgb: npt.NDArray[np.uint8]
    labels: npt.NDArray[np.uint8]

    def semantic_rgb(self) -> npt.NDArray[np.uint8]:
        """Return the labels as a colour image in :func:`raster_palette` colours."""
        colours: npt.NDArray[np.uint8] = raster_palette().display_colors()[self.labels]
        return colours


class RasterScene:
    """The static scene: road surfaces, markings, kerbs, sidewalks, parked cars, buildings."""

    def __init__(
        self,
        road_map: RoadMap,
        vehicles: Sequence[ScenarioVehicle] = (),
        buildings: Sequence[BuildingFootprint] = (),
        *,
        options: RasterOptions | None = None,
    ) -> None:
        """Build the meshes (once; the renderer uploads them once).

        Args:
            road_map: The lanes.
            vehicles: Parked vehicles (bottom-centre position, heading, size).
            buildings: Building footprints in world xy with heights (OSM buildings).
            options: Kerb height and ground extent (``RasterOptions()`` by default).
        """
        opts = options or RasterOptions()
        parts = [
            lane_mesh(road_map, kerb_height_m=opts.kerb_height_m),
            marking_mesh(road_map) if opts.lane_markings else Mesh.empty(),
            car_mesh(vehicles),
            building_mesh(buildings),
        ]
        body = Mesh.concat(parts)
        if len(body):
            lo, hi = body.positions[:, :2].min(axis=0), body.positions[:, :2].max(axis=0)
        else:
            lo = hi = np.zeros(2)
        self.origin: npt.NDArray[np.float64] = np.array([*(0.5 * (lo + hi)), 0.0])
        body, tiles = _tiled(body, opts.tile_m)
        ground = ground_mesh((lo[0], lo[1], hi[0], hi[1]), margin_m=opts.ground_margin_m)
        self.mesh: Mesh = Mesh.concat([body, ground])  # ground last: hidden parts fail early-z
        # Culling tiles: first vertex, vertex count, centre (world) and bounding radius.
        self.tile_first: npt.NDArray[np.int64] = tiles[0]
        self.tile_count: npt.NDArray[np.int64] = tiles[1]
        self.tile_centre: npt.NDArray[np.float64] = tiles[2]
        self.tile_radius: npt.NDArray[np.float64] = tiles[3]
        self.ground_first = len(body)
        self.ground_count = len(ground)
        vertices = np.empty(len(self.mesh), dtype=_VERTEX)
        vertices["pos"] = self.mesh.positions - self.origin
        vertices["rgba"][:, :3] = self.mesh.colours
        vertices["rgba"][:, 3] = self.mesh.labels
        self.vertices: npt.NDArray[np.void] = vertices
        _log.info(
            "raster scene: %d triangles (%d lanes, %d vehicles, %d buildings)",
            len(self.mesh) // 3,
            len(road_map.lanes),
            len(vehicles),
            len(buildings),
        )


def _tiled(
    mesh: Mesh, tile_m: float
) -> tuple[Mesh, tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.float64],
                  npt.NDArray[np.float64]]]:  # fmt: skip
    """The mesh's triangles sorted by square tile; each tile's vertex range and bounds."""
    n_tri = len(mesh) // 3
    if n_tri == 0:
        z = np.zeros(0, dtype=np.int64)
        return mesh, (z, z, np.zeros((0, 3)), np.zeros(0))
    tri = mesh.positions.reshape(n_tri, 3, 3)
    centroid = tri.mean(axis=1)
    key = np.floor(centroid[:, :2] / tile_m).astype(np.int64)
    tile_of, counts = grid_cells(key)
    order = np.argsort(tile_of, kind="stable")
    vert_order = (order[:, None] * 3 + np.arange(3)[None, :]).ravel()
    sorted_mesh = Mesh(
        mesh.positions[vert_order], mesh.colours[vert_order], mesh.labels[vert_order]
    )
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    tri_sorted = tri[order]
    lo = np.minimum.reduceat(tri_sorted.min(axis=1), starts, axis=0)
    hi = np.maximum.reduceat(tri_sorted.max(axis=1), starts, axis=0)
    centre = 0.5 * (lo + hi)
    radius = 0.5 * np.linalg.norm(hi - lo, axis=1)
    return sorted_mesh, (starts * 3, counts.astype(np.int64) * 3, centre, radius)


def projection_matrix(
    K: npt.NDArray[np.float64], width: int, height: int, near: float, far: float
) -> npt.NDArray[np.float64]:
    """Return the ``(4, 4)`` clip matrix of a pinhole camera (module doc), camera frame in."""
    fx, s, cx = K[0]
    fy, cy = K[1, 1], K[1, 2]
    return np.array(
        [
            [2 * fx / width, 2 * s / width, 2 * (cx + 0.5) / width - 1, 0.0],
            [0.0, 2 * fy / height, 2 * (cy + 0.5) / height - 1, 0.0],
            [0.0, 0.0, (far + near) / (far - near), -2 * far * near / (far - near)],
            [0.0, 0.0, 1.0, 0.0],
        ]
    )


def _gl_bytes(matrix: npt.NDArray[np.float64]) -> bytes:
    """A row-major numpy matrix as GL's column-major float32 bytes."""
    return np.ascontiguousarray(matrix.T, dtype=np.float32).tobytes()


def _create_context() -> Any:  # a moderngl.Context (moderngl is imported lazily)
    try:
        import moderngl  # noqa: PLC0415
    except ImportError as exc:
        msg = "the raster renderer needs moderngl: pip install moderngl"
        raise BackendUnavailableError(msg) from exc
    try:
        # moderngl's stub types **settings as dict values; the keyword is a string.
        return moderngl.create_context(standalone=True, backend="egl", require=330)  # type: ignore[arg-type]
    except Exception as exc:
        msg = (
            f"no headless OpenGL 3.3 context through EGL ({exc}); install the EGL/Mesa drivers "
            "(e.g. apt-get install libegl1 libgl1-mesa-dri) or a GPU driver with EGL"
        )
        raise BackendUnavailableError(msg) from exc


class RasterRenderer:
    """Render a :class:`RasterScene` from any camera pose (a ``CameraRenderer`` backend).

    Use as a context manager, or call :meth:`close` to free the GL objects.
    """

    def __init__(self, scene: RasterScene, *, options: RasterOptions | None = None) -> None:
        """Create the EGL context and upload the scene.

        Raises:
            BackendUnavailableError: moderngl is missing or no EGL context can be made.
        """
        self.scene = scene
        self.options = options or RasterOptions()
        ctx = _create_context()
        self._ctx = ctx
        self._scene_prog = ctx.program(vertex_shader=_SCENE_VS, fragment_shader=_SCENE_FS)
        self._sky_prog = ctx.program(vertex_shader=_SKY_VS, fragment_shader=_SKY_FS)
        self._vbo = ctx.buffer(scene.vertices.tobytes())
        self._scene_vao = ctx.vertex_array(
            self._scene_prog, [(self._vbo, "3f 4f1", "in_pos", "in_rgba")]
        )
        self._sky_vao = ctx.vertex_array(self._sky_prog, [])
        self._targets: dict[tuple[int, int], tuple[Any, npt.NDArray[np.uint8]]] = {}
        _log.info("raster renderer on %s", ctx.info.get("GL_RENDERER", "?"))

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
        """Release the framebuffers, buffers and the context (idempotent)."""
        if self._ctx is None:
            return
        for fbo, _ in self._targets.values():
            for attachment in (*fbo.color_attachments, fbo.depth_attachment):
                attachment.release()
            fbo.release()
        self._targets.clear()
        for obj in (self._scene_vao, self._sky_vao, self._vbo, self._scene_prog, self._sky_prog):
            obj.release()
        self._ctx.release()
        self._ctx = None

    def _visible_runs(
        self, pose: npt.NDArray[np.float64], k: npt.NDArray[np.float64], width: int, height: int
    ) -> list[tuple[int, int]]:
        """Contiguous vertex ranges of the tiles inside the view frustum and draw distance."""
        s = self.scene
        if s.tile_first.size == 0:
            return []
        d = s.tile_centre - pose[:3, 3]
        cam = d @ pose[:3, :3]  # tile centres in the camera frame (x right, y down, z forward)
        r = s.tile_radius
        tan_x = max(k[0, 2] + 0.5, width - k[0, 2] - 0.5) / k[0, 0]
        tan_y = max(k[1, 2] + 0.5, height - k[1, 2] - 0.5) / k[1, 1]
        # A bounding sphere is outside a side plane when its centre is beyond it by > r; the
        # planes' normals are not unit, hence the sqrt(1 + tan^2) factors.
        ahead = cam[:, 2] + r > self.options.near_m
        near = np.linalg.norm(d, axis=1) - r < self.options.draw_distance_m
        inside_x = np.abs(cam[:, 0]) - tan_x * cam[:, 2] < r * np.sqrt(1 + tan_x**2)
        inside_y = np.abs(cam[:, 1]) - tan_y * cam[:, 2] < r * np.sqrt(1 + tan_y**2)
        vis = np.flatnonzero(ahead & near & inside_x & inside_y)
        if vis.size == 0:
            return []
        # Merge neighbouring tiles into one draw call.
        breaks = np.flatnonzero(np.diff(vis) != 1) + 1
        runs = []
        for group in np.split(vis, breaks):
            first = int(s.tile_first[group[0]])
            end = int(s.tile_first[group[-1]] + s.tile_count[group[-1]])
            runs.append((first, end - first))
        return runs

    def _target(self, width: int, height: int) -> tuple[Any, npt.NDArray[np.uint8]]:
        """The framebuffer and read-back array of one size (made once, reused)."""
        key = (width, height)
        if key not in self._targets:
            ctx = self._ctx
            fbo = ctx.framebuffer(
                color_attachments=[ctx.renderbuffer(key, components=4)],
                depth_attachment=ctx.depth_renderbuffer(key),
            )
            self._targets[key] = (fbo, np.empty((height, width, 4), dtype=np.uint8))
        return self._targets[key]

    def render(self, T_world_cam: npt.NDArray[np.float64], camera: PinholeCamera) -> RasterResult:
        """Render RGB and labels of a pinhole camera.

        Args:
            T_world_cam: ``(4, 4)`` camera (OpenCV optical axes) -> world, metres.
            camera: The camera of the wanted image (intrinsics and size, pixels), without lens
                distortion: the image is an undistorted pinhole image.

        Returns:
            The RGB image and the label image.

        Raises:
            ValueError: A pose that is not ``(4, 4)``, or a camera with lens distortion.
            RuntimeError: The renderer was closed.
        """
        pose = np.asarray(T_world_cam, dtype=np.float64)
        if pose.shape != (4, 4):
            msg = f"render needs a (4, 4) pose, got shape {pose.shape}"
            raise ValueError(msg)
        camera.require_undistorted("the raster renderer")
        if self._ctx is None:
            msg = "the raster renderer is closed"
            raise RuntimeError(msg)
        with self._ctx:  # current while drawing: several renderers may be open at once
            return self._draw(pose, camera.K(), camera.width, camera.height)

    def _draw(
        self, pose: npt.NDArray[np.float64], k: npt.NDArray[np.float64], width: int, height: int
    ) -> RasterResult:
        import moderngl  # noqa: PLC0415

        local = pose.copy()
        local[:3, 3] -= self.scene.origin
        opts = self.options
        mvp = projection_matrix(k, width, height, opts.near_m, opts.far_m) @ np.linalg.inv(local)
        self._scene_prog["mvp"].write(_gl_bytes(mvp))
        self._sky_prog["ray"].write(_gl_bytes(pose[:3, :3] @ np.linalg.inv(k)))
        self._sky_prog["size"].value = (float(width), float(height))
        fbo, out = self._target(width, height)
        ctx = self._ctx
        fbo.use()
        fbo.clear(depth=1.0)
        ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.depth_func = "<="
        for first, count in self._visible_runs(pose, k, width, height):
            self._scene_vao.render(moderngl.TRIANGLES, vertices=count, first=first)
        scene = self.scene
        self._scene_vao.render(
            moderngl.TRIANGLES, vertices=scene.ground_count, first=scene.ground_first
        )
        self._sky_vao.render(moderngl.TRIANGLES, vertices=3)
        fbo.read_into(out, components=4, alignment=1)
        return RasterResult(rgb=out[..., :3].copy(), labels=out[..., 3].copy())
