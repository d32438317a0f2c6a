"""A 400 m residential route as a prepared splat scene: the 1,500-frame speed figure of issue 4.

Builds a ~400 m street (straight, a left bend, straight, a right bend, straight; a driving,
parking and sidewalk lane each way; cars parked on both sides; buildings on both sidewalks) in
the demo's frame (UTM 32N at the demo's origin), drives it on the right lane with the demo
driver's weave, renders a frame every ``--spacing`` metres with the truth camera's pipeline
(raster renderer + the photographic look with per-pose sensor noise, JPEG as a recording has
it) and ray-casts the demo's 16-beam LiDAR every ``--lidar-every`` metres. It writes what
``cam2sim splat`` preparation would (``scene.json``, ``images/``, ``sky/``, ``points.npz``;
also ``truth_world.json`` and a summary ``route.json``) straight into ``--out``:

* frames: the rendered poses (the recording's metric poses), every 8th held out, chunks along
  the route by distance with overlap (:func:`cam2sim.splat.geometry.chunks_by_distance`);
* masks: no ``masks/`` (the synthetic camera has no hood; the trainer then uses every pixel);
  sky masks by the classical fallback (:func:`cam2sim.splat.masks.sky_mask_classical`), as
  preparation without SegFormer;
* points: the LiDAR scans (range <= ``--max-range``) in the world frame, coloured from the
  nearest frame and voxel-downsampled (``--voxel``), as preparation does with a recording's
  LiDAR, plus SIFT points triangulated with the known poses from the training frames (not the
  held-out ones) as preparation's :func:`~cam2sim.splat.sfm.triangulate_known_poses` does
  (``--no-triangulate`` to leave them out). ``points.npz`` is compressed and ``scene.json`` compact,
  and the images are JPEG at ``--quality`` 75, so that the folder (about 31 MiB for 1,500
  frames) fits the 64 MiB a GPU call carries.

The trainer reads PNG images; ``benchmarks/splat_gpu.py --resize WxH`` (the same size is fine)
writes them. Usage (docs/benchmarks.md has the full GPU command)::

    PYTHONPATH=src python benchmarks/splat_route.py --out .carry/route400
    PYTHONPATH=src python benchmarks/splat_gpu.py --prep .carry/route400 --resize 480x300 ...
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from cam2sim.core.camera import PinholeCamera
from cam2sim.core.frames import Pose
from cam2sim.demo.lidar import LidarModel, scan_scene
from cam2sim.demo.route import PiecewiseRoute
from cam2sim.demo.world import (
    CRS,
    L_STREET,
    ORIGIN_UTM,
    DemoStreet,
    footprint_ring,
    street_xodr,
)
from cam2sim.render.truth import TruthBuilding, TruthCar, TruthLook, TruthRenderer, TruthWorld
from cam2sim.splat.geometry import chunk_membership, chunks_by_distance, voxel_downsample
from cam2sim.splat.masks import sky_mask_classical
from cam2sim.splat.prepare import colour_from_view
from cam2sim.splat.scene import FrameRecord, SceneRecord
from cam2sim.splat.sfm import FeatureOptions, KnownView, triangulate_known_poses

if TYPE_CHECKING:
    import numpy.typing as npt


LANE_M = 3.5
PARKING_M = 2.5
SIDEWALK_M = 2.0
LEAD_M = 30.0
CAMERA_MOUNT = (1.6, 0.0, 1.4)
LIDAR_MOUNT = (1.0, 0.0, 1.9)
# Optical camera axes (x right, y down, z forward) in the body frame (x forward, y left, z up).
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
# The route: (length m, curvature 1/m, positive left) pieces, starting at the origin heading east.
PIECES: tuple[tuple[float, float], ...] = (
    (110.0, 0.0),
    (40.0 * math.pi / 2.0, 1.0 / 40.0),
    (90.0, 0.0),
    (50.0 * math.pi / 3.0, -1.0 / 50.0),
    (85.0, 0.0),
)
SPEED_MPS = 8.0
HELD_OUT_EVERY = 8


def route_xodr(route: PiecewiseRoute) -> str:
    """OpenDRIVE text; the reference line runs between the driving lanes (half a lane left)."""
    street = DemoStreet(
        name="route400", title="the 400 m route", route=route, lane_m=LANE_M,
        parking_m=PARKING_M, sidewalk_m=SIDEWALK_M, lead_m=LEAD_M,
    )  # fmt: skip
    return street_xodr(street, "Routenstraße")


def _cars(route: PiecewiseRoute, rng: np.random.Generator) -> list[dict[str, Any]]:
    right = -LANE_M / 2.0 - PARKING_M / 2.0
    left = LANE_M / 2.0 + LANE_M + PARKING_M / 2.0
    out: list[dict[str, Any]] = []
    for lateral, side in ((right, "right"), (left, "left")):
        s = -LEAD_M + 3.0 + rng.uniform(0.0, 2.0)
        while s < route.length_m + LEAD_M - 8.0:
            length = rng.uniform(4.0, 4.8)
            if not route.in_bend(s + length / 2.0, 8.0)[0] and rng.random() < 0.65:
                xy, heading = route.points([s + length / 2.0], lateral)
                flip = math.pi if side == "left" and rng.random() < 0.5 else 0.0
                out.append(
                    {
                        "x": float(xy[0, 0]),
                        "y": float(xy[0, 1]),
                        "yaw": float(heading[0] + flip + rng.normal(0.0, 0.02)),
                        "length": float(length),
                        "width": float(rng.uniform(1.75, 1.9)),
                        "height": float(rng.uniform(1.45, 1.6)),
                        "side": side,
                    }
                )
            s += length + rng.uniform(1.0, 3.0)
    return out


def _buildings(route: PiecewiseRoute, rng: np.random.Generator) -> list[dict[str, Any]]:
    kerb = LANE_M + PARKING_M + SIDEWALK_M
    length, depth, setback = 16.0, 10.0, 1.5
    out: list[dict[str, Any]] = []
    for sign in (1.0, -1.0):
        lateral = LANE_M / 2.0 + sign * (kerb + setback + depth / 2.0)
        for s in np.arange(-LEAD_M + 10.0, route.length_m + LEAD_M - 8.0, 21.0):
            if route.in_bend(float(s), 12.0)[0]:
                continue  # the bends stay open (no overlapping footprints)
            c, h = route.points([s], lateral)
            out.append(
                {
                    "xy": footprint_ring(c[0], float(h[0]), length, depth),
                    "height_m": 3.0 * int(rng.integers(2, 6)),
                }
            )
    return out


def build_world(route: PiecewiseRoute, seed: int) -> TruthWorld:
    """The route's street, parked cars and buildings as a truth world (photographic look)."""

    rng = np.random.default_rng(seed)
    return TruthWorld(
        crs=CRS,
        origin=ORIGIN_UTM,
        xodr=route_xodr(route),
        cars=tuple(TruthCar(**c) for c in _cars(route, rng)),
        buildings=tuple(TruthBuilding(**b) for b in _buildings(route, rng)),
        look=TruthLook(kind="photographic", seed=seed),
    )


