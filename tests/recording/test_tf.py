"""The /tf tree: chains between frames, composed and interpolated, and their errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cam2sim.core import frames
from cam2sim.core.errors import RecordingError
from cam2sim.recording.bag import Recording
from cam2sim.recording.bagwriter import BagWriter
from cam2sim.recording.tf import TfTree

T0 = 1_700_000_000_000_000_000
STEP_NS = 50_000_000  # odom -> base_link at 20 Hz
N = 41  # 2 s
ODOM_NS = T0 + STEP_NS * np.arange(N, dtype=np.int64)
MAP_ODOM_NS = ODOM_NS[::10]  # map -> odom at 2 Hz, on a subset of the odom stamps

R_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
T_BASE_CAMLINK = frames.Pose.from_xyz_rpy([1.5, 0.1, 1.2], [0.0, math.radians(5.0), 0.0])
T_CAMLINK_OPTICAL = frames.Pose(np.zeros(3), frames.quat_from_matrix(R_LINK_OPTICAL))
T_BASE_LIDAR = frames.Pose.from_xyz_rpy([0.3, 0.0, 1.8], [0.0, 0.0, math.radians(-2.0)])


def _t(stamp_ns: np.ndarray) -> np.ndarray:
    return (np.asarray(stamp_ns) - T0) / 1e9


def map_odom(stamp_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slowly drifting map -> odom: linear translation, yaw linear in time."""
    t = _t(stamp_ns)
    pos = np.stack([100.0 + 0.02 * t, 200.0 - 0.01 * t, np.full_like(t, 0.5)], -1)
    return pos, frames.quat_from_yaw(math.radians(30.0) + 0.01 * t)


def odom_base(stamp_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A car on an arc: 5 m/s, turning at 0.3 rad/s."""
    t = _t(stamp_ns)
    yaw = 0.3 * t
    pos = np.stack([5 / 0.3 * np.sin(yaw), 5 / 0.3 * (1 - np.cos(yaw)), np.zeros_like(t)], -1)
    return pos, frames.quat_from_yaw(yaw)


def _transform(parent: str, child: str, stamp: int, pos: np.ndarray, quat: np.ndarray) -> dict:
    return {
        "header": {"stamp": int(stamp), "frame_id": parent},
        "child_frame_id": child,
        "transform": {
            "translation": dict(zip("xyz", pos.tolist(), strict=True)),
            "rotation": dict(zip("xyzw", quat.tolist(), strict=True)),
        },
    }


def _static(parent: str, child: str, pose: frames.Pose) -> dict:
    return _transform(parent, child, T0, pose.position, pose.quat)


def write_tf_bag(path: Path, *, extra_static: list[dict] | None = None) -> Path:
    tf_msg = "tf2_msgs/msg/TFMessage"
    mo_pos, mo_q = map_odom(MAP_ODOM_NS)
    ob_pos, ob_q = odom_base(ODOM_NS)
    with BagWriter(path, "mcap") as w:
        statics = [
            _static("base_link", "camera_link", T_BASE_CAMLINK),
            _static("camera_link", "camera_optical", T_CAMLINK_OPTICAL),
            _static("/base_link", "lidar_link", T_BASE_LIDAR),  # a leading slash is ignored
            *(extra_static or []),
        ]
        w.write_fields("/tf_static", tf_msg, {"transforms": statics}, receive_ns=T0)
        for i, stamp in enumerate(ODOM_NS):
            transforms = [_transform("odom", "base_link", stamp, ob_pos[i], ob_q[i])]
            if i % 10 == 0:  # MAP_ODOM_NS = ODOM_NS[::10]
                j = i // 10
                transforms.append(_transform("map", "odom", stamp, mo_pos[j], mo_q[j]))
            w.write_fields("/tf", tf_msg, {"transforms": transforms}, receive_ns=int(stamp) + 1)
    return path


def load_tree(path: Path) -> TfTree:
    tree = TfTree()
    with Recording([path]) as rec:
        tree.add_messages(rec.messages(["/tf", "/tf_static"]), static_topics={"/tf_static"})
    return tree


def _compose(
    a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    (pa, qa), (pb, qb) = a, b
    return pa + frames.quat_rotate(qa, pb), frames.quat_multiply(qa, qb)


@pytest.fixture
def tree(tmp_path: Path) -> TfTree:
    return load_tree(write_tf_bag(tmp_path / "tf"))


def test_tf_chain_composes_dynamic_edges_at_their_stamps(tree: TfTree) -> None:
    chain = tree.chain("map", "base_link")
    assert not chain.static
    np.testing.assert_array_equal(chain.stamp_ns, ODOM_NS)
    want_pos, want_q = _compose(map_odom(ODOM_NS), odom_base(ODOM_NS))
    assert np.abs(chain.position - want_pos).max() < 1e-9
    assert frames.quat_angle_between(chain.quat, want_q).max() < 1e-9


def test_tf_chain_composes_dynamic_and_static_edges(tree: TfTree) -> None:
    chain = tree.chain("/map", "camera_optical")
    base = _compose(map_odom(ODOM_NS), odom_base(ODOM_NS))
    T_base_opt = T_BASE_CAMLINK @ T_CAMLINK_OPTICAL
    want_pos, want_q = _compose(base, (T_base_opt.position, T_base_opt.quat))
    assert np.abs(chain.position - want_pos).max() < 1e-9
    assert frames.quat_angle_between(chain.quat, want_q).max() < 1e-9


def test_tf_chain_between_leaves_sharing_a_parent_is_static_and_exact(tree: TfTree) -> None:
    chain = tree.chain("camera_optical", "lidar_link")
    assert chain.static
    want = (T_BASE_CAMLINK @ T_CAMLINK_OPTICAL).inverse() @ T_BASE_LIDAR
    assert np.abs(chain.position[0] - want.position).max() < 1e-12
    assert frames.quat_angle_between(chain.quat[0], want.quat) < 1e-9


def test_tf_chain_in_both_directions_are_inverse(tree: TfTree) -> None:
    a_b = tree.static_transform("camera_optical", "lidar_link")
    b_a = tree.static_transform("lidar_link", "camera_optical")
    identity = a_b @ b_a
    assert np.abs(identity.position).max() < 1e-12
    assert frames.quat_angle_between(identity.quat, [0.0, 0.0, 0.0, 1.0]) < 1e-9
    # The dynamic chain too, sample by sample.
    fwd = tree.chain("map", "base_link")
    back = tree.chain("base_link", "map")
    np.testing.assert_array_equal(fwd.stamp_ns, back.stamp_ns)
    pos, quat = _compose((fwd.position, fwd.quat), (back.position, back.quat))
    assert np.abs(pos).max() < 1e-9
    assert frames.quat_angle_between(quat, [0.0, 0.0, 0.0, 1.0]).max() < 1e-9


def test_tf_chain_unknown_frame_lists_the_frames_present(tree: TfTree) -> None:
    with pytest.raises(
        RecordingError,
        match=r"frame 'base_footprint' is not in /tf or /tf_static; frames present: "
        r"base_link, camera_link, camera_optical, lidar_link, map, odom",
    ):
        tree.chain("map", "base_footprint")


def test_tf_chain_rejects_frames_in_separate_trees(tmp_path: Path) -> None:
    gps = _static("earth", "gps", frames.Pose.identity())
    tree = load_tree(write_tf_bag(tmp_path / "tf", extra_static=[gps]))
    assert {"earth", "gps"} <= tree.frames
    with pytest.raises(RecordingError, match="frames 'map' and 'gps' are not connected"):
        tree.chain("map", "gps")
