"""ONNX export of a DAVE-2 network, checked against torch with onnxruntime.

The exported graph takes ``image``: float32 ``(1, 3, h, w)`` pixels in ``[0, 255]`` (the
output of :func:`cam2sim.ads.dave2.preprocess`) and returns ``steering`` ``(1, 1)``; opset 17.
Its metadata props carry the preprocessing, so :class:`~cam2sim.ads.policy.ModelPolicy` crops
and scales camera frames as training did:

- ``cam2sim.dave2``: the :class:`~cam2sim.ads.dave2.Dave2Config` JSON (read by the policy);
- ``cam2sim.source_size``, ``cam2sim.crop_rows``, ``cam2sim.crop_cols``,
  ``cam2sim.input_size``, ``cam2sim.pixel_range``: the same, for people reading the file with
  other tools.

The exporter is torch's TorchScript-based one (``dynamo=False``): the dynamo exporter needs
``onnxscript``, which cam2sim does not depend on. Needs ``onnx`` and ``onnxruntime``.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Final

import numpy as np
import torch

from cam2sim.ads.dave2 import METADATA_KEY, Dave2Config
from cam2sim.core.backends import onnx_session, require_module
from cam2sim.core.errors import StageError
from cam2sim.core.files import write_bytes_atomic
from cam2sim.core.schema import Artifact

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

__all__ = ["OPSET", "PARITY_TOLERANCE", "ExportReport", "export_onnx"]

OPSET: Final = 17
PARITY_TOLERANCE: Final = 1e-3
"""Largest torch/onnxruntime difference accepted, in the steering unit (float32 round-off)."""
_HINT: Final = "pip install onnx onnxruntime"


class ExportReport(Artifact):
    """``export.json``: the exported file and how closely onnxruntime reproduces torch.

    Differences are the largest absolute steering difference over the inputs, in the signal's
    unit; ``max_abs_diff_real`` is None when no real frames were given.
    """

    path: str
    opset: int
    input_name: str
    input_shape: tuple[int, int, int, int]
    output_name: str
    metadata: dict[str, str]
    random_inputs: int
    real_inputs: int
    max_abs_diff_random: float
    max_abs_diff_real: float | None
    onnxruntime_version: str


def _metadata(config: Dave2Config) -> dict[str, str]:
    (sw, sh), (top, bottom), (iw, ih) = config.source_size, config.crop_rows, config.input_size
    return {
        METADATA_KEY: config.to_json(),
        "cam2sim.source_size": f"{sw}x{sh}",
        "cam2sim.crop_rows": f"{top},{bottom}",
        "cam2sim.crop_cols": ",".join(str(c) for c in config.crop_cols or (0, sw)),
        "cam2sim.input_size": f"{iw}x{ih}",
        "cam2sim.pixel_range": "0..255",
    }


def _onnx_bytes(model: torch.nn.Module, config: Dave2Config) -> bytes:
    import tempfile  # noqa: PLC0415
    from pathlib import Path  # noqa: PLC0415

    iw, ih = config.input_size
    with tempfile.TemporaryDirectory(prefix="cam2sim-onnx-") as tmp, warnings.catch_warnings():
        # torch 2.9+ flags the TorchScript-based exporter; the dynamo one needs onnxscript.
        warnings.filterwarnings("ignore", r".*legacy TorchScript-based ONNX", DeprecationWarning)
        warnings.filterwarnings("ignore", r"The feature will be removed", DeprecationWarning)
        path = Path(tmp) / "model.onnx"
        torch.onnx.export(
            model,
            (torch.zeros(1, 3, ih, iw),),
            path,
            input_names=["image"],
            output_names=["steering"],
            opset_version=OPSET,
            dynamo=False,
        )
        return path.read_bytes()


def export_onnx(
    model: torch.nn.Module,
    config: Dave2Config,
    out_path: Path,
    *,
    real_inputs: npt.NDArray[np.float32] | None = None,
    random_inputs: int = 8,
    seed: int = 0,
) -> ExportReport:
    """Export ``model`` to ``out_path`` (atomically) and compare onnxruntime with torch.

    Args:
        model: A DAVE-2 network (:func:`~cam2sim.ads.dave2.build_dave2`); put in eval mode.
        config: Its preprocessing, written into the file's metadata.
        out_path: The ``.onnx`` file.
        real_inputs: ``(N, 3, h, w)`` preprocessed frames for the parity check.
        random_inputs: How many uniform random inputs in ``[0, 255]`` to compare.
        seed: Seeds the random inputs.

    Raises:
        BackendUnavailableError: onnx or onnxruntime is missing.
        StageError: onnxruntime differs from torch by more than :data:`PARITY_TOLERANCE`.
    """
    onnx = require_module("onnx", _HINT, "ONNX export")
    ort = require_module("onnxruntime", _HINT, "ONNX export")
    model = model.cpu().eval()
    proto = onnx.load_from_string(_onnx_bytes(model, config))
    meta = _metadata(config)
    for key, value in meta.items():
        prop = proto.metadata_props.add()
        prop.key, prop.value = key, value
    data = proto.SerializeToString()
    iw, ih = config.input_size
    rng = np.random.default_rng(seed)
    rand = rng.uniform(0.0, 255.0, (random_inputs, 3, ih, iw)).astype(np.float32)
    real = np.zeros((0, 3, ih, iw), np.float32) if real_inputs is None else real_inputs
    session = onnx_session(data, "the ONNX export's parity check", cuda=False)

    def max_diff(x: npt.NDArray[np.float32]) -> float:
        worst = 0.0
        with torch.inference_mode():
            for one in x.astype(np.float32)[:, None]:
                ref = model(torch.from_numpy(one)).numpy()
                (got,) = session.run(["steering"], {"image": one})
                worst = max(worst, float(np.max(np.abs(np.asarray(got) - ref))))
        return worst

    diff_random = max_diff(rand)
    diff_real = max_diff(real) if len(real) else None
    worst = max(diff_random, diff_real or 0.0)
    if not worst <= PARITY_TOLERANCE:
        msg = (
            f"onnxruntime differs from torch by {worst:.3g} (> {PARITY_TOLERANCE}); the export is "
            "wrong: report it with the model and torch/onnxruntime versions"
        )
        raise StageError(msg)
    write_bytes_atomic(out_path, data)
    return ExportReport(
        path=str(out_path),
        opset=OPSET,
        input_name="image",
        input_shape=(1, 3, ih, iw),
        output_name="steering",
        metadata=meta,
        random_inputs=len(rand),
        real_inputs=len(real),
        max_abs_diff_random=diff_random,
        max_abs_diff_real=diff_real,
        onnxruntime_version=str(ort.__version__),
    )
