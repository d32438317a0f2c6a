"""The benchmark suite (``SUITE.yaml``): the worlds ``cam2sim bench`` runs the experiment on.

A suite lists worlds: the built-in streets (``builtin: l-street`` or ``paper``), streets of real
OpenStreetMap extracts (``osm: FILE`` with ``routes: N`` distinct routes picked automatically
from different parts of the extract, or only some of them, ``picks: [1, 2]``, named as in the
larger suite, or one ``route: [LAT,LON, LAT,LON]``), each run with
``seeds`` closed-loop runs per method. ``tuned: true`` (for picked routes also their indices,
``tuned: [0]``) marks the worlds that were looked at while the tool was tuned: the report gives
the figures with and without them. Example::

    name: streets
    seeds: 3
    worlds:
      - builtin: l-street
        tuned: true
      - osm: maps/munich.osm
        routes: 3
      - osm: maps/oakland.osm.bz2
        route: ["37.80771,-122.30214", "37.80881,-122.3014"]
    settings:            # optional: smaller settings for a quick look
      ads_epochs: 30

Each world expands to one :class:`WorldSpec` (an OSM entry with ``routes: 3`` to three), whose
id is a readable name plus a hash of what it runs, so the same suite always expands to the same
ids and a re-run resumes.
"""

from __future__ import annotations

import hashlib
import json
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Literal

import pydantic

from cam2sim.campaign.plan import validation_message
from cam2sim.core.config import read_yaml
from cam2sim.core.errors import ConfigError

__all__ = ["Suite", "SuiteSettings", "SuiteWorld", "WorldSpec", "expand_suite", "load_suite"]


class _Model(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)


class SuiteWorld(_Model):
    """One entry of ``worlds:``: a built-in street or streets of an OSM extract."""

    builtin: Literal["l-street", "paper"] | None = pydantic.Field(
        None, description="a built-in street"
    )
    osm: str | None = pydantic.Field(
        None, description="an OSM extract (.osm, .osm.bz2, .osm.pbf), relative to the suite"
    )
    routes: int = pydantic.Field(
        1, ge=1, le=20, description="with osm: this many distinct routes, picked automatically"
    )
    picks: tuple[pydantic.NonNegativeInt, ...] | None = pydantic.Field(
        None,
        min_length=1,
        description="with osm: only these of the picked routes (0 = the best), e.g. [1, 2] to "
        "rerun two streets of a larger suite under the same names",
    )
    route: tuple[str, str] | None = pydantic.Field(
        None, description='with osm: one route between two points, ["LAT,LON", "LAT,LON"]'
    )
    tuned: bool | tuple[int, ...] = pydantic.Field(
        default=False,
        description="looked at while tuning the tool: true, or the indices of picked routes",
    )

    @pydantic.model_validator(mode="after")
    def _one_source(self) -> SuiteWorld:
        if (self.builtin is None) == (self.osm is None):
            msg = "give exactly one of `builtin:` (l-street, paper) or `osm:` (a file)"
            raise ValueError(msg)
        if self.osm is None and (
            self.route is not None or self.routes != 1 or self.picks is not None
        ):
            msg = "`route:`, `routes:` and `picks:` go with `osm:`"
            raise ValueError(msg)
        if self.route is not None and (self.routes != 1 or self.picks is not None):
            msg = "give `route:` (one route) or `routes: N` / `picks: [...]` (picked), not both"
            raise ValueError(msg)
        if self.picks is not None and self.routes != 1:
            msg = "give `routes: N` (the first N picked) or `picks: [...]` (those), not both"
            raise ValueError(msg)
        if self.picks is not None and len(set(self.picks)) != len(self.picks):
            msg = f"`picks: {list(self.picks)}` names a route twice; list each once"
            raise ValueError(msg)
        return self

    @property
    def pick_indices(self) -> tuple[int, ...]:
        """Which picked routes this entry runs: ``picks``, or the first ``routes``."""
        return self.picks if self.picks is not None else tuple(range(self.routes))


class SuiteSettings(_Model):
    """What every world of the suite shares; the defaults are the demo's."""

    ads_epochs: int = pydantic.Field(30, ge=1, description="DAVE-2 training epochs")
    splat_steps: int | None = pydantic.Field(
        None, ge=1, description="splat training steps a chunk (null: the demo's preset)"
    )
    splat_init_points: int | None = pydantic.Field(
        None,
        ge=1,
        description="start each splat chunk from about this many of its points, thinned with "
        "the distance from its cameras (null: the preset's, 40,000 on a CPU, 250,000 on CUDA)",
    )
    splat_max_gaussians: int | None = pydantic.Field(
        None,
        ge=1,
        description="no more growth of a splat chunk once it has this many Gaussians, pruning "
        "goes on (null: the preset's, 120,000 on a CPU, 400,000 on CUDA)",
    )
    save_frames: bool = pydantic.Field(
        default=True, description="keep the closed-loop runs' frames (the failure pictures)"
    )
    profile_every_m: float = pydantic.Field(
        10.0, gt=0, description="the splat against the truth every this many metres of route"
    )
    run_seeds: Literal["per-world", "shared"] = pydantic.Field(
        "per-world",
        description="per-world: each world's runs are seeded from its label, so the streets' "
        "start offsets, speeds and steering noise are independent draws; shared: every world "
        "runs seeds 0 .. seeds-1 (the same draws on every street, as every suite run before "
        "this setting)",
    )


