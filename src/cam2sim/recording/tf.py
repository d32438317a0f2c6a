"""The ``/tf`` and ``/tf_static`` tree: pose chains between two frames and static mounts.

Each child frame has one parent. A chain ``parent -> child`` is composed along the tree; dynamic
edges are interpolated (linear position, slerp rotation) at the union of their sample times within
the time span they all cover, static edges are constant.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from cam2sim.core import frames
from cam2sim.core.errors import RecordingError
from cam2sim.core.frames import Pose

if TYPE_CHECKING:
    from collections.abc import Iterable

    from cam2sim.recording.bag import BagMessage

__all__ = ["TF_MSGTYPE", "TfChain", "TfTree"]

TF_MSGTYPE = "tf2_msgs/msg/TFMessage"


@dataclass(frozen=True)
class TfChain:
    """A composed transform ``T_parent_child`` over time.

    Attributes:
        stamp_ns: ``(N,)`` int64 nanoseconds, strictly increasing (one sample when static).
        position: ``(N, 3)`` float64 child origin in the parent frame.
        quat: ``(N, 4)`` float64 (x, y, z, w) rotation child -> parent.
    """

    stamp_ns: npt.NDArray[np.int64]
    position: npt.NDArray[np.float64]
    quat: npt.NDArray[np.float64]

    @property
    def static(self) -> bool:
        """Whether the chain has a single (time-independent) value."""
        return int(self.stamp_ns.shape[0]) == 1


@dataclass
class _Edge:
    parent: str
    static: bool
    stamps: list[int] = field(default_factory=list)
    values: list[tuple[float, ...]] = field(default_factory=list)


class TfTree:
    """Transforms gathered from ``/tf`` and ``/tf_static`` messages."""

    def __init__(self) -> None:
        self._edges: dict[str, _Edge] = {}

    def add_messages(self, messages: Iterable[BagMessage], *, static_topics: set[str]) -> None:
        """Add every transform of TFMessage messages (static ones from ``static_topics``)."""
        for m in messages:
            static = m.topic in static_topics
            for tr in m.msg.transforms:
                self._add(tr, static=static)

    def _add(self, tr: Any, *, static: bool) -> None:
        child = tr.child_frame_id.lstrip("/")
        parent = tr.header.frame_id.lstrip("/")
        edge = self._edges.get(child)
        if edge is None or edge.parent != parent:
            edge = _Edge(parent=parent, static=static)
            self._edges[child] = edge
        t, r = tr.transform.translation, tr.transform.rotation
        stamp = int(tr.header.stamp.sec) * 1_000_000_000 + int(tr.header.stamp.nanosec)
        if edge.static:
            edge.stamps, edge.values = [stamp], [(t.x, t.y, t.z, r.x, r.y, r.z, r.w)]
        else:
            edge.stamps.append(stamp)
            edge.values.append((t.x, t.y, t.z, r.x, r.y, r.z, r.w))

    @property
    def frames(self) -> set[str]:
        """Every frame named in the tree."""
        return set(self._edges) | {e.parent for e in self._edges.values()}

    def _path_to_root(self, frame: str) -> list[str]:
        path = [frame]
        while path[-1] in self._edges and len(path) <= len(self._edges) + 1:
            path.append(self._edges[path[-1]].parent)
        return path

    def _edge_samples(self, child: str) -> TfChain:
        edge = self._edges[child]
        stamps = np.asarray(edge.stamps, dtype=np.int64)
        values = np.asarray(edge.values, dtype=np.float64)
        order = np.argsort(stamps, kind="stable")
        stamps, values = stamps[order], values[order]
        keep = np.concatenate([[True], np.diff(stamps) > 0])
        quat = frames.quat_normalize(values[keep, 3:])
        return TfChain(stamp_ns=stamps[keep], position=values[keep, :3], quat=quat)

    def chain(self, parent: str, child: str) -> TfChain:
        """Return ``T_parent_child`` over time.

        Raises:
            RecordingError: A frame is unknown or the two frames are not connected.
        """
        parent, child = parent.lstrip("/"), child.lstrip("/")
        known = self.frames
        for name in (parent, child):
            if name not in known:
                msg = (
                    f"frame {name!r} is not in /tf or /tf_static; frames present: "
                    f"{', '.join(sorted(known)) or 'none'}. Fix pose.tf or the mount's tf_frame"
                )
                raise RecordingError(msg)
        up_child = self._path_to_root(child)
        up_parent = self._path_to_root(parent)
        common = next((f for f in up_child if f in up_parent), None)
        if common is None:
            msg = f"frames {parent!r} and {child!r} are not connected in the tf tree"
            raise RecordingError(msg)
        # T_common_child composes edges from common down to child; same for parent.
        down_child = up_child[: up_child.index(common)]
        down_parent = up_parent[: up_parent.index(common)]
        edges = [self._edge_samples(f) for f in down_child + down_parent]
        dynamic = [e for e in edges if not e.static]
        if dynamic:
            start = max(int(e.stamp_ns[0]) for e in dynamic)
            end = min(int(e.stamp_ns[-1]) for e in dynamic)
            if start > end:
                msg = f"the tf edges between {parent!r} and {child!r} never overlap in time"
                raise RecordingError(msg)
            stamps = np.unique(np.concatenate([e.stamp_ns for e in dynamic]))
            stamps = stamps[(stamps >= start) & (stamps <= end)]
        else:
            stamps = np.zeros(1, dtype=np.int64)
        n = stamps.shape[0]

        def compose(names: list[str]) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
            pos = np.zeros((n, 3))
            quat = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
            # names run from the leaf up to (excluding) common: compose from the top down.
            for name in reversed(names):
                e = self._edge_samples(name)
                if e.static:
                    p_e, q_e = (
                        np.broadcast_to(e.position[0], (n, 3)),
                        np.broadcast_to(e.quat[0], (n, 4)),
                    )
                else:
                    s = frames.interpolate_poses(e.stamp_ns, e.position, e.quat, stamps)
                    p_e, q_e = s.positions, s.quats
                pos = pos + frames.quat_rotate(quat, p_e)
                quat = frames.quat_multiply(quat, q_e)
            return pos, quat

        p_cc, q_cc = compose(down_child)
        p_cp, q_cp = compose(down_parent)
        q_pc_inv = frames.quat_conjugate(q_cp)
        position = frames.quat_rotate(q_pc_inv, p_cc - p_cp)
        quat = frames.quat_normalize(frames.quat_multiply(q_pc_inv, q_cc))
        return TfChain(stamp_ns=stamps, position=position, quat=quat)

    def static_transform(self, parent: str, child: str) -> Pose:
        """Return a time-independent ``T_parent_child`` (the first sample of a dynamic chain)."""
        chain = self.chain(parent, child)
        return Pose(position=chain.position[0], quat=chain.quat[0])
