from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cam2sim.core.errors import WorkspaceError
from cam2sim.core.table import read_table, write_table


def test_table_round_trips_integer_nanoseconds_exactly(tmp_path: Path) -> None:
    stamps = np.array([1771283861205308914, 1771283861215190887], dtype=np.int64)
    write_table(tmp_path / "t.csv", {"frame": [0, 1], "stamp_ns": stamps, "x": [0.1234567, 2.0]})
    t = read_table(tmp_path / "t.csv")
    np.testing.assert_array_equal(t["stamp_ns"], stamps)
    assert t["stamp_ns"].dtype == np.int64
    np.testing.assert_allclose(t["x"], [0.123457, 2.0])


def test_table_precision_is_per_column(tmp_path: Path) -> None:
    write_table(tmp_path / "t.csv", {"q": [0.123456789123]}, precision={"q": 9})
    assert (tmp_path / "t.csv").read_text().splitlines()[1] == "0.123456789"


def test_empty_table_keeps_its_columns(tmp_path: Path) -> None:
    write_table(tmp_path / "t.csv", {"stamp_ns": np.zeros(0, np.int64), "x": np.zeros(0)})
    t = read_table(tmp_path / "t.csv")
    assert set(t) == {"stamp_ns", "x"}
    assert t["x"].shape == (0,)


def test_columns_of_different_length_are_rejected(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="differ in length"):
        write_table(tmp_path / "t.csv", {"a": [1.0], "b": [1.0, 2.0]})


def test_non_numeric_value_names_the_column(tmp_path: Path) -> None:
    (tmp_path / "t.csv").write_text("x,y\n1.0,abc\n")
    with pytest.raises(WorkspaceError, match="column 'y'"):
        read_table(tmp_path / "t.csv")
