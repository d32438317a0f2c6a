"""The cameras of runs: renderers by name, camera poses and intrinsics from a scenario.

Shared by replay and drive (:mod:`cam2sim.stages.runs`) and by the reconstruction metrics
(:mod:`cam2sim.stages.reconstruction`). A camera is ``raster`` (the simulator's style),
``splat`` (the Gaussian splats), ``truth`` (the ground-truth world, ``WS/truth/world.json``),
``carla`` (rendered by a CARLA server through the simulator) or ``none``.

Every renderer satisfies :class:`CameraRenderer`; :func:`register_camera` names a factory that
opens one for a run's workspace (as rosbags registers its storage plugins), and
:class:`Cameras` opens the named ones. The built-in cameras are registered below; another
renderer plugs in with ``register_camera("mine", lambda ctx: MyRenderer(ctx.ws))``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Final, Literal, Self

import numpy as np

from cam2sim.core import frames as fr
from cam2sim.core.dataset import NO_INTRINSICS_HINT
from cam2sim.core.errors import StageError
from cam2sim.core.files import write_bytes_atomic
from cam2sim.core.images import as_grey
from cam2sim.render.interface import CameraRenderer
from cam2sim.render.meshes import BuildingFootprint
from cam2sim.render.raster import RasterRenderer, RasterScene
from cam2sim.render.truth import TruthRenderer
from cam2sim.scenario.body import body_point_positions
from cam2sim.scenario.model import Scenario
from cam2sim.splat.render import RenderOptions, SplatRenderer
from cam2sim.stages.map import load_buildings, load_road_map

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

    import numpy.typing as npt

    from cam2sim.core.camera import PinholeCamera
    from cam2sim.core.workspace import Workspace
    from cam2sim.map.query import RoadMap
    from cam2sim.sim.interface import SteeringPolicy

__all__ = [
    "TRUTH_CAMERA",
    "CameraName",
    "CameraRenderer",
    "Cameras",
    "RecordedGround",
    "RunContext",
    "camera_names",
    "camera_poses",
    "first_decision",
    "ground_height_at",
    "load_run_context",
    "policy_band",
    "recorded_ground_at",
    "recorded_tilt",
    "register_camera",
    "run_camera",
    "scaled_intrinsics",
    "vehicle_camera_pose",
    "vehicle_view",
    "view_policy",
    "write_png",
]

CameraName = Literal["raster", "splat", "truth", "carla", "none"]
#: The camera of closed-loop drives in the ground-truth world; their runs are method ``real``.
TRUTH_CAMERA: Final = "truth"


def write_png(path: Path, rgb: npt.NDArray[np.uint8]) -> None:
    """Write an RGB image as PNG, atomically (the folder is created)."""
    from cam2sim.recording.image import encode_image_file  # noqa: PLC0415 -- lazy: imports cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(path, encode_image_file(rgb, "png"))


@dataclass
class RunContext:
    """What a run needs of a workspace: the workspace, its scenario and its road map."""

    ws: Workspace
    scenario: Scenario
    road_map: RoadMap


def load_run_context(ws: Workspace) -> RunContext:
    """The workspace's scenario and road map.

    Raises:
        StageError: The workspace has no scenario yet.
    """
    path = ws.scenario_path
    if not path.is_file():
        msg = f"{ws.root} has no scenario; run `cam2sim scenario {ws.root}` first"
        raise StageError(msg)
    return RunContext(ws, Scenario.load(path), load_road_map(ws))


def run_camera(scenario: Scenario, size: tuple[int, int] | None) -> PinholeCamera:
    """The camera replays and closed-loop drives see through: the recorded one, lens included.

    The scenario's camera scaled to ``size`` (None: as calibrated; scaling keeps pixel centres
    aligned, :meth:`cam2sim.core.camera.PinholeCamera.scaled`) with its lens distortion:
    :meth:`Cameras.render` draws its view with a pinhole renderer and lays the image out as
    the recorded camera would have taken it, so a policy trained on recorded frames sees the
    same geometry in simulation.
    """
    if scenario.camera is None:
        msg = f"the scenario has no camera intrinsics; {NO_INTRINSICS_HINT}"
        raise StageError(msg)
    cam = scenario.camera.camera()
    return cam if size is None else cam.scaled(*size)


def scaled_intrinsics(scenario: Scenario, size: tuple[int, int] | None) -> PinholeCamera:
    """:func:`run_camera` without its lens distortion: a pinhole camera with the calibrated K.

    For comparisons between our own renderers (the reconstruction stage's real and simulated
    label images), where the lens plays no part.
    """
    return replace(run_camera(scenario, size), distortion=(), distortion_model="plumb_bob")


def camera_poses(
    scenario: Scenario, reference_xy: npt.NDArray[np.float64], heading: npt.NDArray[np.float64],
    reference_z: npt.NDArray[np.float64], *, roll: npt.ArrayLike = 0.0,
    pitch: npt.ArrayLike = 0.0,
) -> npt.NDArray[np.float64]:  # fmt: skip
    """``(N, 4, 4)`` camera (optical) -> world of reference-point poses and the mount.

    The car stands at each ``(x, y, z)`` with its ``heading``, level unless ``roll`` and
    ``pitch`` (radians, ROS ZYX: positive pitch is nose down) tilt it, as the recorded car was
    on a sloping road (:func:`recorded_ground_at`);
    :func:`cam2sim.core.frames.camera_poses` composes it with the scenario's camera mount.
    """
    mount = scenario.camera_mount
    xy = np.asarray(reference_xy, dtype=np.float64).reshape(-1, 2)
    z = np.broadcast_to(np.asarray(reference_z, dtype=np.float64), (xy.shape[0],))
    position = np.column_stack([xy, z])
    quat = fr.quat_from_euler(roll, pitch, np.asarray(heading, dtype=np.float64).reshape(-1))
    return fr.camera_poses(position, quat, mount.translation_m, mount.quat_xyzw)


@dataclass(frozen=True)
class RecordedGround:
    """The recorded road under a world ``(x, y)``: its height and the car's tilt on it."""

    z: float
    """Ground height, world z (m): the recorded reference point's z less its height above
    the ground."""
    roll: float = 0.0
    """The recorded car's roll there (rad; 0 when the recording has no orientation)."""
    pitch: float = 0.0
    """The recorded car's pitch there (rad, positive nose down; 0 without orientation)."""


