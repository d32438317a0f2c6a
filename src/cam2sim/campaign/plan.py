"""The campaign plan (``PLAN.yaml``) and its expansion into run specs.

A plan names workspaces (recordings), policies, cameras, seeds, start perturbations and a number
of repetitions; every combination is one :class:`RunSpec`, one closed-loop run. A spec's id is a
hash of what it runs, so the same plan always expands to the same ids (the campaign state keys
on them to resume).
"""

from __future__ import annotations

import collections
import difflib
import hashlib
import itertools
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Literal

import pydantic

from cam2sim.core.config import read_yaml
from cam2sim.core.errors import ConfigError
from cam2sim.core.workspace import Workspace

if TYPE_CHECKING:
    from collections.abc import Callable

__all__ = [
    "WORKSPACE_MODEL",
    "DriveSettings",
    "Perturbation",
    "Plan",
    "RunSpec",
    "expand",
    "load_plan",
    "validation_message",
]

CampaignCamera = Literal["raster", "splat", "truth", "none"]

WORKSPACE_MODEL: Final = "workspace-model"
"""The policy that is each workspace's own DAVE-2 (``WS/ads/dave2.onnx``, what ``cam2sim ads``
trained on that recording): a campaign over many recordings, each driven by its own model."""


class _Model(pydantic.BaseModel):
    model_config = pydantic.ConfigDict(extra="forbid", frozen=True)


def _listed(value: Any) -> Any:
    """A scalar where a list is accepted becomes a one-element list."""
    return value if isinstance(value, list | tuple) else [value]


class Perturbation(_Model):
    """Start perturbations; each list is a sweep and the lists combine (cartesian product)."""

    lateral_m: tuple[float, ...] = pydantic.Field(
        (0.0,), description="start moved this far left (negative: right) of the recorded start"
    )
    heading_deg: tuple[float, ...] = pydantic.Field(
        (0.0,), description="start heading turned this far counter-clockwise, degrees"
    )
    speed_kmh: tuple[float | None, ...] = pydantic.Field(
        (None,), description="target speed, km/h; null holds the recorded start speed"
    )

    @pydantic.field_validator("lateral_m", "heading_deg", "speed_kmh", mode="before")
    @classmethod
    def _as_list(cls, value: Any) -> Any:
        return _listed(value)

    @pydantic.field_validator("lateral_m", "heading_deg")
    @classmethod
    def _finite(cls, value: tuple[float, ...]) -> tuple[float, ...]:
        if not all(math.isfinite(v) for v in value):
            msg = "values must be finite numbers"
            raise ValueError(msg)
        return value

    @pydantic.field_validator("speed_kmh")
    @classmethod
    def _speeds(cls, value: tuple[float | None, ...]) -> tuple[float | None, ...]:
        if any(v is not None and not (math.isfinite(v) and v >= 0) for v in value):
            msg = "speeds must be >= 0 km/h (or null for the recorded start speed)"
            raise ValueError(msg)
        return value


class DriveSettings(_Model):
    """Settings every run of the campaign shares (those of ``cam2sim drive``)."""

    policy_every: int = pydantic.Field(3, ge=1, description="the policy answers every n-th step")
    image_size: tuple[int, int] | None = pydantic.Field(
        None, description="camera [width, height]; null keeps the calibrated size"
    )
    max_steps: int = pydantic.Field(100_000, ge=1)
    save_frames: bool = False
    video: bool = False
    steering_noise_std: float = pydantic.Field(
        0.0, ge=0, description="builtin simulator steering noise (what makes seeds differ)"
    )
    recorded_speed: bool = pydantic.Field(
        default=False,
        description="follow the recorded speed along the route (else hold the start's)",
    )
    judge: Literal["auto", "map", "truth"] = pydantic.Field(
        default="auto",
        description="where leaving the road and collisions are judged: auto (the workspace's "
        "ground-truth world when it has one, as cam2sim run does, else the map), map or truth",
    )

    @pydantic.field_validator("image_size")
    @classmethod
    def _size(cls, value: tuple[int, int] | None) -> tuple[int, int] | None:
        if value is not None and min(value) < 1:
            msg = "image_size takes [width, height] in pixels, both >= 1"
            raise ValueError(msg)
        return value


