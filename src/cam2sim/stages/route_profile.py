"""The splat against the ground truth along the route, and the views at a drive's failure.

The validity envelope (:mod:`cam2sim.splat.envelope`) averages the splat's quality over a dozen
held-out frames; a closed-loop run goes wrong at one place. :func:`route_profile` renders the
splat and the ground-truth world (the ``truth`` camera, as the Real runs see it, sensor noise
included) every ``every_m`` metres along the recorded path, on it and at lateral offsets, and
scores each pair with PSNR: where along the route the splat is poor, and how fast it degrades
off the path there. Given the policy the drives use, it also asks it for its steering on both
views: the **steering gap** (splat minus truth) says where the splat makes the system under
test act differently, which PSNR alone does not (on an unseen Piedmont street the splat runs
swung 0.6 m off at 205 m where PSNR was 26-27 dB all along, and the gap peaked there: 1.2
units, the route's largest; ``docs/benchmarks.md``).

:func:`failure_views` renders the splat, the truth and the simulator camera at a run's pose
just before it failed, side by side with their PSNR against the truth.

Both need a workspace with a scenario, splat models and a ground-truth world
(``WS/truth/world.json``: the demo's and the benchmark's worlds).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Final

import numpy as np

from cam2sim.core.progress import ProgressCallback, no_progress
from cam2sim.metrics.image_quality import psnr
from cam2sim.stages.cameras import (
    TRUTH_CAMERA,
    Cameras,
    RecordedGround,
    camera_poses,
    first_decision,
    load_run_context,
    recorded_ground_at,
    run_camera,
    view_policy,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from cam2sim.core.workspace import Workspace
    from cam2sim.scenario.model import Scenario

__all__ = ["FailureViews", "RouteProfile", "failure_views", "route_profile"]

PROFILE_WIDTH: Final = 320
"""Width of the profile's renders (pixels; the height keeps the camera's aspect)."""


@dataclass(frozen=True)
class RouteProfile:
    """PSNR of the splat against the truth along the route.

    Attributes:
        s_m: ``(K,)`` stations along the recorded path (metres from its start).
        offsets_m: Lateral offsets of the camera (positive: right).
        psnr_db: ``(len(offsets_m), K)`` PSNR at each offset and station (NaN: not scored).
        steering_truth: ``(len(offsets_m), K)`` the policy's steering on the truth view (the
            recording's steering units), or None without a policy.
        steering_splat: The same on the splat view.
        policy: The policy asked, or None.
    """

    s_m: npt.NDArray[np.float64]
    offsets_m: tuple[float, ...]
    psnr_db: npt.NDArray[np.float64]
    steering_truth: npt.NDArray[np.float64] | None = None
    steering_splat: npt.NDArray[np.float64] | None = None
    policy: str | None = None

    def steering_gap(self) -> npt.NDArray[np.float64] | None:
        """``(len(offsets_m), K)`` splat minus truth steering, or None without a policy."""
        if self.steering_truth is None or self.steering_splat is None:
            return None
        gap: npt.NDArray[np.float64] = self.steering_splat - self.steering_truth
        return gap

    def at(self, s_m: float, offset_m: float = 0.0) -> float | None:
        """The PSNR at the station nearest ``s_m`` and the offset nearest ``offset_m``."""
        if self.s_m.size == 0:
            return None
        row = int(np.argmin(np.abs(np.asarray(self.offsets_m) - offset_m)))
        value = float(self.psnr_db[row, int(np.argmin(np.abs(self.s_m - s_m)))])
        return None if np.isnan(value) else value

    def to_json(self) -> dict[str, object]:
        """Plain data (NaN as null)."""

        def rows(values: npt.NDArray[np.float64], digits: int) -> list[list[float | None]]:
            return [[None if np.isnan(v) else round(float(v), digits) for v in r] for r in values]

        out: dict[str, object] = {
            "s_m": [round(float(v), 2) for v in self.s_m],
            "offsets_m": list(self.offsets_m),
            "psnr_db": rows(self.psnr_db, 2),
        }
        if self.steering_truth is not None and self.steering_splat is not None:
            out["policy"] = self.policy
            out["steering_truth"] = rows(self.steering_truth, 3)
            out["steering_splat"] = rows(self.steering_splat, 3)
        return out


@dataclass(frozen=True)
class FailureViews:
    """The cameras' views at a failed run's pose just before its failure.

    Attributes:
        image: The views side by side (splat, truth, Sim), RGB.
        labels: Their names, in order.
        psnr_db: Each view's PSNR against the truth view (None for the truth itself).
        s_m: The station of the pose along the recorded path.
    """

    image: npt.NDArray[np.uint8]
    labels: tuple[str, ...]
    psnr_db: tuple[float | None, ...]
    s_m: float


def _stations(sc: Scenario) -> npt.NDArray[np.float64]:
    ref = np.asarray(sc.trajectory.reference, dtype=np.float64)[:, :2]
    s: npt.NDArray[np.float64] = np.r_[0.0, np.cumsum(np.hypot(*np.diff(ref, axis=0).T))]
    return s


def _small(sc: Scenario) -> tuple[int, int]:
    if sc.camera is None:
        return (PROFILE_WIDTH, PROFILE_WIDTH // 2)
    cam = sc.camera.camera()
    return (PROFILE_WIDTH, max(16, round(cam.height * PROFILE_WIDTH / cam.width)))


def _pose(
    sc: Scenario, xy: npt.NDArray[np.float64], heading: float, lateral_m: float, *, splat: bool
) -> npt.NDArray[np.float64]:
    """The camera pose of the vehicle at reference point ``xy``, moved ``lateral_m`` right."""
    right = np.array([np.sin(heading), -np.cos(heading)])
    at = xy + lateral_m * right
    ground = recorded_ground_at(sc, at) if splat else RecordedGround(0.0)
    z = sc.vehicle.reference_xyz[2] + ground.z
    pose: npt.NDArray[np.float64] = camera_poses(
        sc, at[None, :], np.array([heading]), np.array([z]), roll=ground.roll, pitch=ground.pitch
    )[0]
    return pose


def route_profile(
    ws: Workspace,
    *,
    every_m: float = 10.0,
    offsets_m: Sequence[float] = (-1.0, 0.0, 1.0),
    policy: str | None = None,
    progress: ProgressCallback = no_progress,
) -> RouteProfile:
    """Score the splat against the truth every ``every_m`` along the recorded path.

    Args:
        ws: The workspace.
        every_m: Station spacing, metres.
        offsets_m: Lateral offsets of the camera (positive: right).
        policy: A policy spec (:func:`cam2sim.ads.policy.load_policy`, e.g. the workspace's
            ``ads/dave2.onnx``) to ask for its steering on both views; None: PSNR only.
        progress: Receives the renders' task.

    Raises:
        StageError: No scenario, no splat models or no ground-truth world in ``ws``.
    """
    ctx = load_run_context(ws)
    sc = ctx.scenario
    s_all = _stations(sc)
    stations = np.arange(0.0, float(s_all[-1]) + 1e-9, every_m)
    idx = np.minimum(np.searchsorted(s_all, stations), len(s_all) - 1)
    ref = np.asarray(sc.trajectory.reference, dtype=np.float64)[:, :2]
    heading = np.asarray(sc.trajectory.heading, dtype=np.float64)
    camera = run_camera(sc, _small(sc))
    out = np.full((len(offsets_m), len(idx)), np.nan)
    steer = np.full((2, *out.shape), np.nan) if policy is not None else None
    asked = None
    if policy is not None:
        asked = view_policy(policy, sc)
    total = out.size
    try:
        with Cameras(ctx, ("splat", TRUTH_CAMERA)) as cams:
            for r, lateral in enumerate(offsets_m):
                for k, i in enumerate(idx.tolist()):
                    truth = cams.render(
                        TRUTH_CAMERA, _pose(sc, ref[i], heading[i], lateral, splat=False), camera
                    )
                    splat = cams.render(
                        "splat", _pose(sc, ref[i], heading[i], lateral, splat=True), camera
                    )
                    value = psnr(truth, splat)
                    out[r, k] = np.nan if value is None else value
                    if asked is not None and steer is not None:
                        at = (float(ref[i, 0]), float(ref[i, 1]))
                        steer[:, r, k] = (
                            first_decision(asked, truth, at, float(heading[i])),
                            first_decision(asked, splat, at, float(heading[i])),
                        )
                    progress("splat vs truth along the route", r * len(idx) + k + 1, total)
    finally:
        if asked is not None:
            asked.close()
    return RouteProfile(
        s_m=s_all[idx],
        offsets_m=tuple(float(v) for v in offsets_m),
        psnr_db=out,
        steering_truth=None if steer is None else steer[0],
        steering_splat=None if steer is None else steer[1],
        policy=policy,
    )


def failure_views(
    ws: Workspace, xy: Sequence[float], heading: float, *, cameras: Sequence[str]
) -> FailureViews:
    """Render ``cameras`` (e.g. splat, truth, raster) at the vehicle pose ``(xy, heading)``.

    Raises:
        StageError: A camera cannot open (no splat models, no ground-truth world).
    """
    from cam2sim.stages.runs import side_by_side  # noqa: PLC0415 -- lazy: imports cv2

    ctx = load_run_context(ws)
    sc = ctx.scenario
    camera = run_camera(sc, _small(sc))
    at = np.asarray(xy, dtype=np.float64)
    names = tuple(cameras)
    with Cameras(ctx, names) as cams:
        views = [
            cams.render(n, _pose(sc, at, heading, 0.0, splat=n == "splat"), camera) for n in names
        ]
    truth = views[names.index(TRUTH_CAMERA)] if TRUTH_CAMERA in names else None
    scores = tuple(
        None if n == TRUTH_CAMERA or truth is None else psnr(truth, v)
        for n, v in zip(names, views, strict=True)
    )
    ref = np.asarray(sc.trajectory.reference, dtype=np.float64)[:, :2]
    s_m = float(_stations(sc)[int(np.argmin(np.hypot(*(ref - at).T)))])
    captions = [
        n if v is None else f"{n}: {v:.1f} dB vs truth" for n, v in zip(names, scores, strict=True)
    ]
    return FailureViews(
        image=side_by_side([_captioned(v, c) for v, c in zip(views, captions, strict=True)]),
        labels=names,
        psnr_db=scores,
        s_m=s_m,
    )


def _captioned(image: npt.NDArray[np.uint8], text: str) -> npt.NDArray[np.uint8]:
    """``image`` with ``text`` written in its top-left corner (white on a dark band)."""
    import cv2  # noqa: PLC0415

    out = image.copy()
    scale = max(0.35, image.shape[1] / 900.0)
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    out[: h + base + 6, : w + 8] = (out[: h + base + 6, : w + 8] * 0.35).astype(np.uint8)
    cv2.putText(out, text, (4, h + 3), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1,
                cv2.LINE_AA)  # fmt: skip
    return out
