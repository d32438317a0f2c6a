"""Scalar signals (steering, model commands, speed) from any numeric field of any message."""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from cam2sim.core.errors import RecordingError

if TYPE_CHECKING:
    from collections.abc import Iterable

    from cam2sim.recording.bag import BagMessage

__all__ = ["SignalSeries", "numeric_field_paths", "signal_from_messages", "value_at_path"]

_PART = re.compile(r"^(?P<name>[A-Za-z_][A-Za-z0-9_]*)(?:\[(?P<index>-?\d+)\])?$")


@dataclass(frozen=True)
class SignalSeries:
    """Samples of one scalar signal.

    Attributes:
        stamp_ns: ``(N,)`` int64 nanoseconds, in receive order.
        value: ``(N,)`` float64 in the message's own unit.
    """

    stamp_ns: npt.NDArray[np.int64]
    value: npt.NDArray[np.float64]


def numeric_field_paths(msg: Any, prefix: str = "") -> list[str]:
    """List the dotted paths of every numeric scalar field of a message (for error messages)."""
    out: list[str] = []
    if not dataclasses.is_dataclass(msg):
        return out
    for f in dataclasses.fields(msg):
        if f.name.startswith("__"):
            continue
        value = getattr(msg, f.name)
        path = f"{prefix}{f.name}"
        if isinstance(value, bool | int | float | np.number):
            out.append(path)
        elif dataclasses.is_dataclass(value):
            out.extend(numeric_field_paths(value, prefix=path + "."))
        elif isinstance(value, np.ndarray) and value.size and value.dtype.kind in "iuf":
            out.append(f"{path}[0]")
    return out


def value_at_path(msg: Any, path: str) -> float:
    """Return the number at a dotted field path such as ``drive.steering_angle`` or ``data[0]``.

    Raises:
        RecordingError: The path does not exist or is not numeric; the message lists the numeric
            fields that exist.
    """
    obj = msg
    for part in path.split("."):
        match = _PART.match(part)
        try:
            if match is None:
                raise AttributeError(part)  # noqa: TRY301 - one handler for every lookup failure
            obj = getattr(obj, match["name"])
            if match["index"] is not None:
                obj = obj[int(match["index"])]
        except (AttributeError, IndexError, TypeError):
            fields = ", ".join(numeric_field_paths(msg)) or "none"
            msg_ = (
                f"field {path!r} does not exist in {getattr(msg, '__msgtype__', 'message')}; "
                f"numeric fields: {fields}. Fix the signal's field in config.yaml"
            )
            raise RecordingError(msg_) from None
    if isinstance(obj, bool | int | float | np.number):
        return float(obj)
    fields = ", ".join(numeric_field_paths(msg)) or "none"
    msg_ = f"field {path!r} is not a number ({type(obj).__name__}); numeric fields: {fields}"
    raise RecordingError(msg_)


def signal_from_messages(messages: Iterable[BagMessage], *, field: str) -> SignalSeries:
    """Gather one numeric field of every message into a :class:`SignalSeries`."""
    stamps: list[int] = []
    values: list[float] = []
    for m in messages:
        stamps.append(m.stamp_ns)
        values.append(value_at_path(m.msg, field))
    return SignalSeries(
        stamp_ns=np.asarray(stamps, dtype=np.int64), value=np.asarray(values, dtype=np.float64)
    )
