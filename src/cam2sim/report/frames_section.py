"""The report's ``frames`` section: what the cameras saw, side by side.

The latest replay side by side, each camera's first drive (with its last frame before a
failure), a video strip of each, and the replay as an embedded WebM clip.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from cam2sim.core.errors import Cam2SimError
from cam2sim.core.native import native_stderr_silenced
from cam2sim.core.run_record import RunEvents
from cam2sim.core.workspace import run_paths
from cam2sim.metrics.behaviour import (
    CAMERA_LABELS,
)
from cam2sim.report.pieces import data_uri, esc

if TYPE_CHECKING:
    from cam2sim.report.context import ReportContext

from cam2sim.report.pieces import FRAME_WIDTH, evenly, img, jpeg, not_available

__all__ = ["VIDEO_CAP_BYTES", "frames_section", "webm"]

_VIDEO_FRAMES = 300  # frames of a run's clip in the report
_VIDEO_WIDTH = 640
#: A run's clip (WebM made from its frames) is embedded only up to this size.
VIDEO_CAP_BYTES = 8 * 1024 * 1024
_CHOSEN_FRAMES = 4
_STRIP_FRAMES = 8
_STRIP_WIDTH = 320


def frames_section(ctx: ReportContext) -> str:
    """The latest replay side by side, and the first kept drive of each camera (method).

    A drive that ended in a failure also shows its last frame before it.
    """
    found = [(run, f) for run in ctx.runs if (f := _frame_folder(run)) is not None]
    if not found:
        return not_available("Frames", f"cam2sim replay {ctx.ws.root} --camera both")
    replays = [(r, f) for r, f in found if ctx.meta[r.name].kind == "replay"]
    chosen = replays[-1:]
    by_camera: dict[str, tuple[Path, Path]] = {}
    for run, folder in found:
        meta = ctx.meta[run.name]
        if meta.kind == "drive" and meta.camera and meta.camera not in by_camera:
            by_camera[meta.camera] = (run, folder)
    chosen += [by_camera[c] for c in sorted(by_camera, key=_camera_order)]
    parts = []
    for run, folder in chosen:
        files = sorted(folder.glob("*.png"))
        meta = ctx.meta[run.name]
        if meta.kind == "replay":
            cams = meta.cameras or [meta.camera or "?"]
            labels = [CAMERA_LABELS.get(str(c), str(c)) for c in cams]
            panels = " | ".join(["recorded (left, where there is a recorded frame)", *labels])
            what = f"replay, side by side: {panels}"
        else:
            label = CAMERA_LABELS.get(meta.camera or "", meta.camera or "?")
            what = f"closed loop, {label}: what DAVE-2 saw (seed {meta.seed})"
        parts.append(f"<h3>{esc(run.name)}</h3><p class='note'>{esc(what)}</p>")
        try:
            for f in evenly(files, _CHOSEN_FRAMES):
                tag = img(jpeg(f, FRAME_WIDTH), f"frame {f.stem}", mime="image/jpeg")
                parts.append(f"<figure>{tag}<figcaption>frame {esc(f.stem)}</figcaption></figure>")
            failure = _failure(run)
            if failure is not None and files:
                tag = img(jpeg(files[-1], FRAME_WIDTH), "the last frame", mime="image/jpeg")
                caption = f"the last frame before it failed: {failure}"
                parts.append(f"<figure>{tag}<figcaption>{esc(caption)}</figcaption></figure>")
            strip = "".join(
                img(jpeg(f, _STRIP_WIDTH), f"strip {f.stem}", mime="image/jpeg", cls="strip")
                for f in evenly(files, _STRIP_FRAMES)
            )
        except OSError as err:
            ctx.warnings.append(f"frames of {run.name}: {err}")
            continue
        parts.append(f'<p class="note">Video strip</p><div class="strip">{strip}</div>')
        if meta.kind != "replay":
            continue  # one clip: the replay's
        clip = webm(files[:_VIDEO_FRAMES])
        if clip is not None and len(clip) <= VIDEO_CAP_BYTES:
            src = data_uri(clip, "video/webm")
            parts.append(f'<video controls muted loop width="640" src="{src}"></video>')
        elif run_paths(run).video.is_file():
            parts.append(f'<p class="note">the run\'s video: {esc(str(run_paths(run).video))}</p>')
    return "".join(parts)


def _frame_folder(run: Path) -> Path | None:
    if any(run_paths(run).side_by_side_dir.glob("*.png")):
        return run_paths(run).side_by_side_dir
    for folder in sorted((run / "frames").glob("*")):
        if any(folder.glob("*.png")):
            return folder
    return None


def _camera_order(camera: str) -> int:
    """Real (truth), splat, Sim (raster), then the others: the behaviour table's order."""
    order = ("truth", "splat", "raster", "carla")
    return order.index(camera) if camera in order else len(order)


def _failure(run: Path) -> str | None:
    """``collision at 12.3 s: hit parked vehicle pv_3`` for a run that failed, else None."""
    path = run_paths(run).events_json
    if not path.is_file():
        return None
    try:
        events = RunEvents.load(path).events
    except Cam2SimError:
        return None
    for event in events:
        if event.kind in ("collision", "off_road", "stuck", "timeout"):
            reason = f": {event.reason}" if event.reason else ""
            return f"{event.kind} at {event.t:.1f} s{reason}"
    return None


def webm(files: list[Path], fps: float = 10.0) -> bytes | None:
    """The frames as a VP8 WebM clip (browsers play it; OpenCV's MP4 is not H.264), or None."""
    import tempfile  # noqa: PLC0415

    import cv2  # noqa: PLC0415

    if not files:
        return None
    first = cv2.imread(str(files[0]), cv2.IMREAD_COLOR)
    if first is None:
        return None
    h, w = first.shape[:2]
    size = (_VIDEO_WIDTH, max(2, round(h * _VIDEO_WIDTH / w) // 2 * 2))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "clip.webm"
        with native_stderr_silenced():  # FFmpeg's "tag 'VP80' is not supported" (it is)
            writer = cv2.VideoWriter(str(out), cv2.VideoWriter.fourcc(*"VP80"), fps, size)
        if not writer.isOpened():
            return None
        try:
            for f in files:  # one encode per frame
                bgr = cv2.imread(str(f), cv2.IMREAD_COLOR)
                if bgr is not None:
                    writer.write(cv2.resize(bgr, size, interpolation=cv2.INTER_AREA))
        finally:
            writer.release()
        return out.read_bytes() if out.stat().st_size else None
