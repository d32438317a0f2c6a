"""Semantic classes and the palette of colours that mean them (road, car, background, ...).

The vocabulary of label images, shared by the renderers that draw them
(:mod:`cam2sim.render.raster`) and the metrics that compare them (:mod:`cam2sim.metrics.semantic`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np
import yaml

from cam2sim.core.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    import numpy.typing as npt

__all__ = ["BACKGROUND", "RGB", "Palette", "SemanticClass"]

RGB = tuple[int, int, int]
"""An 8-bit RGB colour."""

BACKGROUND: Final = "background"


@dataclass(frozen=True)
class SemanticClass:
    """A class of the palette and the colours that mean it."""

    name: str
    colors: tuple[RGB, ...]


@dataclass(frozen=True)
class Palette:
    """Colours of the classes compared; every other colour is background.

    Attributes:
        classes: The classes in label order (label ``i + 1``; background is label 0).
        tolerance: A pixel matches a colour when every channel differs by at most this much
            (0: exact match). With a tolerance, a pixel near several colours takes the nearest
            (largest channel difference smallest; ties go to the earlier class).
    """

    classes: tuple[SemanticClass, ...]
    tolerance: int = 0

    def __post_init__(self) -> None:
        names = [c.name for c in self.classes]
        if not names or len(set(names)) != len(names) or BACKGROUND in names:
            msg = f"palette classes must be non-empty, unique and not {BACKGROUND!r}; got {names}"
            raise ConfigError(msg)
        if not 0 <= self.tolerance <= 255:
            msg = f"palette tolerance must be within 0..255, got {self.tolerance}"
            raise ConfigError(msg)
        seen: dict[RGB, str] = {}
        for cls in self.classes:
            if not cls.colors:
                msg = f"palette class {cls.name!r} has no colour"
                raise ConfigError(msg)
            for rgb in cls.colors:
                if len(rgb) != 3 or not all(isinstance(v, int) and 0 <= v <= 255 for v in rgb):
                    msg = f"palette class {cls.name!r}: {rgb!r} is not an RGB colour (0..255)"
                    raise ConfigError(msg)
                if rgb in seen:
                    msg = f"colour {rgb} is in both {seen[rgb]!r} and {cls.name!r}"
                    raise ConfigError(msg)
                seen[rgb] = cls.name

    @classmethod
    def cityscapes(cls) -> Palette:
        """Return the default palette: Cityscapes road (128, 64, 128) and car (0, 0, 142)."""
        return cls(
            classes=(
                SemanticClass("road", ((128, 64, 128),)),
                SemanticClass("car", ((0, 0, 142),)),
            )
        )

    @classmethod
    def from_mapping(
        cls, classes: Mapping[str, Sequence[int] | Sequence[Sequence[int]]], *, tolerance: int = 0
    ) -> Palette:
        """Build a palette from ``{name: [r, g, b]}`` or ``{name: [[r, g, b], ...]}``."""
        parsed = []
        for name, value in classes.items():
            parsed.append(SemanticClass(str(name), _colors(str(name), value)))
        return cls(classes=tuple(parsed), tolerance=int(tolerance))

    @classmethod
    def from_yaml(cls, path: Path) -> Palette:
        """Read a palette YAML file.

        The file holds ``classes`` (``{name: [r, g, b]}`` or ``{name: [[r, g, b], ...]}``, in
        label order) and optionally ``tolerance`` (default 0).

        Raises:
            ConfigError: The file is missing, not YAML, or malformed.
        """
        path = Path(path)
        try:
            raw = yaml.safe_load(path.read_text(encoding="utf-8"))
        except (OSError, yaml.YAMLError, UnicodeDecodeError) as err:
            msg = f"cannot read palette {path}: {err}"
            raise ConfigError(msg) from None
        if not isinstance(raw, dict) or not isinstance(raw.get("classes"), dict):
            msg = f"{path}: expected a mapping with 'classes: {{name: [r, g, b], ...}}'"
            raise ConfigError(msg)
        unknown = set(raw) - {"classes", "tolerance"}
        if unknown:
            msg = f"{path}: unknown keys {sorted(unknown)}; expected 'classes' and 'tolerance'"
            raise ConfigError(msg)
        try:
            return cls.from_mapping(raw["classes"], tolerance=int(raw.get("tolerance", 0)))
        except (ConfigError, TypeError, ValueError) as err:
            msg = f"{path}: {err}"
            raise ConfigError(msg) from None

    @property
    def names(self) -> tuple[str, ...]:
        """Class names by label: ``("background", *classes)``."""
        return (BACKGROUND, *(c.name for c in self.classes))

    def display_colors(self) -> npt.NDArray[np.uint8]:
        """Return ``(K, 3)`` uint8 drawing colours by label: black, then each class's 1st colour."""
        return np.asarray([(0, 0, 0), *(c.colors[0] for c in self.classes)], dtype=np.uint8)


def _colors(name: str, value: object) -> tuple[RGB, ...]:
    """Parse ``[r, g, b]`` or ``[[r, g, b], ...]`` of class ``name``."""
    bad = f"palette class {name!r}: {value!r} is not [r, g, b] or a list of them"
    if not isinstance(value, (list, tuple)) or not value:
        raise ConfigError(bad)
    rows = value if isinstance(value[0], (list, tuple)) else [value]
    out = []
    for row in rows:
        if not isinstance(row, (list, tuple)) or len(row) != 3:
            raise ConfigError(bad)
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in row):
            raise ConfigError(bad)
        out.append((int(row[0]), int(row[1]), int(row[2])))
    return tuple(out)
