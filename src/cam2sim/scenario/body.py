"""The recorded trajectory at the vehicle's body points.

The recorded pose is one point of the car (its ``reference``: usually the rear axle, ROS
``base_link``). A simulator places a vehicle by another point: CARLA by its centre, OpenSCENARIO
by its rear axle. Every point follows from the reference with the vehicle geometry and the
heading, once, here: ``p = reference + R(heading) @ (point - reference_xyz)`` in the vehicle
frame (x forward, y left, z up; origin at the footprint centre on the ground). The offset is
turned by the heading only (the car is placed upright on the road; recorded roll and pitch are
not applied), so all three points share the heading and keep the configured distances exactly.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from cam2sim.scenario.model import VehicleGeometry

if TYPE_CHECKING:
    import numpy.typing as npt

    from cam2sim.core.config import VehicleConfig

__all__ = ["body_point_positions", "vehicle_geometry"]


def vehicle_geometry(cfg: VehicleConfig) -> VehicleGeometry:
    """The scenario's vehicle record from the config's ``vehicle`` block."""
    return VehicleGeometry(
        length_m=cfg.length_m,
        width_m=cfg.width_m,
        height_m=cfg.height_m,
        wheelbase_m=cfg.wheelbase_m,
        reference_xyz=cfg.reference_xyz(),
        rear_axle_xyz=(cfg.rear_axle_x_m, 0.0, 0.0),
    )


def body_point_positions(
    reference: npt.ArrayLike,
    heading: npt.ArrayLike,
    reference_xyz: tuple[float, float, float],
    point_xyz: tuple[float, float, float],
) -> npt.NDArray[np.float64]:
    """Positions of a body point given the recorded reference point's positions.

    Args:
        reference: ``(N, 3)`` world positions of the recorded reference point, metres.
        heading: ``(N,)`` vehicle headings, radians.
        reference_xyz: The reference point in the vehicle frame.
        point_xyz: The wanted point in the vehicle frame.

    Returns:
        ``(N, 3)`` world positions of the point.
    """
    ref = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    h = np.asarray(heading, dtype=np.float64).reshape(-1)
    d = np.asarray(point_xyz, dtype=np.float64) - np.asarray(reference_xyz, dtype=np.float64)
    c, s = np.cos(h), np.sin(h)
    out = ref.copy()
    out[:, 0] += c * d[0] - s * d[1]
    out[:, 1] += s * d[0] + c * d[1]
    out[:, 2] += d[2]
    return out
