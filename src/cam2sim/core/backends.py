"""Optional model backends: importing them with an install hint, loading ONNX and torch models.

Shared by every component that runs a user's model file: the learned detectors
(:mod:`cam2sim.detect.learned`) and the steering policies (:mod:`cam2sim.ads.policy`). Each
helper names the file or the package and the fix when something is missing or malformed.
"""

from __future__ import annotations

import importlib
import io
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from cam2sim.core.errors import BackendUnavailableError, ConfigError
from cam2sim.core.machine import available_cpus

if TYPE_CHECKING:
    from collections.abc import Callable
    from types import ModuleType

    import numpy.typing as npt

__all__ = [
    "ONNX_FLOAT_TYPES",
    "ONNX_HINT",
    "TORCH_HINT",
    "checked_size",
    "fixed_dim",
    "image_tensor",
    "load_torch_model",
    "local_file",
    "onnx_session",
    "require_module",
    "to_numpy",
    "torch_archive_kind",
]

ONNX_HINT: Final = "pip install 'cam2sim[detect]' (or: pip install onnxruntime)"
TORCH_HINT: Final = "pip install torch (CPU wheels suffice)"
ONNX_FLOAT_TYPES: Final[dict[str, type[np.floating[Any]]]] = {
    "tensor(float)": np.float32,
    "tensor(double)": np.float64,
}
"""numpy dtypes of the ONNX float input types."""


def onnx_session(
    model: Path | bytes, what: str, *, cuda: bool = True
) -> Any:  # Any: onnxruntime is untyped
    """An onnxruntime session of ``model`` (a file or its bytes), quiet and without spinning.

    Its threads are this process's CPUs (:func:`cam2sim.core.machine.available_cpus`), not
    every core of the machine.

    CUDA is used when ``cuda`` and onnxruntime has it, else the CPU. The intra-op threads do not
    spin-wait after a call: the models here run between renders on the same cores (a steering
    policy at 10 Hz, a detector per frame), and spinning threads took those cores from the
    renderer (a splat frame of the closed loop cost 2.5 times its time alone on 2 cores).

    Raises:
        BackendUnavailableError: onnxruntime is not installed.
        ConfigError: The model cannot be loaded (the message names the file).
    """
    ort = require_module("onnxruntime", ONNX_HINT, what)
    options = ort.SessionOptions()
    options.log_severity_level = 3
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.add_session_config_entry("session.inter_op.allow_spinning", "0")
    # As many threads as this process has CPUs (a Ray task's share, not the node's cores).
    options.intra_op_num_threads = available_cpus()
    options.inter_op_num_threads = 1
    available = set(ort.get_available_providers())
    cpu = ("CPUExecutionProvider",)
    wanted = ("CUDAExecutionProvider", *cpu) if cuda else cpu
    providers = [p for p in wanted if p in available]
    source = model if isinstance(model, bytes) else str(model)
    try:
        return ort.InferenceSession(source, sess_options=options, providers=providers)
    except Exception as err:  # onnxruntime's errors derive from Exception only
        name = "the exported model" if isinstance(model, bytes) else repr(str(model))
        msg = f"cannot load ONNX model {name}: {err}"
        raise ConfigError(msg) from err


def require_module(module: str, hint: str, what: str) -> ModuleType:
    """Import an optional backend, or say how to install it."""
    try:
        return importlib.import_module(module)
    except ImportError as err:
        msg = f"{what} needs {module.partition('.')[0]}, which is not installed ({err}); {hint}"
        raise BackendUnavailableError(msg) from None


def local_file(path: Path, what: str) -> Path:
    """``path`` when it is a local file, else a ConfigError naming ``what`` and the fix."""
    path = Path(path)
    if not path.is_file():
        msg = f"{what} {str(path)!r} does not exist; give the path of a local file"
        raise ConfigError(msg)
    return path


def to_numpy(value: Any) -> npt.NDArray[Any]:  # Any: torch tensors, numpy arrays or lists
    """A model output as a numpy array (torch tensors detached and moved to the host)."""
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    return np.asarray(value)


def image_tensor(image: npt.NDArray[np.uint8]) -> npt.NDArray[np.float32]:
    """``(H, W, 3)`` uint8 to ``(1, 3, H, W)`` float32 in ``[0, 1]``."""
    return np.ascontiguousarray(image.transpose(2, 0, 1)[None], dtype=np.float32) / 255.0


def checked_size(size: tuple[int, int] | None) -> tuple[int, int] | None:
    """A model's ``(width, height)`` input size, checked (None: the model's own)."""
    if size is not None and (len(size) != 2 or min(size) < 1):
        msg = f"input_size must be (width, height) in pixels, got {size!r}"
        raise ConfigError(msg)
    return None if size is None else (int(size[0]), int(size[1]))


def fixed_dim(dim: object) -> int | None:
    """An ONNX input dimension when it is fixed (a positive int), else None (dynamic)."""
    return dim if isinstance(dim, int) and dim > 0 else None


def torch_archive_kind(path: Path) -> str:
    """``torchscript`` (torch.jit.save) or ``export`` (torch.export.save) archive, by contents."""
    try:
        with zipfile.ZipFile(path) as archive:
            names = archive.namelist()
    except (zipfile.BadZipFile, OSError):
        names = []
    if any(n.endswith("/archive_format") for n in names):
        return "export"
    if any("/code/" in n or n.endswith("/constants.pkl") for n in names):
        return "torchscript"
    msg = (
        f"{path.name} is not a TorchScript or torch.export archive (a plain state dict holds "
        "weights only); save the whole model with torch.export.save(torch.export.export(model, "
        "example_inputs), path) or torch.jit.save(torch.jit.script(model), path)"
    )
    raise ConfigError(msg)


def load_torch_model(
    path: Path, device: str
) -> tuple[Callable[..., Any], int, tuple[int, int] | None]:
    """Load a ``torch.export`` program or a TorchScript archive.

    Returns:
        The callable module on ``device``, its number of inputs, and the ``(width, height)``
        its first input declares (None when dynamic or unknown).

    Raises:
        ConfigError: The file is neither, or cannot be loaded.
    """
    import warnings  # noqa: PLC0415  (only torch's deprecations need it)

    torch = require_module("torch", TORCH_HINT, "torch models")
    declared: tuple[int, int] | None = None
    try:
        if torch_archive_kind(path) == "export":
            program = torch.export.load(io.BytesIO(path.read_bytes()))
            user = set(program.graph_signature.user_inputs)
            shapes = [
                tuple(n.meta["val"].shape)
                for n in program.graph.nodes
                if n.op == "placeholder" and n.name in user and "val" in n.meta
            ]
            if shapes and len(shapes[0]) == 4 and all(type(d) is int for d in shapes[0][2:]):
                declared = (int(shapes[0][3]), int(shapes[0][2]))
            module: Callable[..., Any] = program.module().to(device)
            return module, len(user), declared
        with warnings.catch_warnings():
            # torch >= 2.10 deprecates TorchScript; loading a user's archive still works.
            warnings.filterwarnings("ignore", r".*torch\.jit", DeprecationWarning)
            script = torch.jit.load(str(path), map_location=device)
    except (RuntimeError, ValueError, KeyError, OSError) as err:
        msg = f"cannot load torch model {str(path)!r}: {err}"
        raise ConfigError(msg) from err
    return script, len(script.forward.schema.arguments) - 1, None
