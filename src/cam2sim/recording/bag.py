"""Reading ROS1 ``.bag``, ROS2 sqlite3 and MCAP recordings without ROS.

:class:`Recording` wraps rosbags' ``AnyReader``: one context-managed facade over one or several
bag files, translating rosbags' errors into :class:`RecordingError` with a message that says what
to do, and yielding deserialised messages with the chosen time base.
"""

from __future__ import annotations

import difflib
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Self

from cam2sim.core.errors import RecordingError

if TYPE_CHECKING:
    from collections.abc import Iterable, Iterator, Sequence
    from types import TracebackType

__all__ = ["BagMessage", "RawMessage", "Recording", "TopicInfo", "stamp_ns_of"]

logger = logging.getLogger(__name__)

TimeBase = Literal["header", "receive"]


@dataclass(frozen=True)
class TopicInfo:
    """A topic of a recording."""

    name: str
    msgtype: str
    count: int


@dataclass(frozen=True)
class RawMessage:
    """A message as stored: topic, type, receive time and serialised bytes."""

    topic: str
    msgtype: str
    receive_ns: int
    rawdata: bytes


@dataclass(frozen=True)
class BagMessage:
    """A deserialised message with its time on the chosen time base.

    ``stamp_ns`` is ``header.stamp`` with time base ``header`` (the receive time for messages
    without a header or with an unset stamp), else the receive time. Integer nanoseconds.
    """

    topic: str
    msgtype: str
    stamp_ns: int
    receive_ns: int
    msg: Any  # rosbags generates message classes at run time; they have no static type


def stamp_ns_of(msg: Any) -> int | None:
    """Return ``msg.header.stamp`` in nanoseconds, or None when absent or zero."""
    header = getattr(msg, "header", None)
    stamp = getattr(header, "stamp", None)
    if stamp is None:
        return None
    value = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
    return value or None


def _bag_paths(paths: Sequence[Path]) -> list[Path]:
    if not paths:
        msg = "no recording given; pass --bag PATH (a .bag, .mcap or ROS2 bag folder)"
        raise RecordingError(msg)
    out = []
    for path in paths:
        p = Path(path)
        if not p.exists():
            msg = (
                f"recording {p} does not exist; check the path (on the command line, or "
                "recording.bags in config.yaml)"
            )
            raise RecordingError(msg)
        if p.is_dir() and not _looks_like_a_bag(p):
            images = sum(1 for f in p.iterdir() if f.suffix.lower() in (".png", ".jpg", ".jpeg"))
            video = next((f for f in sorted(p.iterdir()) if f.name.startswith("video.")), None)
            if (p / "global_pose").is_dir() and video is not None:  # a comma2k19 segment
                hint = (
                    f"; it is a comma2k19 segment: import it with `cam2sim import WS --images "
                    f"{video} --fps 20 --poses {p / 'global_pose'}` (docs/real-recordings.md)"
                )
            elif images:
                hint = (
                    f"; it holds {images} images: import them with `cam2sim import WS --images {p}`"
                )
            else:
                hint = "; pass a .bag or .mcap file, or a ROS2 bag folder (with metadata.yaml)"
            msg = f"no bag here: {p} is a folder without a ROS2 bag's metadata.yaml{hint}"
            raise RecordingError(msg)
        out.append(p)
    return out


def _looks_like_a_bag(folder: Path) -> bool:
    """Whether a folder is a ROS2 bag (``metadata.yaml``, or its .db3/.mcap storage files)."""
    if (folder / "metadata.yaml").is_file():
        return True
    return any(f.suffix in (".db3", ".mcap") for f in folder.iterdir())


