"""What a recording holds: topics, types, counts, rates, time span and largest gaps."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from cam2sim.recording.bag import Recording

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from cam2sim.core.progress import ProgressCallback

__all__ = ["RecordingSummary", "TopicSummary", "summarize_recording"]


@dataclass(frozen=True)
class TopicSummary:
    """Statistics of one topic, on bag receive times.

    Attributes:
        name: Topic name.
        msgtype: Message type, e.g. ``sensor_msgs/msg/Image``.
        count: Number of messages.
        rate_hz: Mean rate over the topic's own span (0 for fewer than 2 messages).
        start_ns: First receive time.
        end_ns: Last receive time.
        max_gap_s: Largest interval between consecutive messages, seconds.
        max_gap_at_s: Seconds from the recording start to where that gap begins.
    """

    name: str
    msgtype: str
    count: int
    rate_hz: float
    start_ns: int
    end_ns: int
    max_gap_s: float
    max_gap_at_s: float


@dataclass(frozen=True)
class RecordingSummary:
    """A whole recording: its files, span and topics."""

    paths: tuple[str, ...]
    start_ns: int
    end_ns: int
    topics: tuple[TopicSummary, ...]

    @property
    def duration_s(self) -> float:
        """Receive-time span of the recording."""
        return (self.end_ns - self.start_ns) / 1e9


def summarize_recording(
    paths: Sequence[Path], *, progress: ProgressCallback | None = None
) -> RecordingSummary:
    """Read every message's receive time (without deserialising) and summarise each topic."""
    with Recording(paths) as rec:
        infos = rec.topics()
        stamps: dict[str, list[int]] = {name: [] for name in infos}
        total = sum(i.count for i in infos.values())
        n = 0
        for n, raw in enumerate(rec.raw_messages(), start=1):
            stamps[raw.topic].append(raw.receive_ns)
            if progress is not None and n % 1000 == 0:
                progress("messages", n, total)
        if progress is not None:
            progress("messages", n, n)  # the end (the count the index gave may differ)
        start = min((s[0] for s in stamps.values() if s), default=rec.start_ns)
        end = max((s[-1] for s in stamps.values() if s), default=rec.end_ns)
    topics = []
    for name, info in infos.items():
        t = np.asarray(stamps[name], dtype=np.int64)
        count = int(t.shape[0])
        if count >= 2:
            gaps = np.diff(t)
            i = int(np.argmax(gaps))
            rate = (count - 1) / ((t[-1] - t[0]) / 1e9) if t[-1] > t[0] else 0.0
            max_gap, gap_at = gaps[i] / 1e9, (t[i] - start) / 1e9
        else:
            rate, max_gap, gap_at = 0.0, 0.0, 0.0
        topics.append(
            TopicSummary(
                name=name,
                msgtype=info.msgtype,
                count=count,
                rate_hz=float(rate),
                start_ns=int(t[0]) if count else 0,
                end_ns=int(t[-1]) if count else 0,
                max_gap_s=float(max_gap),
                max_gap_at_s=float(gap_at),
            )
        )
    return RecordingSummary(
        paths=tuple(str(p) for p in paths),
        start_ns=int(start),
        end_ns=int(end),
        topics=tuple(topics),
    )
