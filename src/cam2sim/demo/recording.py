"""The demo recordings: a demo world driven, recorded and written into one folder.

:func:`build_demo_recording` writes the files :mod:`cam2sim.demo.world` describes (the OSM
file, the ROS2 bag written by :mod:`cam2sim.demo.bag`, the config, the ground truth and the
truth world), each atomically and ``demo.json`` last; :func:`load_demo_recording` reads a
complete folder back, and :func:`recorded_street` says which street a folder holds. This module
sits above both the world and the bag writer, so neither imports the other's caller.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

from cam2sim.core.config import save_config
from cam2sim.core.files import atomic_folder, write_text_atomic
from cam2sim.core.progress import no_progress
from cam2sim.demo.bag import write_bag
from cam2sim.demo.world import (
    L_STREET,
    DemoBuilding,
    DemoStreet,
    DemoWorld,
    ParkedCar,
    demo_config,
    demo_world,
)

if TYPE_CHECKING:
    from collections.abc import Sequence

    from cam2sim.core.progress import ProgressCallback

__all__ = ["DemoRecording", "build_demo_recording", "load_demo_recording", "recorded_street"]

_MARKER: Final = "demo.json"
_TRUTH_WORLD: Final = "truth_world.json"
_VERSION: Final = 3


@dataclass(frozen=True)
class DemoRecording:
    """What :func:`build_demo_recording` wrote.

    Attributes:
        root: The folder holding everything.
        street: The street it drove.
        bag: The ROS2 MCAP bag folder.
        osm: The OSM file of the street and buildings.
        config: The cam2sim config of the bag.
        truth: The parked cars (local frame; add :data:`ORIGIN_UTM` for UTM 32N).
        buildings: The buildings (local frame).
        truth_world: The :class:`~cam2sim.render.truth.TruthWorld` file of the world.
        camera_frames: Camera images in the bag.
        duration_s: Length of the drive.
    """

    root: Path
    street: DemoStreet
    bag: Path
    osm: Path
    config: Path
    truth: tuple[ParkedCar, ...]
    buildings: tuple[DemoBuilding, ...]
    truth_world: Path
    camera_frames: int
    duration_s: float


def recorded_street(out_dir: Path) -> str | None:
    """The name of the street whose recording ``out_dir`` holds (None: none, or unreadable)."""
    try:
        meta = json.loads((Path(out_dir) / _MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    name = meta.get("world", L_STREET.name) if isinstance(meta, dict) else None
    return str(name) if name is not None else None


def _paths(root: Path) -> tuple[Path, Path, Path, Path]:
    return root / "recording" / "bag", root / "demo.osm", root / "config.yaml", root / "truth.json"


def load_demo_recording(out_dir: Path, street: DemoStreet = L_STREET) -> DemoRecording | None:
    """The recording of ``street`` already built in ``out_dir``, or None.

    None when there is none, a partial one, or one of another street.
    """
    root = Path(out_dir)
    marker = root / _MARKER
    bag, osm, config, truth = _paths(root)
    truth_world = root / _TRUTH_WORLD
    files = (marker, osm, config, truth_world)
    if not (bag.is_dir() and all(f.is_file() for f in files)):
        return None
    try:
        meta = json.loads(marker.read_text(encoding="utf-8"))
        data = json.loads(truth.read_text(encoding="utf-8"))
        if meta.get("version") != _VERSION or meta.get("world", L_STREET.name) != street.name:
            return None
        cars = tuple(ParkedCar(**c) for c in data["cars"])
        buildings = tuple(
            DemoBuilding(xy=tuple((float(x), float(y)) for x, y in b["xy"]), levels=b["levels"])
            for b in data["buildings"]
        )
        return DemoRecording(
            root=root,
            street=street,
            bag=bag,
            osm=osm,
            config=config,
            truth=cars,
            buildings=buildings,
            truth_world=truth_world,
            camera_frames=int(meta["camera_frames"]),
            duration_s=float(meta["duration_s"]),
        )
    except (OSError, ValueError, KeyError, TypeError):
        return None


def build_demo_recording(
    out_dir: Path,
    *,
    seed: int = 0,
    street: DemoStreet = L_STREET,
    world: DemoWorld | None = None,
    notes: Sequence[str] = (),
    progress: ProgressCallback | None = None,
) -> DemoRecording:
    """Write the demo's OSM file, bag, config and ground truth of ``street`` into ``out_dir``.

    ``world`` (a world on ``street`` built elsewhere, e.g. from a real OSM file by
    :func:`~cam2sim.demo.osm_world.osm_demo_world`) replaces :func:`demo_world`'s; ``notes``
    (how it was made) go into the ground-truth world with the street's title.

    Every file is written atomically, and ``demo.json`` last: a folder with it is complete
    (:func:`load_demo_recording` reads it back).

    Raises:
        BackendUnavailableError: No headless OpenGL for the raster renderer (the message says
            what to install).
    """
    root = Path(out_dir)
    root.mkdir(parents=True, exist_ok=True)
    if world is None:
        world = demo_world(seed, street)
    elif world.street != street:
        msg = f"the world given is on street {world.street.name!r}, not {street.name!r}"
        raise ValueError(msg)
    bag, osm, config, truth = _paths(root)
    write_text_atomic(osm, world.osm_xml())
    with atomic_folder(bag.parent) as tmp:
        frames = write_bag(tmp / bag.name, world, seed=seed, progress=progress or no_progress)
    save_config(
        demo_config(bag, street.crs), config, comment="The cam2sim demo recording (cam2sim demo)"
    )
    data = {
        "crs": street.crs,
        "origin_utm": list(street.origin),
        "cars": [asdict(c) for c in world.cars],
        "buildings": [{"xy": [list(p) for p in b.xy], "levels": b.levels} for b in world.buildings],
    }
    write_text_atomic(truth, json.dumps(data, indent=1) + "\n")
    world.truth_world(seed=seed, notes=notes).save(root / _TRUTH_WORLD)
    duration = street.duration_s
    meta = {
        "version": _VERSION,
        "world": street.name,
        "seed": seed,
        "camera_frames": frames,
        "duration_s": duration,
    }
    write_text_atomic(root / _MARKER, json.dumps(meta, indent=1) + "\n")
    return DemoRecording(
        root=root,
        street=street,
        bag=bag,
        osm=osm,
        config=config,
        truth=world.cars,
        buildings=world.buildings,
        truth_world=root / _TRUTH_WORLD,
        camera_frames=frames,
        duration_s=duration,
    )