class Recording:
    """One recording, possibly split over several bag files of the same kind.

    Use as a context manager::

        with Recording([Path("drive.mcap")]) as rec:
            for m in rec.messages(["/odom"]):
                ...
    """

    def __init__(self, paths: Sequence[Path]) -> None:
        self.paths = _bag_paths(paths)
        self._reader: Any = None  # rosbags AnyReader, imported lazily

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def open(self) -> None:
        """Open every bag file; on failure nothing stays open."""
        from rosbags.highlevel import AnyReader, AnyReaderError  # noqa: PLC0415
        from rosbags.typesys import Stores, get_typestore  # noqa: PLC0415

        reader = AnyReader(self.paths, default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        try:
            reader.open()
        except (AnyReaderError, OSError, ValueError, KeyError, IndexError) as err:
            names = ", ".join(str(p) for p in self.paths)
            msg = (
                f"cannot read recording {names}: {err or type(err).__name__}. Check that it is a "
                "complete ROS1 .bag, ROS2 bag folder or .mcap file (a truncated copy cannot be "
                "read; re-copy it, or reindex it with `rosbag reindex` / `ros2 bag reindex`)"
            )
            raise RecordingError(msg) from err
        self._reader = reader

    def close(self) -> None:
        """Close the bag files (idempotent)."""
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    @property
    def _open_reader(self) -> Any:
        assert self._reader is not None, "Recording is not open; use it as a context manager"
        return self._reader

    def topics(self) -> dict[str, TopicInfo]:
        """Return every topic with its message type and count."""
        out: dict[str, TopicInfo] = {}
        for name, info in self._open_reader.topics.items():
            out[name] = TopicInfo(name=name, msgtype=info.msgtype or "?", count=info.msgcount)
        return dict(sorted(out.items()))

    @property
    def start_ns(self) -> int:
        """First receive time in the recording."""
        return int(self._open_reader.start_time)

    @property
    def end_ns(self) -> int:
        """Last receive time in the recording."""
        return int(self._open_reader.end_time)

    def require_topic(self, topic: str, *, key: str, msgtypes: Iterable[str] = ()) -> TopicInfo:
        """Return a topic's info, or raise an error listing the topics that exist.

        Args:
            topic: The topic name.
            key: The config key that named it (for the message).
            msgtypes: Accepted message types; empty accepts any.

        Raises:
            RecordingError: The topic is missing or of an unsupported type.
        """
        topics = self.topics()
        if topic not in topics:
            close = difflib.get_close_matches(topic, list(topics), n=3, cutoff=0.4)
            hint = f" Closest: {', '.join(close)}." if close else ""
            listing = ", ".join(f"{t.name} ({t.msgtype})" for t in topics.values())
            msg = (
                f"topic {topic!r} ({key} in config.yaml) is not in the recording.{hint} "
                f"Topics present: {listing}. Set {key} to one of them."
            )
            raise RecordingError(msg)
        info = topics[topic]
        accepted = tuple(msgtypes)
        if accepted and info.msgtype not in accepted:
            msg = (
                f"topic {topic!r} ({key}) has type {info.msgtype}, expected one of "
                f"{', '.join(accepted)}; point {key} at a topic of a supported type"
            )
            raise RecordingError(msg)
        return info

    def raw_messages(self, topics: Iterable[str] | None = None) -> Iterator[RawMessage]:
        """Yield stored messages in receive-time order without deserialising them."""
        reader = self._open_reader
        wanted = set(topics) if topics is not None else None
        conns = [c for c in reader.connections if wanted is None or c.topic in wanted]
        if not conns:
            return
        try:
            for conn, receive_ns, rawdata in reader.messages(connections=conns):
                yield RawMessage(conn.topic, conn.msgtype, int(receive_ns), rawdata)
        except Exception as err:  # noqa: BLE001 - rosbags raises many types on corrupt data
            self._raise_corrupt(err)

    def messages(
        self, topics: Iterable[str], *, time_base: TimeBase = "header"
    ) -> Iterator[BagMessage]:
        """Yield deserialised messages of ``topics`` in receive-time order.

        Args:
            topics: Topic names.
            time_base: ``header`` (``header.stamp``, falling back to the receive time for
                messages without one) or ``receive``.
        """
        reader = self._open_reader
        for raw in self.raw_messages(topics):
            try:
                msg = reader.deserialize(raw.rawdata, raw.msgtype)
            except Exception as err:  # noqa: BLE001 - deserialisation errors vary by format
                self._raise_corrupt(err, topic=raw.topic)
            stamp = stamp_ns_of(msg) if time_base == "header" else None
            yield BagMessage(raw.topic, raw.msgtype, stamp or raw.receive_ns, raw.receive_ns, msg)

    def _raise_corrupt(self, err: BaseException, *, topic: str | None = None) -> None:
        names = ", ".join(str(p) for p in self.paths)
        where = f" (topic {topic})" if topic else ""
        msg = (
            f"recording {names} is corrupt or truncated{where}: {err or type(err).__name__}. "
            "Re-copy the file or reindex it (`rosbag reindex` / `ros2 bag reindex`)"
        )
        raise RecordingError(msg) from err