def recorded_ground_at(scenario: Scenario, xy: npt.NDArray[np.float64]) -> RecordedGround:
    """The recorded road under the reference point at world ``(x, y)``: the nearest sample's.

    The splat models live in the recorded world, hills included: a camera that renders them
    must stand at the recorded height and lean with the road, or its horizon moves (a 5 %
    grade is 3 degrees: 35 px on a 700 px focal length). The raster and truth worlds are flat
    (their road is z = 0), so their cameras stay level.
    """
    traj = scenario.trajectory
    ref = np.asarray(traj.reference, dtype=np.float64)
    i = int(np.argmin(np.hypot(ref[:, 0] - xy[0], ref[:, 1] - xy[1])))
    z = float(ref[i, 2] - scenario.vehicle.reference_xyz[2])
    if traj.pitch is None or traj.roll is None:
        return RecordedGround(z)
    return RecordedGround(z, roll=float(traj.roll[i]), pitch=float(traj.pitch[i]))


def recorded_tilt(
    scenario: Scenario, idx: npt.NDArray[np.int64]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """The recorded car's roll and pitch (rad) at trajectory samples ``idx`` (0: not recorded)."""
    traj = scenario.trajectory
    if traj.roll is None or traj.pitch is None:
        zero = np.zeros(len(idx))
        return zero, zero
    return np.asarray(traj.roll, np.float64)[idx], np.asarray(traj.pitch, np.float64)[idx]


def ground_height_at(scenario: Scenario, xy: npt.NDArray[np.float64]) -> float:
    """Recorded ground height (world z, m) under a world ``(x, y)``: at the nearest sample.

    The raster and truth worlds have their road at z = 0; the splat models live at the
    recorded heights (:func:`recorded_ground_at` adds the car's tilt there).
    """
    return recorded_ground_at(scenario, xy).z


_CAMERAS: dict[str, Callable[[RunContext], CameraRenderer | None]] = {}


def register_camera(name: str, factory: Callable[[RunContext], CameraRenderer | None]) -> None:
    """Make camera ``name`` available to runs: ``factory(ctx)`` opens its renderer.

    A factory returning None names a camera that another part renders (``carla``: the
    simulator's own sensor). Registering a name again replaces its factory.
    """
    _CAMERAS[name] = factory


def camera_names() -> tuple[str, ...]:
    """The registered camera names, sorted."""
    return tuple(sorted(_CAMERAS))


def _raster(ctx: RunContext) -> CameraRenderer:
    buildings = [BuildingFootprint(b.xy, b.height_m) for b in load_buildings(ctx.ws)]
    return RasterRenderer(RasterScene(ctx.road_map, ctx.scenario.parked, buildings))


def _truth(ctx: RunContext) -> CameraRenderer:
    """The ground-truth world (``WS/truth/world.json``)."""
    return TruthRenderer.open(ctx.ws.root, ctx.scenario.world.proj_string)


def _splat(ctx: RunContext) -> CameraRenderer:
    models = ctx.ws.splat_files.models_dir
    if not models.is_dir():
        msg = f"{ctx.ws.root} has no splat models; run `cam2sim splat {ctx.ws.root}`"
        raise StageError(msg)
    # The run's vehicle is planar: its camera takes the recorded views' height and tilt.
    return SplatRenderer(models, options=RenderOptions(pose_frame="vehicle"))


register_camera("raster", _raster)
register_camera(TRUTH_CAMERA, _truth)
register_camera("splat", _splat)
register_camera("carla", lambda _ctx: None)  # rendered by the CARLA server through the simulator


class Cameras:
    """The run's renderers by name, opened once and closed at the end."""

    def __init__(self, ctx: RunContext, names: tuple[str, ...]) -> None:
        """Open the renderers of ``names``.

        Raises:
            StageError: A name no camera is registered under (the message lists them), or a
                renderer that cannot open (its own message).
        """
        self.renderers: dict[str, Any] = {}
        # A grey recording's camera: every view is made grey as that sensor would record it.
        camera = ctx.scenario.camera if ctx is not None else None
        self.grey = bool(camera is not None and camera.grey)
        self.carla: Any = None  # a CarlaSimulator whose hero is teleported (replay)
        # Per camera with lens distortion: the pinhole camera to render and the remap tables.
        self._lenses: dict[PinholeCamera, Any] = {}
        unknown = [n for n in names if n not in _CAMERAS and n != "none"]
        if unknown:
            msg = f"no camera {', '.join(unknown)}; the cameras are {', '.join(camera_names())}"
            raise StageError(msg)
        try:
            for name in names:
                if name == "none":
                    continue
                renderer = _CAMERAS[name](ctx)
                if renderer is not None:
                    self.renderers[name] = renderer
        except BaseException:
            self.close()
            raise

    def render(
        self,
        name: str,
        T: npt.NDArray[np.float64],
        camera: PinholeCamera,
        rows: tuple[int, int] | None = None,
    ) -> npt.NDArray[np.uint8]:
        """RGB of camera ``name`` at ``T`` (camera -> world, optical axes) through ``camera``.

        With ``rows = (first, stop)`` only those rows, ``stop - first`` high: rendered alone by
        cameras that can (:meth:`renders_rows`), cut from the whole image by the others.

        A ``camera`` with lens distortion is drawn through its pinhole camera and remapped
        (:meth:`~cam2sim.core.camera.PinholeCamera.pinhole_remap`): the image is what that
        camera records (always whole before ``rows`` are cut from it). For a grey recording
        (``CameraIntrinsics.grey``) the view is grey (:func:`~cam2sim.core.images.as_grey`).
        """
        image = self._render(name, T, camera, rows)
        return as_grey(image) if self.grey else image

    def _render(
        self,
        name: str,
        T: npt.NDArray[np.float64],
        camera: PinholeCamera,
        rows: tuple[int, int] | None,
    ) -> npt.NDArray[np.uint8]:
        renderer = self.renderers[name]
        if camera not in self._lenses:
            self._lenses[camera] = camera.pinhole_remap()
        lens = self._lenses[camera]
        if lens is not None:
            import cv2  # noqa: PLC0415 -- lazy: imports cv2

            pinhole, map_x, map_y = lens
            image = renderer.render(T, pinhole).rgb
            seen: npt.NDArray[np.uint8] = cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR)
            return seen if rows is None else seen[rows[0] : rows[1]]
        if rows is not None and self.renders_rows(name):
            band: npt.NDArray[np.uint8] = renderer.render(T, camera, rows=rows).rgb
            return band
        rgb: npt.NDArray[np.uint8] = renderer.render(T, camera).rgb
        return rgb if rows is None else rgb[rows[0] : rows[1]]

    def renders_rows(self, name: str) -> bool:
        """Whether camera ``name`` renders a band of rows for less than the whole image.

        The splat renderer does (its pixels do not depend on the image's size); the others
        render whole images (the truth camera's sensor noise and vignetting are laid out over
        the whole frame).
        """
        return bool(getattr(self.renderers.get(name), "RENDERS_ROWS", False))

    def coverage(self, name: str, T: npt.NDArray[np.float64]) -> float:
        """The splat camera ``name``'s coverage of pose ``T`` (0 on a training view, toward 1)."""
        value: float = self.renderers[name].coverage_of(T)[0]
        return value

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close every renderer (and the CARLA simulator a replay teleports)."""
        for r in self.renderers.values():
            r.close()
        if self.carla is not None:
            self.carla.close()


def view_policy(spec: str, scenario: Scenario) -> SteeringPolicy:
    """The policy ``spec`` loaded to answer single views (:func:`first_decision`): no route.

    Raises:
        StageError: The policy cannot be loaded (see :func:`cam2sim.ads.policy.load_policy`).
    """
    from cam2sim.ads.policy import load_policy  # noqa: PLC0415 -- lazy: cv2, onnxruntime

    return load_policy(
        spec, route_xy=None, wheelbase_m=scenario.vehicle.wheelbase_m,
        calibration=scenario.steering_calibration,
    )  # fmt: skip


def first_decision(
    policy: SteeringPolicy,
    image: npt.NDArray[np.uint8],
    xy: tuple[float, float] = (0.0, 0.0),
    heading: float = 0.0,
) -> float:
    """The policy's steering for one view, as the first decision of a run (the car at ``xy``).

    How the route profile and the steering agreement ask a policy about a single image.
    """
    from cam2sim.core.vehicle import VehicleState  # noqa: PLC0415
    from cam2sim.sim.interface import Observation  # noqa: PLC0415

    x, y = float(xy[0]), float(xy[1])
    state = VehicleState(0.0, x, y, 0.0, float(heading), 0.0, 0.0, 0.0, (x, y))
    policy.reset()
    return float(policy.predict(Observation(0.0, image, state)))


def policy_band(
    policy: object, cameras: Cameras, cam_name: str | None, height: int, *, keep_frames: bool
) -> tuple[int, int] | None:
    """The rows of the camera's frames a drive renders, or None for whole frames.

    A band when the policy reads only one (DAVE-2's crop,
    :class:`~cam2sim.ads.policy.ReadsImageRows`) and the camera renders a band for less
    (:meth:`Cameras.renders_rows`: the splat camera, the costly one on a CPU); the policy's
    input is what the whole frame would give it. Whole frames when they are kept
    (``keep_frames``: PNG frames or video, what people look at).
    """
    from cam2sim.ads.policy import ReadsImageRows  # noqa: PLC0415 -- lazy: imports cv2

    if cam_name is None or keep_frames or not cameras.renders_rows(cam_name):
        return None
    if not isinstance(policy, ReadsImageRows):
        return None
    rows = policy.image_rows(height)
    if rows is None or rows == (0, height):
        return None
    return rows


def vehicle_camera_pose(
    sc: Scenario, x: float, y: float, heading: float, *, recorded: bool
) -> npt.NDArray[np.float64]:
    """``(4, 4)`` camera (optical) -> world of the vehicle with its centre at ``(x, y)``.

    ``recorded``: in the recorded world (the splat's), at the recorded road's height and tilt
    under the car (:func:`recorded_ground_at`); else on the flat road at z = 0 of the raster
    and truth worlds.
    """
    ref_xyz = sc.vehicle.reference_xyz
    ref_now = body_point_positions([[x, y, 0.0]], [heading], (0.0, 0.0, 0.0), ref_xyz)[0]
    ground = recorded_ground_at(sc, ref_now[:2]) if recorded else RecordedGround(0.0)
    pose: npt.NDArray[np.float64] = camera_poses(
        sc, ref_now[None, :2], np.array([heading]), np.array([ref_xyz[2] + ground.z]),
        roll=ground.roll, pitch=ground.pitch,
    )[0]  # fmt: skip
    return pose


def vehicle_view(
    sc: Scenario,
    state: Any,
    cameras: Cameras,
    cam_name: str,
    camera: PinholeCamera,
    coverage: list[float],
    band: tuple[int, int] | None = None,
) -> npt.NDArray[np.uint8]:
    """What the vehicle's camera sees in its current state (the splat's coverage appended).

    With ``band = (first, stop)`` only those rows are rendered; the others stay black.
    """
    T = vehicle_camera_pose(sc, state.x, state.y, state.heading, recorded=cam_name == "splat")
    if cam_name == "splat":
        coverage.append(cameras.coverage(cam_name, T))
    if band is None:
        return cameras.render(cam_name, T, camera)
    frame = np.zeros((camera.height, camera.width, 3), np.uint8)
    frame[band[0] : band[1]] = cameras.render(cam_name, T, camera, rows=band)
    return frame
