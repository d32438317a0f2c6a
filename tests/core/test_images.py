"""Reading and writing images the one way the packages compare them."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.core.errors import WorkspaceError
from cam2sim.core.images import read_mask, read_rgb, write_rgb

if TYPE_CHECKING:
    from pathlib import Path


@pytest.mark.parametrize("suffix", [".png", ".webp"])
def test_written_images_read_back_to_the_same_pixels(tmp_path: Path, suffix: str) -> None:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, size=(37, 53, 3), dtype=np.uint8)  # noise: no lossy shortcut
    path = tmp_path / "sub" / f"frame{suffix}"
    write_rgb(path, image)
    np.testing.assert_array_equal(read_rgb(path), image)
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary left behind


def test_writing_a_non_rgb_array_is_refused_and_writes_nothing(tmp_path: Path) -> None:
    with pytest.raises(WorkspaceError, match=r"need \(H, W, 3\) uint8"):
        write_rgb(tmp_path / "f.png", np.zeros((4, 4), dtype=np.uint8))
    with pytest.raises(WorkspaceError, match="uint8"):
        write_rgb(tmp_path / "f.png", np.zeros((4, 4, 3), dtype=np.float32))
    assert not any(tmp_path.iterdir())


def test_unreadable_files_name_themselves(tmp_path: Path) -> None:
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"not an image")
    with pytest.raises(WorkspaceError, match="broken.png"):
        read_rgb(bad)
    with pytest.raises(WorkspaceError, match="broken.png"):
        read_mask(bad)
