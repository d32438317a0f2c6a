"""Stage scenario: ``WS/scenario/`` from the dataset, the map and the parked vehicles.

Writes, in one atomic folder swap:

- ``scenario.json`` (:class:`~cam2sim.scenario.model.Scenario`), the description every
  simulator backend loads;
- ``carla/``: the same in CARLA's frame, as the published tool's scripts read it
  (:mod:`cam2sim.scenario.carla_export`);
- ``scenario.xosc``: OpenSCENARIO 1.2, validated against the official schema
  (:mod:`cam2sim.scenario.openscenario`);
- ``scenario.png``: map, route, start pose, parked cars and the ones left out.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from cam2sim.core.dataset import Calibration, DatasetInfo
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.core.files import atomic_folder, file_fingerprint
from cam2sim.core.frames.rotation import euler_from_quat
from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.core.table import read_table
from cam2sim.core.trajectory import heading_from_motion
from cam2sim.core.vehicle import SteeringCalibration
from cam2sim.core.workspace import SCENARIO_FILE, Workspace, dataset_paths, hash_inputs
from cam2sim.detect.vehicles import ParkedVehicles, parked_vehicles_path
from cam2sim.report.scenario_figures import plot_scenario
from cam2sim.scenario.body import body_point_positions, vehicle_geometry
from cam2sim.scenario.calibration import PosePoint, fit_pose_point, fit_steering_calibration
from cam2sim.scenario.carla_export import write_carla_files
from cam2sim.scenario.checks import check_parked
from cam2sim.scenario.model import (
    HeroStart,
    Rejection,
    Scenario,
    ScenarioTrajectory,
    ScenarioVehicle,
)
from cam2sim.scenario.openscenario import validate_openscenario, write_openscenario
from cam2sim.stages._runner import stage_run
from cam2sim.stages.map import load_road_map

if TYPE_CHECKING:
    from pathlib import Path

    from cam2sim.detect.vehicles import ParkedVehicle
    from cam2sim.map.query import RoadMap
    from cam2sim.scenario.checks import CheckOptions
    from cam2sim.scenario.model import SizeClass

__all__ = ["ScenarioOptions", "ScenarioResult", "check_pose_point", "run_scenario", "size_class"]

logger = logging.getLogger(__name__)
STAGE = "scenario"
XOSC_FILE = "scenario.xosc"


@dataclass(frozen=True)
class ScenarioOptions:
    """What ``cam2sim scenario`` does.

    Attributes:
        heading: ``orientation`` (the recorded orientation's yaw) or ``motion`` (the direction
            of travel over ``motion_window_s``).
        motion_window_s: Centred window for headings from motion.
        keep_conflicts: Spawn parked vehicles that fail the checks anyway (still reported).
        checks: Thresholds of the parked-vehicle checks.
    """

    heading: Literal["orientation", "motion"] = "orientation"
    motion_window_s: float = 0.5
    keep_conflicts: bool = False
    checks: CheckOptions | None = None


@dataclass(frozen=True)
class ScenarioResult:
    """What the stage wrote (``scenario`` is None when it was up to date)."""

    folder: Path
    scenario: Scenario | None


def size_class(size: tuple[float, float, float]) -> SizeClass:
    """Size class of a vehicle from its length, width and height (metres)."""
    length, _, height = size
    if height > 1.9 or length > 5.3:
        return "van"
    if length >= 4.7:
        return "large"
    if length >= 4.1:
        return "medium"
    return "small"


_CONTENTS = 2
"""What a scenario records, by version: 2 added the recorded car's roll and pitch (a splat camera
leans with them). A workspace whose scenario is older builds it again on its next run."""


def _inputs(ws: Workspace, opts: ScenarioOptions) -> str:
    extract = ws.stage_record("extract")
    parked = parked_vehicles_path(ws.detections_dir)
    xodr = ws.map_xodr_path
    return hash_inputs(
        {
            "dataset": extract.inputs_hash if extract else None,
            "vehicle": ws.load_config().vehicle.model_dump(mode="json"),
            "map": file_fingerprint(xodr) if xodr.is_file() else None,
            "parked": file_fingerprint(parked) if parked.is_file() else None,
            "options": repr(opts),
            "contents": _CONTENTS,
        }
    )


def run_scenario(
    ws: Workspace,
    *,
    options: ScenarioOptions | None = None,
    force: bool = False,
    progress: ProgressCallback | None = None,
) -> ScenarioResult:
    """Build the workspace's scenario.

    Raises:
        StageError: No dataset, a dataset without poses, or no map.
        BackendUnavailableError: scenariogeneration is not installed.
    """
    opts = options or ScenarioOptions()
    report = progress or no_progress
    record = ws.stage_record("extract")
    if record is None or record.state != "done":
        msg = f"{ws.root} has no dataset; run `cam2sim extract {ws.root}` (or import) first"
        raise StageError(msg)
    if not ws.map_xodr_path.is_file():
        msg = f"{ws.root} has no map; run `cam2sim map {ws.root}` first"
        raise StageError(msg)
    inputs = _inputs(ws, opts)
    folder = ws.scenario_dir
    if not force and (folder / SCENARIO_FILE).is_file() and ws.is_up_to_date(STAGE, inputs):
        logger.info("scenario: up to date; skipping (use --force to run again)")
        return ScenarioResult(folder, None)
    config = ws.load_config()
    with stage_run(ws, STAGE, inputs_hash=inputs, config=config):
        report("scenario", 0, 4)
        scenario, conflicts, road_map = build_scenario(ws, opts)
        left_out = [v for v in _parked(ws) if v.id in conflicts and not opts.keep_conflicts]
        report("scenario", 1, 4)
        with atomic_folder(folder) as tmp:
            scenario.save(tmp / SCENARIO_FILE)
            _write_exports(ws, scenario, tmp, report)

            plot_scenario(tmp / "scenario.png", scenario, conflicts, road_map, left_out)
            report("scenario", 4, 4)
    return ScenarioResult(folder, scenario)


def _write_exports(ws: Workspace, scenario: Scenario, tmp: Path, report: ProgressCallback) -> None:
    import os  # noqa: PLC0415

    write_carla_files(scenario, tmp / "carla")
    report("scenario", 2, 4)
    xosc = tmp / XOSC_FILE
    map_rel = os.path.relpath(ws.map_xodr_path, ws.scenario_dir)
    write_openscenario(scenario, xosc, map_path=map_rel)
    errors = validate_openscenario(xosc)
    if errors:
        msg = f"the written {XOSC_FILE} does not validate: " + "; ".join(errors[:5])
        raise StageError(msg)
    report("scenario", 3, 4)


def build_scenario(
    ws: Workspace, opts: ScenarioOptions
) -> tuple[Scenario, dict[str, list[str]], RoadMap]:
    """The scenario record, the check findings by vehicle id, and the road map."""
    paths = dataset_paths(ws.dataset_dir)
    info = DatasetInfo.load(paths.dataset_json)
    calib: Calibration = Calibration.load(paths.calibration_json)
    if info.pose_less:
        msg = (
            "this dataset has no poses (images imported without them); a scenario replays the "
            "recorded drive, so import a pose CSV with the images"
        )
        raise StageError(msg)
    world = ws.world_frame()
    if world is None:
        msg = f"{ws.root} has no world frame; re-run `cam2sim extract {ws.root}`"
        raise StageError(msg)
    check_pose_point(ws)
    table = read_table(paths.poses_csv)
    stamp = table["stamp_ns"].astype(np.int64)
    ref = np.stack([table[c] for c in ("x", "y", "z")], 1).astype(np.float64)
    q = np.stack([table[c] for c in ("qx", "qy", "qz", "qw")], 1).astype(np.float64)
    euler = euler_from_quat(q)
    if opts.heading == "motion":
        heading = heading_from_motion(stamp, ref, window_s=opts.motion_window_s, min_speed_mps=0.5)
    else:
        heading = np.asarray(euler.yaw)
    geom = vehicle_geometry(ws.load_config().vehicle)
    centre = body_point_positions(ref, heading, geom.reference_xyz, (0.0, 0.0, 0.0))
    rear = body_point_positions(ref, heading, geom.reference_xyz, geom.rear_axle_xyz)
    trajectory = ScenarioTrajectory(
        heading_source=opts.heading,
        frame=tuple(int(f) for f in table["frame"]),
        stamp_ns=tuple(int(s) for s in stamp),
        t=tuple(float(v) for v in (stamp - stamp[0]) / 1e9),
        heading=tuple(float(h) for h in heading),
        speed=tuple(float(v) for v in table["speed"]),
        reference=tuple(map(tuple, ref.tolist())),
        center=tuple(map(tuple, centre.tolist())),
        rear_axle=tuple(map(tuple, rear.tolist())),
        # The recorded car's tilt, as the splat's training cameras had it: a splat camera
        # leans with the road (hills) whichever way the heading was taken.
        roll=tuple(euler.roll.tolist()),
        pitch=tuple(euler.pitch.tolist()),
    )
    road_map = load_road_map(ws)
    vehicles = _parked(ws)
    conflicts = check_parked(vehicles, centre[:, :2], geom.width_m, road_map, opts.checks)
    for vid, why in conflicts.items():
        logger.warning("parked vehicle %s: %s", vid, "; ".join(why))
    keep = [v for v in vehicles if opts.keep_conflicts or v.id not in conflicts]
    scenario = Scenario(
        map_file="map/map.xodr",
        world=world,
        vehicle=geom,
        trajectory=trajectory,
        # The map is the plan view (OpenDRIVE elevation is not evaluated): the road is z = 0.
        hero_start=HeroStart(
            position=(float(centre[0, 0]), float(centre[0, 1]), 0.0),
            heading=float(heading[0]),
            speed=float(table["speed"][0]),
        ),
        parked=tuple(_spawn(v) for v in keep),
        rejected=tuple(Rejection(id=k, reasons=tuple(v)) for k, v in sorted(conflicts.items())),
        camera=calib.camera,
        camera_mount=calib.camera_mount,
        steering_calibration=steering_calibration(ws),
    )
    return scenario, conflicts, road_map


STEERING_SIGNAL = "steering"


def steering_calibration(ws: Workspace) -> SteeringCalibration:
    """Curvature per steering unit, fitted from the recording's ``steering`` signal.

    Without such a signal or a trajectory (or with too little driving to fit), the default
    calibration (the reference drives' 0.022 1/m per unit) is used and the log says so.
    """
    paths = dataset_paths(ws.dataset_dir)
    signal = paths.signal_file(STEERING_SIGNAL)
    if not signal.is_file() or not paths.trajectory_csv.is_file():
        logger.info(
            "no '%s' signal or no trajectory: default steering calibration", STEERING_SIGNAL
        )
        return SteeringCalibration()
    s = read_table(signal)
    tr = read_table(paths.trajectory_csv)
    try:
        return fit_steering_calibration(
            s["stamp_ns"].astype(np.int64) / 1e9,
            s["value"].astype(np.float64),
            tr["stamp_ns"].astype(np.int64) / 1e9,
            np.stack([tr["x"], tr["y"]], 1).astype(np.float64),
            tr["heading"].astype(np.float64),
            tr["speed"].astype(np.float64),
        )
    except ConfigError as err:
        logger.warning("steering calibration not fitted (%s); using the default", err)
        return SteeringCalibration()


def check_pose_point(ws: Workspace) -> PosePoint | None:
    """Fit where the recorded poses sit along the car; warn when config.yaml says otherwise.

    A car posed at the wrong point cannot turn as the recorded one did (KITTI 03 with its
    camera put 1.3 m too far forward left the road at every junction run). None: no
    trajectory, a drive that turns too little to tell, or poses without orientation (their
    heading is their own direction of travel: they never slip, wherever they sit).
    """
    paths = dataset_paths(ws.dataset_dir)
    if not paths.trajectory_csv.is_file():
        return None
    if paths.dataset_json.is_file() and DatasetInfo.load(paths.dataset_json).heading_from_motion:
        return None
    tr = read_table(paths.trajectory_csv)
    fit = fit_pose_point(
        tr["stamp_ns"].astype(np.int64) / 1e9,
        np.stack([tr["x"], tr["y"]], 1).astype(np.float64),
        tr["heading"].astype(np.float64),
        tr["speed"].astype(np.float64),
    )
    vehicle = ws.load_config().vehicle
    ahead = vehicle.reference_ahead_of_rear_axle_m()
    if fit is not None and fit.disagrees_with(ahead):
        _, y, z = vehicle.reference_xyz()
        logger.warning(
            "the recorded poses turn like a point %s (%d samples in turns), but config.yaml's "
            "vehicle puts them %.2f m ahead: the simulated car will not turn as the recorded one "
            "did. Set vehicle.reference: offset and vehicle.reference_offset_m: [%.2f, %.2f, "
            "%.2f] in config.yaml (or re-import with --pose-offset fit,Y,Z) and run again",
            fit, fit.turning, ahead, vehicle.rear_axle_x_m + fit.ahead_m, y, z,
        )  # fmt: skip
    return fit


def _parked(ws: Workspace) -> list[ParkedVehicle]:
    path = parked_vehicles_path(ws.detections_dir)
    if not path.is_file():
        logger.info("no %s: the scenario has no parked vehicles (run `cam2sim detect`)", path)
        return []
    return list(ParkedVehicles.load(path).vehicles)


def _spawn(v: ParkedVehicle) -> ScenarioVehicle:
    return ScenarioVehicle(
        id=v.id,
        position=(v.position[0], v.position[1], 0.0),
        heading=v.yaw,
        size=v.size,
        size_class=size_class(v.size),
        side=v.side,
        orientation=v.orientation,
    )