class Plan(_Model):
    """A campaign: what to run, how often, and how long a run may take."""

    name: str | None = pydantic.Field(None, description="label; default: the plan file's stem")
    output: str | None = pydantic.Field(
        None, description="campaign folder (state, logs, summary); default PLAN_STEM-campaign/"
    )
    workspaces: tuple[str, ...] = pydantic.Field(
        min_length=1, description="workspace folders, relative to the plan file or absolute"
    )
    policies: tuple[str, ...] = pydantic.Field(
        ("pure-pursuit",),
        min_length=1,
        description="pure-pursuit, constant:VALUE, tcp://HOST:PORT, a model file, or "
        "workspace-model (each workspace's own ads/dave2.onnx)",
    )
    cameras: tuple[CampaignCamera, ...] = pydantic.Field(("raster",), min_length=1)
    seeds: tuple[int, ...] = pydantic.Field((0,), min_length=1)
    repetitions: int = pydantic.Field(1, ge=1, description="runs of every combination")
    perturbations: tuple[Perturbation, ...] = pydantic.Field((Perturbation(),), min_length=1)
    drive: DriveSettings = DriveSettings()
    timeout_s: float | None = pydantic.Field(
        600.0, gt=0, description="a run still going after this long fails as timed out"
    )

    @pydantic.field_validator("workspaces", "policies", "seeds", "cameras", mode="before")
    @classmethod
    def _as_list(cls, value: Any) -> Any:
        return _listed(value)

    @pydantic.field_validator("perturbations", mode="before")
    @classmethod
    def _perturbations(cls, value: Any) -> Any:
        return _listed(value)


@dataclass(frozen=True)
class RunSpec:
    """One closed-loop run of a campaign.

    Attributes:
        workspace: The workspace as the plan names it (the recording's label).
        workspace_path: The workspace folder, resolved against the plan's folder.
        policy: Policy spec (``cam2sim drive --policy``) as the plan writes it.
        policy_arg: The policy spec with a model file resolved against the plan's folder.
        camera: The camera the policy sees.
        seed: Simulator seed.
        repetition: Index of the repetition (0-based).
        lateral_m: Start moved left by this much.
        heading_deg: Start heading turned by this much.
        speed_kmh: Target speed; None holds the recorded start speed.
        drive: The shared drive settings.
    """

    workspace: str
    workspace_path: str
    policy: str
    policy_arg: str
    camera: CampaignCamera
    seed: int
    repetition: int
    lateral_m: float
    heading_deg: float
    speed_kmh: float | None
    drive: DriveSettings

    @property
    def spec_id(self) -> str:
        """A deterministic id: a readable prefix and the hash of what the run does."""
        content = asdict(self)
        for resolved in ("workspace_path", "policy_arg"):  # as the plan writes them: stable
            content.pop(resolved)  # when a campaign moves
        content["drive"] = self.drive.model_dump(mode="json")
        for key, default in (("recorded_speed", False), ("judge", "auto")):
            if content["drive"][key] == default:  # added later: the ids of older plans stay
                content["drive"].pop(key)
        digest = hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()[:12]
        return f"{Path(self.workspace).name}-{self.camera}-s{self.seed}-r{self.repetition}-{digest}"

    @property
    def needs_gpu(self) -> bool:
        """Whether the run renders with the splat camera (a GPU on a cluster)."""
        return self.camera == "splat"