class Suite(_Model):
    """A benchmark suite: worlds, seeds, settings, time limit."""

    name: str | None = pydantic.Field(None, description="label; default: the suite file's stem")
    seeds: int = pydantic.Field(3, ge=1, le=50, description="closed-loop runs per method")
    worlds: tuple[SuiteWorld, ...] = pydantic.Field(min_length=1)
    settings: SuiteSettings = SuiteSettings()
    timeout_s: float | None = pydantic.Field(
        7200.0, gt=0, description="a world still running after this long fails as timed out"
    )


@dataclass(frozen=True)
class WorldSpec:
    """One world of a suite: the experiment ``cam2sim demo`` runs, with the suite's settings.

    Attributes:
        label: Readable name (``l-street``, ``munich-r2``).
        builtin: The built-in street, or None.
        osm: The OSM file as the suite writes it, or None.
        osm_path: That file resolved against the suite's folder.
        route: Two ``"LAT,LON"`` points, or None.
        pick: Which picked route of the extract (0 = the best).
        tuned: Looked at while tuning.
        seeds: Closed-loop runs per method.
        settings: The suite's shared settings.
    """

    label: str
    builtin: str | None
    osm: str | None
    osm_path: str | None
    route: tuple[str, str] | None
    pick: int
    tuned: bool
    seeds: int
    settings: SuiteSettings

    @property
    def spec_id(self) -> str:
        """The readable label and 10 hex digits of what the world runs."""
        content: dict[str, Any] = asdict(self)
        content.pop("osm_path")
        if self.osm is not None:  # the file's name: stable when the suite or the file moves
            content["osm"] = Path(self.osm).name
        content["settings"] = self.settings.model_dump(mode="json")
        digest = hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:10]
        return f"{self.label}-{digest}"

    @property
    def run_seed(self) -> int:
        """Seed of the world's first closed-loop run (its runs: this, this + 1, ...).

        With ``run_seeds: per-world`` a number below 10**6 from the label (CRC-32, the same on
        every machine and run), so two streets never share their runs' draws, and the Real
        column's spread on one street is not a copy of another's; ``shared``: 0.
        """
        if self.settings.run_seeds == "shared":
            return 0
        return zlib.crc32(self.label.encode()) % 1_000_000

    @property
    def needs_gpu(self) -> bool:
        """Every world trains a splat: one GPU a world on a cluster that has GPUs."""
        return True


def _suite_keys(loc: tuple[int | str, ...]) -> list[str]:
    del loc  # one list for every level: the suite's keys are distinct
    return [*Suite.model_fields, *SuiteWorld.model_fields, *SuiteSettings.model_fields]


def _message(err: pydantic.ValidationError, source: Path) -> str:
    return validation_message(
        err, source, what="benchmark suite", known=_suite_keys, doc="docs/bench.md"
    )


def load_suite(path: Path) -> Suite:
    """Read and validate a suite file.

    Raises:
        ConfigError: The file is missing, not YAML, or a key is invalid (the message names the
            file, the key and the fix).
    """
    path = Path(path)
    raw = read_yaml(path, missing="write a benchmark suite (see docs/bench.md)")
    if not isinstance(raw, dict):
        msg = f"{path}: expected a mapping with at least `worlds:`, found {type(raw).__name__}"
        raise ConfigError(msg)
    try:
        return Suite.model_validate(raw)
    except pydantic.ValidationError as err:
        raise ConfigError(_message(err, path)) from None


def _label(world: SuiteWorld, pick: int, used: set[str]) -> str:
    base: str
    if world.builtin is not None:
        base = world.builtin
    else:
        base = Path(world.osm or "osm").name.split(".")[0].lower()
        base = f"{base}-r{pick}" if world.route is None else f"{base}-route"
    label, n = base, 2
    while label in used:
        label, n = f"{base}-{n}", n + 1
    used.add(label)
    return label


def expand_suite(suite: Suite, base: Path) -> list[WorldSpec]:
    """Every world of ``suite`` in order; OSM files resolve against ``base``.

    Raises:
        ConfigError: An OSM file does not exist, or one world is listed twice.
    """
    specs: list[WorldSpec] = []
    used: set[str] = set()
    for world in suite.worlds:
        osm_path = None
        if world.osm is not None:
            p = Path(world.osm).expanduser()
            resolved = p if p.is_absolute() else (base / p).resolve()
            if not resolved.is_file():
                msg = f"suite world osm: {world.osm}: no such file ({resolved}); fix the path"
                raise ConfigError(msg)
            osm_path = str(resolved)
        specs.extend(
            WorldSpec(
                label=_label(world, pick, used),
                builtin=world.builtin,
                osm=world.osm,
                osm_path=osm_path,
                route=world.route,
                pick=pick,
                tuned=world.tuned if isinstance(world.tuned, bool) else pick in world.tuned,
                seeds=suite.seeds,
                settings=suite.settings,
            )
            for pick in world.pick_indices
        )
    ids = [s.spec_id.rsplit("-", 1)[1] for s in specs]
    if len(set(ids)) != len(ids):
        msg = "the suite lists the same world more than once; remove the repeated entry"
        raise ConfigError(msg)
    return specs