def drive(route: PiecewiseRoute, s: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """``(N, 4, 4)`` body poses (x forward, z up) on the driven path (route plus weave)."""
    weave = L_STREET.weave  # the demo driver's weave
    xy, _ = route.points(s, weave(s))
    a, _ = route.points(s - 0.01, weave(s - 0.01))
    b, _ = route.points(s + 0.01, weave(s + 0.01))
    heading = np.arctan2(b[:, 1] - a[:, 1], b[:, 0] - a[:, 0])
    out = np.tile(np.eye(4), (len(s), 1, 1))
    c, sn = np.cos(heading), np.sin(heading)
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1] = c, -sn, sn, c
    out[:, :2, 3] = xy
    return out


def render_frames(
    args: argparse.Namespace, world: TruthWorld, poses: npt.NDArray[np.float64], K: Any
) -> list[npt.NDArray[np.uint8]]:
    """Render, look and JPEG-encode every frame into ``out/images``; sky masks into ``out/sky``."""

    out = Path(args.out)
    lens = PinholeCamera.from_K(K, args.width, args.height)
    decoded = []
    t0 = time.perf_counter()
    with TruthRenderer(world, None) as camera:
        for i, pose in enumerate(poses):
            rgb = camera.render(pose, lens).rgb
            ok, jpeg = cv2.imencode(
                ".jpg",
                cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                [cv2.IMWRITE_JPEG_QUALITY, args.quality],
            )
            if not ok:
                msg = f"JPEG encoding failed at frame {i}"
                raise RuntimeError(msg)
            (out / "images" / f"{i:06d}.jpg").write_bytes(jpeg.tobytes())
            image = cv2.cvtColor(cv2.imdecode(jpeg, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
            sky = sky_mask_classical(image)
            cv2.imwrite(str(out / "sky" / f"{i:06d}.png"), np.where(sky, 255, 0).astype(np.uint8))
            decoded.append(image)
            if i % 100 == 0:
                print(f"frame {i}/{len(poses)} {time.perf_counter() - t0:.0f} s", flush=True)
    return decoded


def lidar_points(
    args: argparse.Namespace,
    world: TruthWorld,
    route: PiecewiseRoute,
    frame_s: npt.NDArray[np.float64],
    cams: npt.NDArray[np.float64],
    K: Any,
    images: list[npt.NDArray[np.uint8]],
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8]]:
    """Ray-cast scans along the drive, in the world frame, coloured, voxel-downsampled."""

    scene = world.lidar_scene()
    lidar = LidarModel(beams=16, azimuths=720)
    stations = np.arange(0.0, route.length_m, args.lidar_every)
    xyz_all, rgb_all = [np.zeros((0, 3))], [np.zeros((0, 3), np.uint8)]
    for i, body in enumerate(drive(route, stations)):
        position = body[:3, :3] @ np.asarray(LIDAR_MOUNT) + body[:3, 3]
        yaw = math.atan2(body[1, 0], body[0, 0])
        q = np.array([0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)])
        local = scan_scene(scene, Pose(position, q), lidar=lidar, seed=i).points[:, :3]
        reach = np.linalg.norm(local, axis=1)
        local = local[(reach > 1.0) & (reach <= args.max_range)].astype(np.float64)
        world_xyz = local @ body[:3, :3].T + position
        j = int(np.argmin(np.abs(frame_s - stations[i])))
        rgb = colour_from_view(world_xyz, cams[j], K, images[j])
        xyz_d, rgb_d = voxel_downsample(world_xyz, rgb, args.voxel)
        xyz_all.append(xyz_d)
        rgb_all.append(rgb_d)
    return voxel_downsample(np.concatenate(xyz_all), np.concatenate(rgb_all), args.voxel)