def validation_message(
    err: pydantic.ValidationError,
    source: Path,
    *,
    what: str,
    known: Callable[[tuple[int | str, ...]], list[str]],
    doc: str,
) -> str:
    """One line per invalid key of a YAML file: the key, what is wrong, and the fix.

    ``what`` names the file's kind (``campaign plan``); ``known(loc)`` the keys a misspelt one
    at ``loc`` is matched against; ``doc`` where an example is.
    """
    parts = []
    for item in err.errors():
        loc = ".".join(str(p) for p in item["loc"]) or "<root>"
        if item["type"] == "extra_forbidden":
            close = difflib.get_close_matches(str(item["loc"][-1]), known(item["loc"]), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            parts.append(f"{loc}: unknown key{hint}; remove it or fix its spelling")
        elif item["type"] == "missing":
            parts.append(f"{loc}: missing; add it (see {doc})")
        else:
            parts.append(f"{loc}: {item['msg']} (found {item.get('input')!r})")
    return f"{source}: invalid {what}: " + "; ".join(parts)


def _plan_keys(loc: tuple[int | str, ...]) -> list[str]:
    return list(Plan.model_fields) if len(loc) == 1 else []


def _message(err: pydantic.ValidationError, source: Path) -> str:
    return validation_message(
        err, source, what="campaign plan", known=_plan_keys, doc="the example plan in the README"
    )


def load_plan(path: Path) -> Plan:
    """Read and validate a campaign plan.

    Raises:
        ConfigError: The file is missing, not YAML, or a key is invalid; the message names the
            file, the key and the fix.
    """
    path = Path(path)
    raw = read_yaml(path, missing="write a campaign plan (see the README's example)")
    if not isinstance(raw, dict):
        msg = f"{path}: expected a mapping with at least `workspaces:`, found {type(raw).__name__}"
        raise ConfigError(msg)
    try:
        return Plan.model_validate(raw)
    except pydantic.ValidationError as err:
        raise ConfigError(_message(err, path)) from None


def _resolve(path: str, base: Path) -> str:
    p = Path(path).expanduser()
    return str(p if p.is_absolute() else (base / p).resolve())


def expand(plan: Plan, base: Path) -> list[RunSpec]:
    """Every run of ``plan``, in a fixed order; workspaces resolve against ``base``.

    Raises:
        ConfigError: Two combinations are the same run (a value listed twice), or a workspace
            has no model for the ``workspace-model`` policy.
    """
    specs: list[RunSpec] = []
    for ws, policy, camera, pert, seed, rep in itertools.product(
        plan.workspaces,
        plan.policies,
        plan.cameras,
        plan.perturbations,
        plan.seeds,
        range(plan.repetitions),
    ):
        resolved = _resolve(ws, base)
        policy_arg = policy
        if policy == WORKSPACE_MODEL:  # each recording's own DAVE-2
            model = Workspace(Path(resolved)).ads_files.onnx
            if not model.is_file():
                msg = (
                    f"policy {WORKSPACE_MODEL}: workspace {ws} has no {model.name} in "
                    f"{model.parent}; train it with `cam2sim ads train {ws}` (or name a model file)"
                )
                raise ConfigError(msg)
            policy_arg = str(model)
        elif not policy.startswith(("pure-pursuit", "constant:", "tcp://")):
            policy_arg = _resolve(policy, base)  # a model file
        for lateral, heading, speed in itertools.product(
            pert.lateral_m, pert.heading_deg, pert.speed_kmh
        ):
            specs.append(
                RunSpec(
                    ws, resolved, policy, policy_arg, camera, seed, rep, lateral, heading, speed,
                    plan.drive,
                )
            )  # fmt: skip
    counts = collections.Counter(s.spec_id for s in specs)
    twice = sorted(i for i, n in counts.items() if n > 1)
    if twice:
        msg = f"the plan lists the same run more than once ({', '.join(twice[:3])}); "
        msg += "remove the repeated value (use repetitions: N to repeat runs)"
        raise ConfigError(msg)
    return specs
