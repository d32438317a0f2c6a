"""Runs: trajectory replay and closed-loop drives of a scenario, each in its own run folder.

``cam2sim replay`` moves the vehicle exactly along the recorded trajectory and renders every
frame with the chosen cameras, beside the real frame. ``cam2sim drive`` closes the loop: the
builtin simulator (:mod:`cam2sim.sim.builtin`) steps the vehicle, a camera renders what the
vehicle sees, and a steering policy (:mod:`cam2sim.ads.policy`) answers every
``policy_every``-th step.

Every run writes a new folder ``WS/runs/<run-id>/`` (built under a temporary name and renamed
into place, so runs never overwrite each other and no half run is left):

- ``trajectory.csv``: ``t, x, y, z, heading, speed, steering, wheel_angle`` of the recorded
  reference point (the point real drives are recorded at, so runs and real drives compare
  directly in ``cam2sim evaluate drive``);
- ``steering.csv``: the policy's decisions ``t, value``; ``events.json``; ``run.json`` (what was
  run: kind, policy, camera, seed, options, timing, the world projection; with the splat
  camera also ``splat_quality``, the splat's coverage along the driven path and its held-out
  and ground-truth scores, and ``splat_gate``, the quality gate's verdict:
  :mod:`cam2sim.metrics.splat_gate`);
- ``frames/<camera>/NNNNNN.png`` and ``side_by_side/`` on request, ``video.mp4`` on request.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import time
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from cam2sim.core.background import BackgroundJobs
from cam2sim.core.dataset import DatasetInfo
from cam2sim.core.errors import Cam2SimError, ConfigError, StageError
from cam2sim.core.polyline import arc_length
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.run_record import RunEvents, RunRecord
from cam2sim.core.schema import format_validation_error
from cam2sim.core.table import write_table
from cam2sim.core.workspace import dataset_paths, run_paths
from cam2sim.detect.route import MIN_ROUTE_M
from cam2sim.metrics.splat_gate import gate_run, path_quality
from cam2sim.render.truth import TRUTH_WORLD_FILE, TruthWorld, truth_world_path
from cam2sim.sim.builtin import BuiltinOptions, BuiltinSimulator
from cam2sim.sim.carla_backend import CarlaOptions, CarlaSimulator
from cam2sim.sim.episode import EpisodeOptions, run_episode
from cam2sim.sim.interface import PlanarPose
from cam2sim.sim.speed import SpeedProfile
from cam2sim.splat.evaluate import SplatEval
from cam2sim.stages.cameras import (
    TRUTH_CAMERA,
    CameraName,
    Cameras,
    RunContext,
    camera_poses,
    load_run_context,
    policy_band,
    recorded_tilt,
    run_camera,
    vehicle_view,
    write_png,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

    import numpy.typing as npt

    from cam2sim.core.workspace import Workspace
    from cam2sim.scenario.model import Scenario
    from cam2sim.sim.interface import Simulator, SteeringPolicy, VehicleState
    from cam2sim.stages.variation import DrawnVariation, RunVariation

__all__ = [
    "TRUTH_CAMERA",
    "CameraName",
    "DriveOptions",
    "ReplayOptions",
    "RunResult",
    "default_judge",
    "drive",
    "replay",
]

logger = logging.getLogger(__name__)
SimulatorName = Literal["builtin", "carla"]


@dataclass(frozen=True)
class ReplayOptions:
    """What ``cam2sim replay`` does.

    Attributes:
        cameras: Cameras to render (``raster``, ``splat``; both for a side by side).
        frames: ``(first, stop)`` or ``(first, stop, step)`` trajectory samples to replay
            (Python slice bounds).
        image_size: ``(width, height)`` of rendered frames; None keeps the calibrated size.
        save_frames: Write every rendered frame (PNG) and the side-by-side images.
        video: Write ``video.mp4`` of the side-by-side images.
        simulator: ``carla`` adds CARLA's camera (``cameras`` may then name ``carla``): the
            hero is teleported to every recorded pose and CARLA renders it.
        carla: CARLA backend options; None: defaults.
        carla_client_factory: Builds the ``carla.Client`` (tests and embedding).
    """

    cameras: tuple[CameraName, ...] = ("raster",)
    frames: tuple[int | None, ...] = (None, None)
    image_size: tuple[int, int] | None = None
    save_frames: bool = True
    video: bool = True
    simulator: SimulatorName = "builtin"
    carla: Any = field(default=None)
    carla_client_factory: Any = field(default=None)

    def __post_init__(self) -> None:
        if "carla" in self.cameras and self.simulator != "carla":
            msg = "the carla camera needs --sim carla (CARLA's own camera runs in CARLA)"
            raise ConfigError(msg)


@dataclass(frozen=True)
class DriveOptions:
    """What ``cam2sim drive`` does.

    Attributes:
        policy: Policy name (see :func:`cam2sim.ads.policy.load_policy`).
        camera: Camera the policy sees (``none`` for policies that need no image).
        runs: Number of runs (seeds ``seed``, ``seed + 1``, ...).
        speed_kmh: Target speed; None holds the recorded start speed.
        recorded_speed: Follow the recorded speed along the route instead (where the driver
            slowed for a turn, the car slows; :mod:`cam2sim.sim.speed`); not with
            ``speed_kmh``.
        seed: Seed of the first run.
        policy_every: The policy answers every n-th simulator step (3, as the published tool).
        image_size: ``(width, height)`` the camera renders at; None keeps the calibrated size.
        max_steps: Step cap per run (the simulator's timeout usually ends it first).
        save_frames: Write the rendered frames.
        video: Write ``video.mp4``.
        sim: Builtin simulator options (None: defaults with the scenario's calibration).
        steering_noise_std: Steering noise of the builtin simulator (steering units per step,
            seeded per run) over ``sim``'s, so that repeated runs of a deterministic policy
            differ; 0 keeps ``sim``'s (none by default).
        simulator: ``builtin`` (embedded) or ``carla`` (a running CARLA server).
        carla: CARLA backend options (host, port, mesh, blueprints...); None: defaults.
        carla_client_factory: Builds the ``carla.Client`` (tests and embedding; None: connect).
        start_offset: ``(lateral_m, heading_deg)`` moved from the recorded hero start (lateral:
            left of the start heading; heading: counter-clockwise); ``(0, 0)`` keeps it.
        variation: Seeded run-to-run differences (start pose, speed) drawn per run on top of
            ``start_offset`` and the target speed (:mod:`cam2sim.stages.variation`); None: none.
        judge: The world whose road and parked cars decide when a run left the road or hit a
            car: ``map`` (the reconstructed map and the scenario's parked vehicles, as in
            CARLA) or ``truth`` (the workspace's ground-truth world, ``WS/truth/world.json``:
            where a real car would have driven; builtin simulator only).
    """

    policy: str = "pure-pursuit"
    camera: CameraName = "raster"
    runs: int = 1
    speed_kmh: float | None = None
    recorded_speed: bool = False
    seed: int = 0
    policy_every: int = 3
    image_size: tuple[int, int] | None = None
    max_steps: int = 100_000
    save_frames: bool = False
    video: bool = False
    sim: BuiltinOptions | None = None
    steering_noise_std: float = 0.0
    simulator: SimulatorName = "builtin"
    carla: CarlaOptions | None = None
    carla_client_factory: Any = field(default=None)
    start_offset: tuple[float, float] = (0.0, 0.0)
    variation: RunVariation | None = None
    judge: Literal["map", "truth"] = "map"

    def __post_init__(self) -> None:
        if self.judge == "truth" and self.simulator != "builtin":
            msg = (
                "judging runs in the ground-truth world needs the builtin simulator (--sim builtin)"
            )
            raise ConfigError(msg)
        if self.runs < 1 or self.policy_every < 1 or self.max_steps < 1:
            msg = "runs, policy_every and max_steps must be >= 1"
            raise ValueError(msg)
        if self.camera == "carla" and self.simulator != "carla":
            msg = "--camera carla needs --sim carla (CARLA's own camera runs in CARLA)"
            raise ConfigError(msg)
        if self.recorded_speed and self.speed_kmh is not None:
            msg = "give a fixed speed (--speed KMH) or --speed recorded, not both"
            raise ConfigError(msg)


@dataclass(frozen=True)
class RunResult:
    """One finished run."""

    run_id: str
    folder: Path
    steps: int
    events: tuple[dict[str, Any], ...]
    seconds: float


def _new_run_dir(ws: Workspace, kind: str, label: str) -> tuple[str, Path]:
    stamp = dt.datetime.now(dt.UTC).strftime("%Y%m%d-%H%M%S")
    base = f"{stamp}-{kind}-{label}".replace("/", "_").replace(":", "_")
    ws.runs_dir.mkdir(parents=True, exist_ok=True)
    run_id, n = base, 1
    while True:
        tmp = ws.runs_dir / f".tmp-{run_id}"
        if not (ws.runs_dir / run_id).exists():
            try:
                tmp.mkdir()  # atomic: of concurrent runs (a campaign) one gets each name
            except FileExistsError:
                pass
            else:
                return run_id, tmp
        n += 1
        run_id = f"{base}-{n}"


def _finish_run(ws: Workspace, run_id: str, tmp: Path) -> Path:
    final = ws.runs_dir / run_id
    tmp.rename(final)  # same folder: atomic; the name was checked to be free
    return final


class _Video:
    """An MP4 written frame by frame (OpenCV's ``mp4v``), opened on the first frame."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path, self.fps = path, fps
        self.writer: Any = None

    def add(self, rgb: npt.NDArray[np.uint8]) -> None:
        import cv2  # noqa: PLC0415

        h, w = rgb.shape[:2]
        if self.writer is None:
            fourcc = cv2.VideoWriter.fourcc(*"mp4v")
            self.writer = cv2.VideoWriter(str(self.path), fourcc, self.fps, (w - w % 2, h - h % 2))
            if not self.writer.isOpened():
                msg = f"OpenCV cannot write {self.path}; install an OpenCV build with video I/O"
                raise StageError(msg)
        self.writer.write(cv2.cvtColor(rgb[: h - h % 2, : w - w % 2], cv2.COLOR_RGB2BGR))

    def close(self) -> None:
        if self.writer is not None:
            self.writer.release()


def side_by_side(images: list[npt.NDArray[np.uint8]], height: int = 360) -> npt.NDArray[np.uint8]:
    """Images resized to one height and put next to each other."""
    import cv2  # noqa: PLC0415

    parts = []
    for im in images:
        w = max(1, round(im.shape[1] * height / im.shape[0]))
        parts.append(cv2.resize(im, (w, height), interpolation=cv2.INTER_AREA))
    out: npt.NDArray[np.uint8] = np.concatenate(parts, axis=1)
    return out


def _write_tables(
    folder: Path, rows: dict[str, list[float]], decisions: list[tuple[float, float]]
) -> None:
    files = run_paths(folder)
    write_table(files.trajectory_csv, {k: np.asarray(v) for k, v in rows.items()})
    arr = np.asarray(decisions, dtype=np.float64).reshape(-1, 2)
    write_table(files.steering_csv, {"t": arr[:, 0], "value": arr[:, 1]})


def _write_meta(folder: Path, meta: dict[str, Any], events: list[dict[str, Any]]) -> None:
    """Write ``events.json`` and ``run.json`` through their records (validated, atomic)."""
    files = run_paths(folder)
    RunEvents.model_validate({"events": events}).save(files.events_json)
    # Options hold tuples, nested dataclasses and, for tests, callables: JSON them first.
    RunRecord.model_validate(json.loads(json.dumps(meta, default=str))).save(files.run_json)


# -- replay --------------------------------------------------------------------------------------
def replay(
    ws: Workspace,
    *,
    options: ReplayOptions | None = None,
    progress: ProgressCallback | None = None,
) -> RunResult:
    """Replay the recorded trajectory exactly and render it with the chosen cameras."""
    opts = options or ReplayOptions()
    report = progress or no_progress
    ctx = load_run_context(ws)
    tr = ctx.scenario.trajectory
    sel = slice(*opts.frames)
    idx = np.arange(len(tr.frame))[sel]
    if idx.size == 0:
        msg = f"--frames {opts.frames} selects no sample of the {len(tr.frame)} recorded"
        raise StageError(msg)
    ref = np.asarray(tr.reference, dtype=np.float64)[idx]
    heading = np.asarray(tr.heading, dtype=np.float64)[idx]
    cams = tuple(c for c in opts.cameras if c != "none")
    label = "+".join(cams) or "none"
    run_id, tmp = _new_run_dir(ws, "replay", label)
    started = time.perf_counter()
    try:
        with Cameras(ctx, cams) as cameras:
            if "carla" in cams:
                cameras.carla = _open_carla(
                    ctx, _carla_options(opts.carla, ctx.scenario, 0, ws), opts.carla_client_factory
                )
            frames_done = _replay_frames(ctx, opts, cameras, idx, ref, heading, tmp, report)
        rows = {
            "t": [tr.t[i] for i in idx],
            "x": ref[:, 0].tolist(),
            "y": ref[:, 1].tolist(),
            "z": ref[:, 2].tolist(),
            "heading": heading.tolist(),
            "speed": [tr.speed[i] for i in idx],
            "steering": [0.0] * idx.size,
            "wheel_angle": [0.0] * idx.size,
        }
        _write_tables(tmp, rows, [])
        seconds = time.perf_counter() - started
        meta = {
            "kind": "replay",
            "method": f"replay-{label}",
            "camera": label,
            "cameras": list(cams),
            "frames": [int(idx[0]), int(idx[-1]) + 1],
            "rendered": frames_done,
            "seconds": round(seconds, 3),
            "options": asdict(opts),
            "proj_string": ctx.scenario.world.proj_string,
        }
        _write_meta(tmp, meta, [])
    except BaseException:
        _discard(tmp)
        raise
    return RunResult(run_id, _finish_run(ws, run_id, tmp), int(idx.size), (), seconds)


def _discard(tmp: Path) -> None:
    import shutil  # noqa: PLC0415

    shutil.rmtree(tmp, ignore_errors=True)


def _real_frames(ws: Workspace) -> Callable[[int], npt.NDArray[np.uint8] | None]:
    """A reader of the dataset's real frames by index (returns None where there is none)."""
    import cv2  # noqa: PLC0415

    paths = dataset_paths(ws.dataset_dir)
    fmt = (
        DatasetInfo.load(paths.dataset_json).frame_format if paths.dataset_json.is_file() else None
    )

    def read(frame: int) -> npt.NDArray[np.uint8] | None:
        if fmt is None:
            return None
        bgr = cv2.imread(str(paths.frame_file(frame, fmt)), cv2.IMREAD_COLOR)
        if bgr is None:
            return None
        return np.asarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)

    return read


def _replay_frames(
    ctx: RunContext,
    opts: ReplayOptions,
    cameras: Cameras,
    idx: npt.NDArray[np.int64],
    ref: npt.NDArray[np.float64],
    heading: npt.NDArray[np.float64],
    folder: Path,
    report: ProgressCallback,
) -> int:
    if not (cameras.renderers or cameras.carla) or not (opts.save_frames or opts.video):
        return 0
    camera = run_camera(ctx.scenario, opts.image_size)
    tr = ctx.scenario.trajectory
    ground = ref[:, 2] - ctx.scenario.vehicle.reference_xyz[2]
    # The raster and truth worlds' road is flat at z = 0; the splat models live in the recorded
    # world, at its heights and slopes: there the camera stands as the recorded one stood.
    flat = ref[:, 2] - ground
    roll, pitch = recorded_tilt(ctx.scenario, idx)
    poses = {
        name: camera_poses(ctx.scenario, ref[:, :2], heading, flat)
        for name in ("raster", TRUTH_CAMERA)
    }
    poses["splat"] = camera_poses(
        ctx.scenario, ref[:, :2], heading, ref[:, 2], roll=roll, pitch=pitch
    )
    t = np.asarray(tr.t, dtype=np.float64)[idx]
    fps = 1.0 / max(float(np.median(np.diff(t))), 1e-3) if len(t) > 1 else 10.0
    video = _Video(run_paths(folder).video, fps) if opts.video else None
    real_frame = _real_frames(ctx.ws)
    # The recorded frames are read ahead, and the PNGs encoded and written, on worker threads
    # while this one renders: for a KITTI frame (1242x375) the reading and the three files
    # take about 65 ms of one laptop core; the whole replay took 130 ms a frame on an H100.
    try:
        with BackgroundJobs[Any](name="cam2sim-replay") as writes:
            reals = writes.imap(real_frame, [tr.frame[i] for i in idx.tolist()])
            for k, (i, real) in enumerate(zip(idx.tolist(), reals, strict=True)):
                names = list(cameras.renderers)
                views = [cameras.render(n, poses[n][k], camera) for n in names]
                if cameras.carla is not None:
                    views.append(_carla_view(cameras.carla, tr, i))
                    names.append("carla")
                sbs = side_by_side(([real] if real is not None else []) + views)
                if opts.save_frames:
                    stem = f"{tr.frame[i]:06d}.png"
                    for name, im in zip(names, views, strict=True):
                        writes.submit(write_png, run_paths(folder).frames_dir(name) / stem, im)
                    writes.submit(write_png, run_paths(folder).side_by_side_dir / stem, sbs)
                if video is not None:
                    video.add(sbs)
                report("replay frames", k + 1, int(idx.size))
    finally:
        if video is not None:
            video.close()
    return int(idx.size)


def _carla_view(sim: Any, tr: Any, i: int) -> npt.NDArray[np.uint8]:
    """Teleport CARLA's hero to recorded sample ``i`` and return its camera image."""
    cx, cy, _ = tr.center[i]
    sim.reset(PlanarPose(cx, cy, tr.heading[i], tr.speed[i]))
    rgb: npt.NDArray[np.uint8] = sim.camera_images().rgb
    return rgb


# -- drive ---------------------------------------------------------------------------------------
def stood_still_m(scenario: Scenario) -> float | None:
    """How far the recorded car drove when that is too little for a route, else None.

    Below :data:`~cam2sim.detect.route.MIN_ROUTE_M` (metres along the reference-point
    trajectory) the recording stood still: closed-loop drives, splats and DAVE-2 need motion.
    """
    xy = np.asarray(scenario.trajectory.reference, dtype=np.float64)[:, :2]
    length = float(arc_length(xy)[-1]) if len(xy) else 0.0
    return length if length < MIN_ROUTE_M else None


def require_route(scenario: Scenario) -> None:
    """Refuse closed-loop driving on a recording that stood still.

    Raises:
        StageError: The recorded car drove less than :data:`~cam2sim.detect.route.MIN_ROUTE_M`.
    """
    length = stood_still_m(scenario)
    if length is not None:
        msg = (
            f"the recorded car drove {length:.1f} m (it stood still); closed-loop drives follow "
            f"the recorded route, so they need a recording that moves at least {MIN_ROUTE_M:.0f} m "
            "(extract, detect, map, scenario and replay work on this one)"
        )
        raise StageError(msg)


def default_judge(ws: Workspace) -> Literal["map", "truth"]:
    """Where ``cam2sim run`` and campaigns judge a workspace's drives unless told otherwise.

    In its ground-truth world when it has one (a real car's road and parked cars), else on
    the map.
    """
    return "truth" if ws.truth_world_json.is_file() else "map"


def drive(
    ws: Workspace,
    *,
    options: DriveOptions | None = None,
    progress: ProgressCallback | None = None,
) -> list[RunResult]:
    """Closed-loop runs of a policy in the builtin simulator (one folder per run)."""
    from cam2sim.ads.policy import load_policy  # noqa: PLC0415 -- lazy: imports cv2

    opts = options or DriveOptions()
    ctx = load_run_context(ws)
    sc = ctx.scenario
    require_route(sc)
    policy = load_policy(
        opts.policy,
        route_xy=np.asarray(sc.trajectory.rear_axle, dtype=np.float64)[:, :2],
        wheelbase_m=sc.vehicle.wheelbase_m,
        calibration=sc.steering_calibration,
    )
    results: list[RunResult] = []
    try:
        # What the runs are judged in: read once for all of them.
        judged = _truth_judge(ctx) if opts.judge == "truth" else (sc, ctx.road_map)
        cams: tuple[CameraName, ...] = () if opts.camera == "none" else (opts.camera,)
        with Cameras(ctx, cams) as cameras:
            results.extend(
                _drive_one(
                    ctx, opts, policy, cameras, opts.seed + r, progress or no_progress, judged
                )
                for r in range(opts.runs)
            )
    finally:
        policy.close()
    return results


def _drive_one(
    ctx: RunContext,
    opts: DriveOptions,
    policy: SteeringPolicy,
    cameras: Cameras,
    seed: int,
    report: ProgressCallback,
    judged: tuple[Scenario, Any],
) -> RunResult:
    """One run; the builtin simulator checks road and collisions in ``judged``."""
    sc = ctx.scenario
    target = None if opts.speed_kmh is None else opts.speed_kmh / 3.6
    sim: Simulator
    sim_opts: BuiltinOptions | CarlaOptions
    if opts.simulator == "carla":
        carla_opts = _carla_options(opts.carla, sc, seed, ctx.ws)
        sim, sim_opts = _open_carla(ctx, carla_opts, opts.carla_client_factory), carla_opts
    else:
        base = opts.sim or BuiltinOptions(calibration=sc.steering_calibration)
        update: dict[str, Any] = {"seed": seed}
        if opts.steering_noise_std:
            update["steering_noise_std"] = opts.steering_noise_std
        builtin_opts = base.model_copy(update=update)
        builtin = BuiltinSimulator(builtin_opts)
        builtin.load(*judged)
        sim, sim_opts = builtin, builtin_opts
    try:
        return _drive_loop(ctx, opts, policy, cameras, sim, sim_opts, target, seed, report)
    finally:
        sim.close()


def _truth_judge(ctx: RunContext) -> tuple[Scenario, Any]:
    """The scenario with the ground truth's parked cars, and the ground truth's road.

    Both in the workspace world frame: what a drive judged in the truth world is checked against.
    """
    path = truth_world_path(ctx.ws.root)
    if not path.is_file():
        msg = (
            f"{ctx.ws.root} has no ground-truth world ({TRUTH_WORLD_FILE}) to judge runs in; "
            "judge them on the map instead (--judge map)"
        )
        raise StageError(msg)
    road_map, parked = TruthWorld.load(path).in_world_frame(ctx.scenario.world.proj_string)
    return ctx.scenario.model_copy(update={"parked": tuple(parked)}), road_map


def _carla_options(
    options: CarlaOptions | None, sc: Scenario, seed: int, ws: Workspace | None = None
) -> CarlaOptions:
    """The CARLA options of a run: given ones, else config.yaml's ``carla`` block."""
    import pydantic  # noqa: PLC0415

    base = options
    if base is None:
        raw = ws.load_config().carla if ws is not None else {}
        try:
            base = CarlaOptions.model_validate(raw)
        except pydantic.ValidationError as err:
            source = "config.yaml carla"
            raise ConfigError(format_validation_error(err, source=source)) from None
    update: dict[str, Any] = {"calibration": base.calibration or sc.steering_calibration}
    if "seed" in type(base).model_fields:
        update["seed"] = seed
    return base.model_copy(update=update)


def _open_carla(ctx: RunContext, options: CarlaOptions, client_factory: Any) -> CarlaSimulator:
    sim = CarlaSimulator(options, workspace_root=ctx.ws.root, client_factory=client_factory)
    try:
        sim.load(ctx.scenario, ctx.road_map)
    except BaseException:
        sim.close()
        raise
    return sim


def _drive_loop(  # noqa: PLR0913, PLR0917 - one run: its context, options, parts, seed
    ctx: RunContext,
    opts: DriveOptions,
    policy: SteeringPolicy,
    cameras: Cameras,
    sim: Simulator,
    sim_opts: BuiltinOptions | CarlaOptions,
    target: float | None,
    seed: int,
    report: ProgressCallback,
) -> RunResult:
    """One run folder around :func:`~cam2sim.sim.episode.run_episode`: frames, tables, meta."""
    sc = ctx.scenario
    offset, target, drawn = _varied(sc, opts, seed, target)
    cam_name = "carla" if opts.camera == "carla" else next(iter(cameras.renderers), None)
    view = run_camera(sc, opts.image_size) if cam_name else None
    height = view.height if view is not None else 0
    band = policy_band(
        policy, cameras, cam_name, height, keep_frames=opts.save_frames or opts.video
    )
    run_id, tmp = _new_run_dir(ctx.ws, "drive", f"{policy.name}-{cam_name or 'none'}-s{seed}")
    fps = 1.0 / sim_opts.dt / opts.policy_every
    video = _Video(run_paths(tmp).video, fps) if opts.video else None
    coverage: list[float] = []  # the splat camera's, per frame
    camera = None
    if cam_name == "carla":
        carla_sim: Any = sim  # CARLA's own camera: the frame of the last tick

        def camera(state: VehicleState) -> npt.NDArray[np.uint8]:
            del state
            image: npt.NDArray[np.uint8] = carla_sim.camera_images().rgb
            return image

    elif cam_name is not None and view is not None:
        name, lens = cam_name, view

        def camera(state: VehicleState) -> npt.NDArray[np.uint8]:
            return vehicle_view(sc, state, cameras, name, lens, coverage, band)

    def keep(image: npt.NDArray[np.uint8], step: int) -> None:
        assert cam_name is not None  # frames come only from a camera
        _keep_frame(image, run_paths(tmp).frames_dir(cam_name), step, opts.save_frames, video)

    options = _episode_options(sc, opts, target, drawn)
    try:
        episode = run_episode(
            sim, policy, camera, options, _start_pose(sc, offset),
            on_frame=keep, progress=lambda steps: report(f"run {run_id}", steps, None),
        )  # fmt: skip
        events = [
            {"kind": e.kind, "t": e.t, "x": e.x, "y": e.y, "reason": e.reason}
            for e in episode.events
        ]
        if episode.failure is not None:
            f = episode.failure
            events.append(
                {"kind": "policy_error", "t": f.t, "x": f.x, "y": f.y, "reason": f.reason}
            )
            logger.warning("run %s: policy failed at t=%.2f s: %s", run_id, f.t, f.reason)
        _write_tables(tmp, episode.rows, episode.decisions)
        timing = {
            "seconds": episode.seconds, "render_s": episode.render_s, "policy_s": episode.policy_s
        }  # fmt: skip
        meta = _drive_meta(
            opts, policy.name, cam_name, seed, episode.steps, len(episode.decisions), timing
        )
        if band is not None:
            meta["rendered_rows"] = band
        meta |= {"simulator": sim_opts.model_dump(mode="json"), "proj_string": sc.world.proj_string}
        if drawn is not None:
            meta["variation"] = asdict(drawn)
        if cam_name == "splat":
            meta |= _splat_quality(ctx.ws, run_id, coverage)
        _write_meta(tmp, meta, events)
    except BaseException:
        _discard(tmp)
        raise
    finally:
        if video is not None:
            video.close()
    folder = _finish_run(ctx.ws, run_id, tmp)
    return RunResult(run_id, folder, episode.steps, tuple(events), episode.seconds)


def _drive_meta(
    opts: DriveOptions,
    policy: str,
    cam_name: str | None,
    seed: int,
    steps: int,
    decisions: int,
    timing: dict[str, float],
) -> dict[str, Any]:
    """``run.json`` of a drive (without the simulator block)."""
    seconds = timing["seconds"]
    return {
        "kind": "drive",
        # Drives in the ground-truth world are real-world runs (the Real group of the metrics).
        "method": "real" if cam_name == TRUTH_CAMERA else f"drive-{cam_name or 'none'}",
        "camera": cam_name or "none",
        "policy": policy,
        "seed": seed,
        "sim": opts.simulator,
        "steps": steps,
        "seconds": round(seconds, 3),
        "steps_per_s": round(steps / max(seconds, 1e-9), 1),
        "render_ms": round(1e3 * timing["render_s"] / max(decisions, 1), 3),
        "policy_ms": round(1e3 * timing["policy_s"] / max(decisions, 1), 3),
        "options": {
            k: v
            for k, v in asdict(opts).items()
            if k not in ("sim", "carla", "carla_client_factory")
        },
    }


def _episode_options(
    sc: Scenario, opts: DriveOptions, target: float | None, drawn: DrawnVariation | None
) -> EpisodeOptions:
    """The episode's options: the step cap, the decision rate and the speed to drive at."""
    profile = None
    if opts.recorded_speed:
        tr = sc.trajectory
        profile = SpeedProfile.recorded(tr.center, tr.speed, tr.t)
    return EpisodeOptions(
        max_steps=opts.max_steps,
        policy_every=opts.policy_every,
        target_speed=target,
        speed_profile=profile,
        speed_factor=drawn.speed_factor if drawn is not None else 1.0,
        reference_xyz=sc.vehicle.reference_xyz,
    )


def _varied(
    sc: Scenario, opts: DriveOptions, seed: int, target: float | None
) -> tuple[tuple[float, float], float | None, DrawnVariation | None]:
    """The run's start offset and target speed with its seeded variation, and the draw."""
    if opts.variation is None:
        return opts.start_offset, target, None
    drawn = opts.variation.draw(seed)
    offset = (opts.start_offset[0] + drawn.lateral_m, opts.start_offset[1] + drawn.heading_deg)
    if drawn.speed_factor != 1.0:
        target = (sc.hero_start.speed if target is None else target) * drawn.speed_factor
    return offset, target, drawn


def _start_pose(sc: Scenario, offset: tuple[float, float]) -> PlanarPose | None:
    """The hero start moved by ``offset = (lateral_m, heading_deg)``; None when not moved."""
    import math  # noqa: PLC0415

    lateral, heading_deg = offset
    if lateral == 0.0 and heading_deg == 0.0:
        return None
    s = sc.hero_start
    x = s.position[0] - lateral * math.sin(s.heading)
    y = s.position[1] + lateral * math.cos(s.heading)
    return PlanarPose(x, y, s.heading + math.radians(heading_deg), s.speed)


def _keep_frame(
    image: npt.NDArray[np.uint8], folder: Path, index: int, save: bool, video: _Video | None
) -> None:
    """Write a rendered frame as PNG (on request) and add it to the video (if one is made)."""
    if save:
        write_png(folder / f"{index:06d}.png", image)
    if video is not None:
        video.add(image)


def _splat_quality(ws: Workspace, run_id: str, coverage: list[float]) -> dict[str, Any]:
    """``run.json``'s ``splat_quality`` and ``splat_gate`` (:mod:`cam2sim.metrics.splat_gate`)."""
    path = ws.splat_files.eval_json
    evaluation, notes = None, []
    if not path.is_file():
        notes.append(f"{path} missing: the splat was not evaluated")
    else:
        try:
            evaluation = SplatEval.load(path)
        except Cam2SimError as err:
            notes.append(f"{path} unreadable: {err}")
    quality = path_quality(coverage, evaluation, notes=notes)
    gate = gate_run(quality)
    if not gate.fit:
        logger.warning("run %s: the splat camera fails the quality gate: %s", run_id, gate.reason)
    return {
        "splat_quality": quality.model_dump(mode="json"),
        "splat_gate": gate.model_dump(mode="json"),
    }


def iter_runs(ws: Workspace) -> Iterator[Path]:
    """The finished run folders of a workspace, oldest first (:meth:`Workspace.iter_runs`)."""
    return ws.iter_runs()