def triangulated_points(
    out: Path, cams: npt.NDArray[np.float64], K: npt.NDArray[np.float64], train: list[int]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.uint8]]:
    """SIFT points of the training frames triangulated with their known poses (pycolmap)."""
    result = triangulate_known_poses(
        [out / "images" / f"{i:06d}.jpg" for i in train],
        [KnownView(K, cams[i]) for i in train],
        window=20,
        features=FeatureOptions(window=20, first_octave=0),  # preparation's settings
    )
    print(
        f"triangulated {len(result.points)} points "
        f"({result.mean_reprojection_error_px:.2f} px mean error)",
        flush=True,
    )
    return result.points.xyz, result.points.rgb


def _parser() -> argparse.ArgumentParser:
    """The command line."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", required=True, help="prepared scene folder to write")
    parser.add_argument("--frames", type=int, default=1500)
    parser.add_argument("--spacing", type=float, default=0.27, help="metres between frames")
    parser.add_argument("--width", type=int, default=480)
    parser.add_argument("--height", type=int, default=300)
    parser.add_argument("--focal", type=float, default=300.0)
    parser.add_argument("--quality", type=int, default=75, help="JPEG quality")
    parser.add_argument("--lidar-every", type=float, default=1.6, help="metres between scans")
    parser.add_argument("--voxel", type=float, default=0.25, help="LiDAR voxel edge, metres")
    parser.add_argument("--max-range", type=float, default=30.0, help="LiDAR returns kept, m")
    parser.add_argument("--chunk-length", type=float, default=117.0)
    parser.add_argument("--overlap", type=float, default=20.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--no-triangulate", action="store_true", help="LiDAR points only (no SIFT points)"
    )
    return parser


def main() -> int:
    """Build the world, render, scan and write the prepared scene."""

    args = _parser().parse_args()

    t0 = time.perf_counter()
    route = PiecewiseRoute(PIECES)
    world = build_world(route, args.seed)
    out = Path(args.out)
    if out.exists():
        shutil.rmtree(out)
    for sub in ("images", "sky"):
        (out / sub).mkdir(parents=True)
    world.save(out / "truth_world.json")
    frame_s = args.spacing * np.arange(args.frames)
    mount = np.eye(4)
    mount[:3, :3] = R_BODY_OPTICAL
    mount[:3, 3] = CAMERA_MOUNT
    cams = drive(route, frame_s) @ mount
    w, h = args.width, args.height
    K = np.array([[args.focal, 0.0, w / 2.0], [0.0, args.focal, h / 2.0], [0.0, 0.0, 1.0]])
    images = render_frames(args, world, cams, K)
    t_render = time.perf_counter() - t0
    xyz, rgb = lidar_points(args, world, route, frame_s, cams, K, images)
    t_lidar = time.perf_counter() - t0 - t_render
    source = np.ones(len(xyz), np.uint8)  # save_points's codes: 1 = LiDAR, 0 = triangulated
    if not args.no_triangulate:
        train = [i for i in range(args.frames) if i % HELD_OUT_EVERY != 0]
        tri_xyz, tri_rgb = triangulated_points(out, cams, K, train)
        xyz, rgb = np.concatenate((xyz, tri_xyz)), np.concatenate((rgb, tri_rgb))
        source = np.concatenate((source, np.zeros(len(tri_xyz), np.uint8)))
    n_triangulated = int((source == 0).sum())
    t_triangulate = time.perf_counter() - t0 - t_render - t_lidar
    # save_points's layout, compressed (np.load reads both)
    np.savez_compressed(out / "points.npz", xyz=xyz.astype(np.float32), rgb=rgb, source=source)
    chunks = chunks_by_distance(
        frame_s, cams[:, :3, 3], chunk_length_m=args.chunk_length, overlap_m=args.overlap
    )
    member = chunk_membership(chunks)
    frames = [
        FrameRecord(
            index=i,
            dataset_frame=i,
            stamp_ns=round(1e9 * frame_s[i] / SPEED_MPS),
            T_world_cam=cams[i].tolist(),
            fx=float(K[0, 0]),
            fy=float(K[1, 1]),
            cx=float(K[0, 2]),
            cy=float(K[1, 2]),
            width=w,
            height=h,
            held_out=i % HELD_OUT_EVERY == 0,
            chunks=member.get(i, []),
            progress_m=float(frame_s[i]),
        )
        for i in range(args.frames)
    ]
    note = (
        f"benchmarks/splat_route.py: {route.length_m:.0f} m route, {len(world.cars)} parked cars, "
        f"{len(world.buildings)} buildings; LiDAR every {args.lidar_every} m, "
        f"{args.voxel} m voxels; {n_triangulated} triangulated points"
    )
    notes = [note]
    record = SceneRecord(frames=frames, chunks=chunks, pose_source="recording", notes=notes)
    (out / "scene.json").write_text(record.model_dump_json() + "\n")  # compact: it travels
    size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    summary = {
        "route_m": route.length_m,
        "driven_m": float(frame_s[-1]),
        "frames": args.frames,
        "held_out": sum(f.held_out for f in frames),
        "size": [w, h],
        "cars": len(world.cars),
        "buildings": len(world.buildings),
        "points": len(xyz),
        "triangulated_points": n_triangulated,
        "chunks": [
            {"id": c.id, "start_m": c.start_m, "end_m": c.end_m, "frames": len(c.frames)}
            for c in chunks
        ],
        "render_s": t_render,
        "lidar_s": t_lidar,
        "triangulation_s": t_triangulate,
        "total_s": time.perf_counter() - t0,
        "folder_mib": size / 2**20,
    }
    (out / "route.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
