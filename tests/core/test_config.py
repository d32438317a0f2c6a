from __future__ import annotations

from pathlib import Path

import pytest

from cam2sim.core.config import (
    AXIS_CONVENTION_YAW_OFFSET,
    AxisConvention,
    Config,
    SignalConfig,
    TopicsConfig,
    config_to_yaml,
    load_config,
    save_config,
)
from cam2sim.core.errors import ConfigError


def test_config_round_trips_through_yaml(tmp_path: Path) -> None:
    cfg = Config(
        topics=TopicsConfig(
            camera="/cam", pose="/odom", signals={"steering": SignalConfig(topic="/s")}
        )
    )
    save_config(cfg, tmp_path / "config.yaml")
    assert load_config(tmp_path / "config.yaml") == cfg


def test_config_yaml_explains_the_conventions() -> None:
    text = config_to_yaml(Config())
    assert "axis_convention" in text
    assert "x_left" in text
    assert text.startswith("#")


def test_unknown_key_names_the_key_and_suggests_the_spelling(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("topics:\n  camra: /cam\n")
    with pytest.raises(
        ConfigError, match=r"topics\.camra: unknown key \(did you mean 'camera'\?\)"
    ):
        load_config(tmp_path / "c.yaml")


def test_bad_value_names_the_key_and_the_value_found(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("pose:\n  axis_convention: left\n")
    with pytest.raises(ConfigError, match=r"pose\.axis_convention.*x_left.*found 'left'"):
        load_config(tmp_path / "c.yaml")


def test_out_of_range_value_is_rejected(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("frames:\n  jpeg_quality: 0\n")
    with pytest.raises(ConfigError, match=r"frames\.jpeg_quality"):
        load_config(tmp_path / "c.yaml")


def test_malformed_yaml_says_to_fix_the_syntax(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("topics: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(tmp_path / "c.yaml")


def test_missing_config_says_how_to_create_one(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cam2sim init"):
        load_config(tmp_path / "nope.yaml")


def test_newer_schema_version_is_rejected(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("schema_version: 99\n")
    with pytest.raises(ConfigError, match="schema_version 99"):
        load_config(tmp_path / "c.yaml")


def test_tf_pose_source_requires_the_frames(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("pose:\n  source: tf\n")
    with pytest.raises(ConfigError, match=r"pose\.tf"):
        load_config(tmp_path / "c.yaml")


def test_empty_file_gives_the_defaults(tmp_path: Path) -> None:
    (tmp_path / "c.yaml").write_text("")
    assert load_config(tmp_path / "c.yaml") == Config()


def test_x_left_convention_turns_heading_by_minus_90_degrees() -> None:
    assert AXIS_CONVENTION_YAW_OFFSET[AxisConvention.X_LEFT] == pytest.approx(-1.5707963267948966)
    assert set(AXIS_CONVENTION_YAW_OFFSET) == set(AxisConvention)
