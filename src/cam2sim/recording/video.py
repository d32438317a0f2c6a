"""Video files as a frame source: a dash camera's or phone's drive, decoded with OpenCV.

:func:`decode_video` writes the frames ``cam2sim import`` keeps (at most ``max_fps`` a second)
as image files and returns their times, from the container's presentation times (the frame
index over the stream's frame rate where the container gives none). The times count from the
video's first frame; ``cam2sim import --start`` says when that was on the poses' clock.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from cam2sim.core.errors import RecordingError
from cam2sim.core.progress import ProgressCallback, no_progress

if TYPE_CHECKING:
    from concurrent.futures import Future
    from pathlib import Path

    import numpy.typing as npt

__all__ = ["RAW_STREAM_SUFFIXES", "VIDEO_SUFFIXES", "DecodedVideo", "decode_video", "is_video"]

RAW_STREAM_SUFFIXES = (".hevc", ".h265", ".265", ".h264", ".264", ".mjpeg", ".mjpg")
"""Bare video streams without a container (comma2k19's ``video.hevc``): they carry no times,
and FFmpeg reads them at an assumed 25 frames a second."""
VIDEO_SUFFIXES = (
    ".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".mts", ".ts", *RAW_STREAM_SUFFIXES,
)  # fmt: skip


def is_video(path: Path) -> bool:
    """Whether ``path`` is a video file (by its suffix)."""
    return path.is_file() and path.suffix.lower() in VIDEO_SUFFIXES


@dataclass(frozen=True)
class DecodedVideo:
    """The frames :func:`decode_video` kept.

    Attributes:
        files: The image files written, in time order.
        stamp_ns: ``(N,)`` int64 times from the video's first frame, nanoseconds.
        fps: The stream's frame rate (0 where the container does not say).
        decoded: Frames decoded in all (``len(files)`` of them kept).
    """

    files: list[Path]
    stamp_ns: npt.NDArray[np.int64]
    fps: float
    decoded: int


def _open(path: Path) -> tuple[Any, float, int]:
    """An OpenCV capture of ``path``, its frame rate (0: unknown) and frame count (0: unknown).

    Raises:
        RecordingError: OpenCV cannot open it.
    """
    import cv2  # noqa: PLC0415 -- lazy: cv2 is heavy

    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        msg = (
            f"{path} cannot be opened as a video (OpenCV's FFmpeg reads MP4, MOV, AVI, MKV); "
            "convert it, or extract its frames into a folder"
        )
        raise RecordingError(msg)
    fps = float(capture.get(cv2.CAP_PROP_FPS) or 0.0)
    return capture, fps, int(capture.get(cv2.CAP_PROP_FRAME_COUNT) or 0)


class _FrameFiles:
    """Frames converted, encoded and written on worker threads (OpenCV releases the GIL).

    At most twice the workers' count of frames wait in memory; the first failure is raised.
    """

    def __init__(self, out_dir: Path, fmt: Literal["png", "jpeg"], jpeg_quality: int) -> None:
        from concurrent.futures import ThreadPoolExecutor  # noqa: PLC0415 -- lazy

        from cam2sim.core.machine import available_cpus  # noqa: PLC0415 -- lazy

        self.out_dir, self.fmt, self.quality = out_dir, fmt, jpeg_quality
        self.suffix = "jpg" if fmt == "jpeg" else "png"
        self.workers = max(1, available_cpus())
        self.pool = ThreadPoolExecutor(self.workers, thread_name_prefix="cam2sim-video")
        self.pending: deque[Future[None]] = deque()
        self.files: list[Path] = []

    def _write(self, frame: Any, target: Path) -> None:
        import cv2  # noqa: PLC0415 -- lazy: cv2 is heavy

        from cam2sim.recording.image import encode_image_file  # noqa: PLC0415 -- lazy

        image = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
        target.write_bytes(encode_image_file(image, self.fmt, jpeg_quality=self.quality))

    def add(self, frame: Any) -> None:
        target = self.out_dir / f"frame_{len(self.files):06d}.{self.suffix}"
        self.files.append(target)
        self.pending.append(self.pool.submit(self._write, frame, target))
        while len(self.pending) > 2 * self.workers:
            self.pending.popleft().result()

    def close(self) -> None:
        try:
            while self.pending:
                self.pending.popleft().result()
        finally:
            self.pool.shutdown(wait=True, cancel_futures=True)


def decode_video(
    path: Path,
    out_dir: Path,
    *,
    max_fps: float = 10.0,
    fmt: Literal["png", "jpeg"] = "png",
    jpeg_quality: int = 95,
    stream_fps: float | None = None,
    progress: ProgressCallback = no_progress,
) -> DecodedVideo:
    """Decode ``path``, keeping at most ``max_fps`` frames a second, into ``out_dir``.

    A frame is kept when at least ``1 / max_fps`` seconds passed since the last kept one
    (every frame of a video slower than ``max_fps``). The kept frames are encoded and written
    on every CPU while the next ones decode. ``stream_fps``: the frames are this many a second
    apart, whatever the file says (a bare stream, :data:`RAW_STREAM_SUFFIXES`).

    Raises:
        RecordingError: The file cannot be opened or holds no frame.
    """
    import cv2  # noqa: PLC0415 -- lazy: cv2 is heavy

    if max_fps <= 0:
        msg = f"--video-fps must be positive; got {max_fps}"
        raise RecordingError(msg)
    if stream_fps is not None and stream_fps <= 0:
        msg = f"--fps must be positive; got {stream_fps}"
        raise RecordingError(msg)
    capture, fps, total = _open(path)
    out_dir.mkdir(parents=True, exist_ok=True)
    writer = _FrameFiles(out_dir, fmt, jpeg_quality)
    stamps: list[int] = []
    step_ns = round(1e9 / max_fps)
    next_ns = 0
    last = -1
    decoded = 0
    try:
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            stamp = round(float(capture.get(cv2.CAP_PROP_POS_MSEC) or 0.0) * 1e6)
            if stream_fps is not None:
                stamp = round(decoded * 1e9 / stream_fps)
            elif stamp <= last:  # the container gives no (or no rising) times: index / fps
                if fps <= 0:
                    msg = (
                        f"{path}: its frames carry no times and it names no frame rate; "
                        "extract the frames into a folder and pass --fps"
                    )
                    raise RecordingError(msg)
                stamp = max(last + 1, round(decoded * 1e9 / fps))
            last = stamp
            decoded += 1
            if stamp < next_ns - step_ns // 20:  # a 5 % tolerance for rounded times
                continue
            next_ns = stamp + step_ns
            writer.add(frame)
            stamps.append(stamp)
            if decoded % 32 == 0:
                progress("video frames", decoded, max(total, decoded))
    finally:
        capture.release()
        writer.close()
    progress("video frames", decoded, decoded)
    if not writer.files:
        msg = f"{path}: no frame could be decoded; check the file plays, or convert it"
        raise RecordingError(msg)
    t = np.asarray(stamps, dtype=np.int64)
    return DecodedVideo(writer.files, t - t[0], stream_fps or fps, decoded)
