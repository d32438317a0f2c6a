"""Recording summaries: counts, rates, spans and largest gaps from bag receive times."""

from __future__ import annotations

from pathlib import Path

import pytest

from cam2sim.recording.bagwriter import BagFormat, BagWriter
from cam2sim.recording.summary import TopicSummary, summarize_recording

T0 = 1_700_000_000_000_000_000
MS = 1_000_000

# /fast: 31 messages, 100 ms apart, over 3 s (10 Hz).
FAST_NS = [T0 + i * 100 * MS for i in range(31)]
# /gappy: 250 ms apart from 0.5 s, with one 2 s gap after 1.25 s.
GAPPY_NS = [T0 + s * MS for s in (500, 750, 1000, 1250, 3250, 3500)]
# /once: a single message.
ONCE_NS = [T0 + 2000 * MS]


def _events() -> list[tuple[int, str, str, dict[str, object]]]:
    events: list[tuple[int, str, str, dict[str, object]]] = []
    events += [(t, "/fast", "std_msgs/msg/Float64", {"data": 1.0}) for t in FAST_NS]
    events += [(t, "/gappy", "std_msgs/msg/Int32", {"data": 7}) for t in GAPPY_NS]
    events += [(t, "/once", "std_msgs/msg/String", {"data": "hi"}) for t in ONCE_NS]
    return sorted(events, key=lambda e: (e[0], e[1]))


def _write(path: Path, fmt: BagFormat, keep: slice = slice(None)) -> Path:
    with BagWriter(path, fmt) as w:
        for t, topic, msgtype, fields in _events()[keep]:
            w.write_fields(topic, msgtype, fields, receive_ns=t)
    return path


def _by_name(topics: tuple[TopicSummary, ...]) -> dict[str, TopicSummary]:
    return {t.name: t for t in topics}


@pytest.mark.parametrize("fmt", ["ros1", "sqlite3", "mcap"])
def test_summarize_recording_counts_rates_spans_and_gaps_exactly(
    tmp_path: Path, fmt: BagFormat
) -> None:
    bag = _write(tmp_path / ("rec.bag" if fmt == "ros1" else "rec"), fmt)
    summary = summarize_recording([bag])
    topics = _by_name(summary.topics)
    assert set(topics) == {"/fast", "/gappy", "/once"}
    assert summary.start_ns == T0
    assert summary.end_ns == T0 + 3500 * MS
    assert summary.duration_s == 3.5

    fast = topics["/fast"]
    assert fast.msgtype == "std_msgs/msg/Float64"
    assert fast.count == 31
    assert fast.rate_hz == 10.0
    assert (fast.start_ns, fast.end_ns) == (T0, T0 + 3000 * MS)
    assert fast.max_gap_s == 0.1

    gappy = topics["/gappy"]
    assert gappy.msgtype == "std_msgs/msg/Int32"
    assert gappy.count == 6
    assert gappy.rate_hz == 5 / 3.0
    assert (gappy.start_ns, gappy.end_ns) == (T0 + 500 * MS, T0 + 3500 * MS)
    assert gappy.max_gap_s == 2.0
    assert gappy.max_gap_at_s == 1.25


def test_summarize_recording_reports_zero_rate_and_gap_for_a_single_message(
    tmp_path: Path,
) -> None:
    summary = summarize_recording([_write(tmp_path / "rec", "mcap")])
    once = _by_name(summary.topics)["/once"]
    assert once.count == 1
    assert once.rate_hz == 0.0
    assert once.max_gap_s == 0.0
    assert once.start_ns == once.end_ns == ONCE_NS[0]


def test_summarize_recording_treats_split_ros1_bags_as_one_recording(tmp_path: Path) -> None:
    n = len(_events())
    whole = summarize_recording([_write(tmp_path / "whole.bag", "ros1")])
    parts = [
        _write(tmp_path / "part1.bag", "ros1", slice(0, n // 2)),
        _write(tmp_path / "part2.bag", "ros1", slice(n // 2, None)),
    ]
    split = summarize_recording(parts)
    assert split.paths == tuple(str(p) for p in parts)
    assert (split.start_ns, split.end_ns) == (whole.start_ns, whole.end_ns)
    assert _by_name(split.topics) == _by_name(whole.topics)
    # The 2 s gap of /gappy spans the two files; it is still found.
    assert _by_name(split.topics)["/gappy"].max_gap_s == 2.0
