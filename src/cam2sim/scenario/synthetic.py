"""A synthetic street scenario (map + scenario record) for tests, benchmarks and demos.

A two-way street, straight or turning left on a constant-radius arc, with a driving lane, a
parking lane and a sidewalk on each side (OpenDRIVE 1.4 text), and a recorded drive along the
centre of the right driving lane at constant speed. Parked cars are given by station along the
route and lateral offset from it (positive to the left).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cam2sim.core import frames as fr
from cam2sim.core.config import VehicleConfig
from cam2sim.core.dataset import CameraIntrinsics, MountRecord
from cam2sim.core.workspace import WorldFrameRecord
from cam2sim.scenario.body import body_point_positions, vehicle_geometry
from cam2sim.scenario.model import HeroStart, Scenario, ScenarioTrajectory, ScenarioVehicle

__all__ = ["StreetSpec", "lane_section_xml", "synthetic_street"]


def lane_section_xml(lane_m: float = 3.5, parking_m: float = 2.5, sidewalk_m: float = 2.0) -> str:
    """OpenDRIVE lanes of a two-way street: driving, parking and sidewalk lanes on each side."""
    side = [("sidewalk", sidewalk_m), ("parking", parking_m), ("driving", lane_m)]

    def lane(lane_id: int, kind: str, width: float) -> str:
        w = f'<width sOffset="0" a="{width}" b="0" c="0" d="0"/>'
        return f'        <lane id="{lane_id}" type="{kind}">{w}</lane>\n'

    left = "".join(lane(3 - k, kind, w) for k, (kind, w) in enumerate(side))
    right = "".join(lane(-1 - k, kind, w) for k, (kind, w) in enumerate(reversed(side)))
    return (
        f"\n      <left>\n{left}      </left>\n"
        '      <center><lane id="0" type="none"/></center>\n'
        f"      <right>\n{right}      </right>"
    )


@dataclass(frozen=True)
class StreetSpec:
    """The street and the drive.

    Attributes:
        length_m: Route length.
        radius_m: Radius of the left turn of the route; None for a straight street.
        speed_mps: Recorded speed.
        rate_hz: Recorded samples per second.
        parked: ``(station_m, lateral_m, yaw_offset_rad)`` of each parked car, relative to the
            route (lateral positive to the left; yaw relative to the route's direction).
        lead_m: Road before the route's start and after its end.
    """

    length_m: float = 80.0
    radius_m: float | None = None
    speed_mps: float = 8.0
    rate_hz: float = 10.0
    parked: tuple[tuple[float, float, float], ...] = ((30.0, -4.75, 0.0),)
    lead_m: float = 20.0


def _route(spec: StreetSpec, s: np.ndarray, lateral: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``(N, 2)`` and headings of points at station ``s``, ``lateral`` to the left."""
    if spec.radius_m is None:
        xy = np.column_stack([s, np.full_like(s, lateral)])
        return xy, np.zeros_like(s)
    r = spec.radius_m
    th = s / r
    xy = np.column_stack([(r - lateral) * np.sin(th), r - (r - lateral) * np.cos(th)])
    return xy, th


def _xodr(spec: StreetSpec) -> str:
    total = spec.length_m + 2 * spec.lead_m
    # The reference line runs 1.75 m left of the route (between the two driving lanes).
    if spec.radius_m is None:
        geometry = (
            f'<geometry s="0" x="{-spec.lead_m}" y="1.75" hdg="0" length="{total}"><line/>'
            "</geometry>"
        )
    else:
        r_ref = spec.radius_m - 1.75
        th0 = -spec.lead_m / spec.radius_m
        x0 = r_ref * math.sin(th0)
        y0 = spec.radius_m - r_ref * math.cos(th0)
        length = total * r_ref / spec.radius_m
        geometry = (
            f'<geometry s="0" x="{x0}" y="{y0}" hdg="{th0}" length="{length}">'
            f'<arc curvature="{1.0 / r_ref}"/></geometry>'
        )
        total = length
    return f"""<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="4"/>
  <road name="street" length="{total}" id="1" junction="-1">
    <planView>{geometry}</planView>
    <lanes><laneSection s="0">{lane_section_xml()}
    </laneSection></lanes>
  </road>
</OpenDRIVE>
"""


def synthetic_street(spec: StreetSpec | None = None) -> tuple[Scenario, str]:
    """A :class:`~cam2sim.scenario.model.Scenario` and its OpenDRIVE map text.

    The recorded reference point is the rear axle (the default vehicle); the camera is an
    800x503 pinhole 1.4 m up, 1.6 m ahead of the rear axle, looking forward.
    """
    spec = spec or StreetSpec()
    geom = vehicle_geometry(VehicleConfig())
    n = int(spec.length_m / spec.speed_mps * spec.rate_hz) + 1
    t = np.arange(n) / spec.rate_hz
    s = spec.speed_mps * t
    xy, heading = _route(spec, s)
    ref = np.column_stack([xy, np.zeros(n)])
    centre = body_point_positions(ref, heading, geom.reference_xyz, (0.0, 0.0, 0.0))
    rows = [tuple(map(float, p)) for p in ref]
    traj = ScenarioTrajectory(
        heading_source="orientation",
        frame=tuple(range(n)),
        stamp_ns=tuple(int(v * 1e9) for v in t),
        t=tuple(float(v) for v in t),
        heading=tuple(float(v) for v in heading),
        speed=(spec.speed_mps,) * n,
        reference=tuple(rows),
        center=tuple(tuple(map(float, p)) for p in centre),
        rear_axle=tuple(rows),
    )
    parked = []
    for k, (station, lateral, yaw_off) in enumerate(spec.parked):
        pxy, ph = _route(spec, np.array([station]), lateral)
        parked.append(
            ScenarioVehicle(
                id=f"pv_{k:03d}",
                position=(float(pxy[0, 0]), float(pxy[0, 1]), 0.0),
                heading=float(ph[0] + yaw_off),
                size=(4.5, 1.8, 1.5),
                size_class="medium",
                side="left" if lateral > 0 else "right",
                orientation="parallel",
            )
        )
    # Camera: optical axes (x right, y down, z forward) = body (x fwd, y left, z up) turned.
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    q = fr.quat_from_matrix(R)
    scenario = Scenario(
        map_file="map/map.xodr",
        world=WorldFrameRecord(proj_string=None),
        vehicle=geom,
        trajectory=traj,
        hero_start=HeroStart(
            position=(float(centre[0, 0]), float(centre[0, 1]), 0.0),
            heading=float(heading[0]),
            speed=spec.speed_mps,
        ),
        parked=tuple(parked),
        camera=CameraIntrinsics(
            width=800,
            height=503,
            K=((640.0, 0.0, 399.5), (0.0, 640.0, 251.0), (0.0, 0.0, 1.0)),
            source="config",
        ),
        camera_mount=MountRecord(
            translation_m=(1.6, 0.0, 1.4),
            quat_xyzw=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
            axes="optical",
            source="config",
        ),
    )
    return scenario, _xodr(spec)
