"""Optional backends: missing packages and files are named with the fix."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest

from cam2sim.core.backends import (
    checked_size,
    fixed_dim,
    image_tensor,
    local_file,
    require_module,
    to_numpy,
    torch_archive_kind,
)
from cam2sim.core.errors import BackendUnavailableError, ConfigError

if TYPE_CHECKING:
    from pathlib import Path


def test_a_missing_package_names_itself_and_the_install() -> None:
    with pytest.raises(BackendUnavailableError, match=r"thing needs no_such_pkg.*pip install x"):
        require_module("no_such_pkg.sub", "pip install x", "the thing")
    assert require_module("json", "", "json").dumps([1]) == "[1]"


def test_files_sizes_and_dims_are_checked(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"ONNX model '.*nope.onnx' does not exist"):
        local_file(tmp_path / "nope.onnx", "ONNX model")
    weights = tmp_path / "w.pt"
    weights.write_bytes(b"not an archive")
    assert local_file(weights, "torch model") == weights
    with pytest.raises(ConfigError, match=r"w\.pt is not a TorchScript or torch\.export archive"):
        torch_archive_kind(weights)
    assert checked_size((200, 66)) == (200, 66)
    assert checked_size(None) is None
    with pytest.raises(ConfigError, match="input_size must be"):
        checked_size((0, 66))
    assert fixed_dim(3) == 3
    assert fixed_dim("batch") is None
    assert fixed_dim(-1) is None


def test_images_and_outputs_become_model_arrays() -> None:
    image = np.full((2, 3, 3), 255, dtype=np.uint8)
    x = image_tensor(image)
    assert x.shape == (1, 3, 2, 3)
    assert x.dtype == np.float32
    assert float(x.max()) == 1.0
    assert to_numpy([1, 2]).tolist() == [1, 2]
