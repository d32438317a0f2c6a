"""Steering policies: one observation in, one steering command out.

A closed-loop run calls :meth:`SteeringPolicy.predict` at the policy's own rate with an
:class:`Observation` (the camera frame, when the run has a camera, and the vehicle state) and
applies the returned command, in the recording's steering unit, through the run's
:class:`~cam2sim.sim.interface.SteeringCalibration`. :func:`load_policy` builds one from a spec:

- ``pure-pursuit``: :class:`PurePursuitPolicy`, follows the recorded route (uses the map, not
  the camera): the reference driver and the loop's self-test.
- ``constant:VALUE``: :class:`ConstantPolicy`, always ``VALUE`` (diagnosis, e.g. hard right).
- a model file (``.onnx``, ``.pt``, ``.pth``, ``.ts``, ``.h5``): :class:`ModelPolicy`.
- ``tcp://HOST:PORT``: :class:`RemotePolicy`, a policy served by another process
  (:mod:`cam2sim.ads.serve`).

Tensor contract of image models (:class:`ModelPolicy`)
------------------------------------------------------
- One input (any name; ``image`` by convention): float32 ``(1, 3, H, W)``, RGB, values
  ``pixel / 255`` in ``[0, 1]``, no mean/std normalisation (put it inside the model). The
  camera frame is resized to the model's declared fixed ``H`` and ``W`` with ``cv2.INTER_AREA``;
  a model with a dynamic size (and every TorchScript model) needs ``input_size=(W, H)``.
  Exception: ONNX models exported by cam2sim (``cam2sim.dave2`` metadata) and Keras ``.h5``
  models get the DAVE-2 preprocessing (resize, crop, resize; values in ``[0, 255]``; see
  :mod:`cam2sim.ads.dave2`).
- One output (any name; ``steering`` is picked when there are several): a single value, shape
  ``()``, ``(1,)`` or ``(1, 1)``, the steering command in the recording's steering unit.
- ONNX models run with onnxruntime; torch models are ``torch.export.save`` programs or
  TorchScript archives (``torch.jit.save``) with ``forward(image)`` returning a tensor (or a
  one-element tuple, or a dict with ``steering``). A model that breaks the contract raises
  :class:`~cam2sim.core.errors.ConfigError` naming the inputs and outputs it actually has.

Remote policies (``tcp://HOST:PORT``)
-------------------------------------
:class:`RemotePolicy` sends each camera frame to a server in another process and reads back
``steering,throttle``: the published tool's protocol, served by :mod:`cam2sim.ads.serve`
(``cam2sim ads serve``; :class:`~cam2sim.ads.serve.PolicyServer`) or by the published server.
"""

from __future__ import annotations

import logging
import math
import socket
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final, Protocol, cast, runtime_checkable

import cv2
import numpy as np

from cam2sim.ads import wire
from cam2sim.ads.dave2 import METADATA_KEY as DAVE2_METADATA
from cam2sim.ads.dave2 import Dave2Config, preprocess
from cam2sim.core.backends import (
    ONNX_FLOAT_TYPES,
    TORCH_HINT,
    checked_size,
    fixed_dim,
    image_tensor,
    load_torch_model,
    local_file,
    onnx_session,
    require_module,
    to_numpy,
)
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.sim.interface import Observation, SteeringPolicy

if TYPE_CHECKING:
    import numpy.typing as npt

    from cam2sim.core.vehicle import SteeringCalibration, VehicleState

__all__ = [
    "ConstantPolicy",
    "ModelPolicy",
    "Observation",
    "PurePursuitPolicy",
    "ReadsImageRows",
    "RemotePolicy",
    "SteeringPolicy",
    "load_policy",
]

_log = logging.getLogger(__name__)

_NEAR_M: Final = 1.0
"""Route segments within ``2 * nearest + this`` metres count as near the vehicle."""
_MODEL_SUFFIXES: Final = (".onnx", ".pt", ".pth", ".ts", ".h5")
_KERAS_HINT: Final = "pip install tensorflow (Keras .h5 models need it; cam2sim does not)"
_SPECS: Final = (
    "'pure-pursuit', 'constant:VALUE' (e.g. constant:-10), a model file "
    f"({', '.join(_MODEL_SUFFIXES)}) or 'tcp://HOST:PORT'"
)


@runtime_checkable
class ReadsImageRows(Protocol):
    """A policy that reads only a band of rows of each camera frame.

    A run may then render only that band (the rest of the frame stays black): the policy's
    input is the same and the camera does less work. :class:`ModelPolicy` with DAVE-2
    preprocessing reads the rows its crop keeps.
    """

    def image_rows(self, height: int) -> tuple[int, int] | None:
        """Rows ``[first, stop)`` of a frame ``height`` rows high that ``predict`` reads.

        None = all of them.
        """
        ...


# --------------------------------------------------------------------------------------------
# Pure pursuit


class PurePursuitPolicy:
    """Pure pursuit along the recorded route, from the rear axle.

    The goal point lies ``Ld = max(lookahead_min_m, lookahead_gain_s * speed)`` metres of arc
    length ahead of the vehicle's progress on the route (beyond the route's end, on the
    extension of its last segment). With ``alpha`` the goal's bearing from the heading and ``d``
    its distance, the path curvature is ``2 sin(alpha) / d`` and the command
    ``curvature / curvature_per_unit`` of the calibration (the simulator maps a command back
    with the same ``k`` and no offset: the fit's offset is a recording bias, not vehicle behaviour).

    Progress is monotone: each call projects the rear axle on the route segments from the last
    progress up to ``search_ahead_m`` (at least ``2 Ld``) further, and takes the nearest point of
    the *first* stretch of segments near the vehicle (within ``2 d_min + 1 m``), so loops and
    routes that pass near themselves are followed in order. The first call after :meth:`reset`
    searches the whole route among segments heading the vehicle's way.

    Args:
        route_xy: ``(N, 2)`` rear axle positions of the recorded drive, world metres, in order.
        wheelbase_m: Vehicle wheelbase, metres (reported; pure pursuit from the rear axle needs
            only the curvature).
        calibration: Maps curvature to the steering unit.
        lookahead_min_m: Shortest look-ahead distance, metres.
        lookahead_gain_s: Look-ahead per speed, seconds.
        search_ahead_m: Arc length searched ahead of the last progress, metres.
    """

    def __init__(
        self,
        route_xy: npt.ArrayLike,
        wheelbase_m: float,
        calibration: SteeringCalibration,
        *,
        lookahead_min_m: float = 4.0,
        lookahead_gain_s: float = 0.6,
        search_ahead_m: float = 25.0,
    ) -> None:
        xy = np.asarray(route_xy, dtype=np.float64)
        if xy.ndim != 2 or xy.shape[1] != 2 or not np.isfinite(xy).all():
            msg = f"route_xy must be a finite (N, 2) array of positions, got shape {xy.shape}"
            raise ConfigError(msg)
        keep = np.r_[True, np.any(np.diff(xy, axis=0) != 0.0, axis=1)]
        xy = xy[keep]
        if len(xy) < 2:
            msg = "pure-pursuit needs a route of at least 2 distinct positions"
            raise ConfigError(msg)
        bad = {
            k: v
            for k, v in (
                ("wheelbase_m", wheelbase_m),
                ("lookahead_min_m", lookahead_min_m),
                ("search_ahead_m", search_ahead_m),
                ("calibration.curvature_per_unit", abs(calibration.curvature_per_unit)),
            )
            if not (math.isfinite(v) and v > 0)
        }
        if bad or not (math.isfinite(lookahead_gain_s) and lookahead_gain_s >= 0):
            msg = (
                "pure-pursuit needs positive finite wheelbase, look-ahead, search window and "
                f"curvature_per_unit and a non-negative lookahead_gain_s; got {bad or {}!r}, "
                f"lookahead_gain_s={lookahead_gain_s!r}"
            )
            raise ConfigError(msg)
        self._xy = xy
        self._seg = np.diff(xy, axis=0)
        self._seg_len = np.hypot(self._seg[:, 0], self._seg[:, 1])
        self._s = np.r_[0.0, np.cumsum(self._seg_len)]
        self.wheelbase_m = float(wheelbase_m)
        self._calibration = calibration
        self._ld_min = float(lookahead_min_m)
        self._ld_gain = float(lookahead_gain_s)
        self._ahead = float(search_ahead_m)
        self._index: int | None = None
        self._progress = 0.0

    @property
    def name(self) -> str:
        """``pure-pursuit``."""
        return "pure-pursuit"

    @property
    def needs_image(self) -> bool:
        """False: pure pursuit uses the route and the state only."""
        return False

    @property
    def progress_m(self) -> float:
        """Arc length reached along the route, metres (monotone between resets)."""
        return self._progress

    @property
    def route_length_m(self) -> float:
        """Total arc length of the route, metres."""
        return float(self._s[-1])

    def reset(self) -> None:
        """Forget the progress: the next call searches the whole route."""
        self._index = None
        self._progress = 0.0

    def _project(
        self, p: npt.NDArray[np.float64], heading: float, lookahead: float
    ) -> tuple[int, float]:
        """Segment index and arc length of the rear axle's projection, searched monotonically."""
        if self._index is None:
            lo, hi = 0, len(self._seg)
        else:
            lo = self._index
            reach = self._progress + max(self._ahead, 2.0 * lookahead)
            hi = max(lo + 1, int(np.searchsorted(self._s, reach, side="right")))
            hi = min(hi, len(self._seg))
        a, d = self._xy[lo:hi], self._seg[lo:hi]
        t = np.clip(np.einsum("ij,ij->i", p - a, d) / self._seg_len[lo:hi] ** 2, 0.0, 1.0)
        dist = np.hypot(*(a + t[:, None] * d - p).T)
        if self._index is None:
            along = d @ np.array([math.cos(heading), math.sin(heading)]) > 0.0
            if along.any():
                dist = np.where(along, dist, np.inf)
        # The first run of segments near the best one: a later leg of the route passing close
        # by (a hairpin, a loop) forms a separate run and is not taken.
        near = dist <= 2.0 * float(dist.min()) + _NEAR_M
        start = int(np.argmax(near))
        stop = start + int(np.argmin(near[start:])) if not near[start:].all() else len(near)
        j = start + int(np.argmin(dist[start:stop]))
        return lo + j, float(self._s[lo + j] + t[j] * self._seg_len[lo + j])

    def _point_at(self, s: float) -> npt.NDArray[np.float64]:
        if s >= self._s[-1]:
            end = self._xy[-1] + (s - self._s[-1]) * self._seg[-1] / self._seg_len[-1]
            return np.asarray(end, dtype=np.float64)
        return np.array(
            [np.interp(s, self._s, self._xy[:, 0]), np.interp(s, self._s, self._xy[:, 1])]
        )

    def curvature(self, state: VehicleState) -> float:
        """Pure-pursuit path curvature (1/m, positive left) for ``state``; advances progress."""
        p = np.asarray(state.rear_axle, dtype=np.float64)
        lookahead = max(self._ld_min, self._ld_gain * max(state.speed, 0.0))
        index, s = self._project(p, state.heading, lookahead)
        if self._index is None or s >= self._progress:
            self._progress = s
        self._index = index
        goal = self._point_at(self._progress + lookahead) - p
        c, si = math.cos(state.heading), math.sin(state.heading)
        ahead, left = c * goal[0] + si * goal[1], -si * goal[0] + c * goal[1]
        d2 = ahead * ahead + left * left
        return 0.0 if d2 < 1e-12 else 2.0 * left / d2  # 2 sin(alpha) / d

    def predict(self, obs: Observation) -> float:
        """The steering command that follows the route from ``obs.state``."""
        cal = self._calibration
        return self.curvature(obs.state) / cal.curvature_per_unit

    def close(self) -> None:
        """Nothing to release."""


class ConstantPolicy:
    """Always the same command (tests and diagnosis, e.g. ``constant:-10`` for hard right)."""

    def __init__(self, value: float) -> None:
        if not math.isfinite(value):
            msg = f"constant policy value must be finite, got {value!r}"
            raise ConfigError(msg)
        self.value = float(value)

    @property
    def name(self) -> str:
        """``constant:VALUE``."""
        return f"constant:{self.value:g}"

    @property
    def needs_image(self) -> bool:
        """False."""
        return False

    def reset(self) -> None:
        """Nothing to forget."""

    def predict(self, obs: Observation) -> float:  # noqa: ARG002  (the interface's argument)
        """``value``."""
        return self.value

    def close(self) -> None:
        """Nothing to release."""


# --------------------------------------------------------------------------------------------
# Image models


def _contract_error(model: str, what: str, inputs: str, outputs: str) -> ConfigError:
    msg = (
        f"{model}: {what}; it has inputs [{inputs}] and outputs [{outputs}] (contract: image "
        "float32 (1, 3, H, W) in [0, 1] -> one steering value; see cam2sim.ads.policy)"
    )
    return ConfigError(msg)


def _steering_value(value: Any, model: str) -> float:  # Any: numpy arrays or torch tensors
    a = to_numpy(value)
    if a.size != 1 or a.ndim > 2:
        msg = (
            f"{model} returned an output of shape {a.shape}; the contract is one steering value, "
            "shape (), (1,) or (1, 1) (see cam2sim.ads.policy)"
        )
        raise ConfigError(msg)
    out = float(a.reshape(()))
    if not math.isfinite(out):
        msg = f"{model} returned a non-finite steering value ({out}); check the model's inputs"
        raise StageError(msg)
    return out


def _model_image(obs: Observation, size: tuple[int, int], model: str) -> npt.NDArray[np.float32]:
    if obs.image is None:
        msg = f"{model} steers from the camera image, but the run has none; configure a camera"
        raise ConfigError(msg)
    img = np.asarray(obs.image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or min(img.shape[:2]) < 1:
        msg = f"observation image must be (H, W, 3) uint8 RGB; got {img.dtype} {img.shape}"
        raise ValueError(msg)
    if (img.shape[1], img.shape[0]) != size:
        img = np.asarray(cv2.resize(img, size, interpolation=cv2.INTER_AREA), dtype=np.uint8)
    return image_tensor(img)


def _fit_size(
    declared: tuple[int, int] | None, input_size: tuple[int, int] | None, model: str
) -> tuple[int, int]:
    size = checked_size(input_size) or declared
    if size is None:
        msg = f"{model} has no fixed input size; give input_size=(width, height)"
        raise ConfigError(msg)
    if declared is not None and size != declared:
        msg = f"{model}: input_size {input_size!r} differs from the model's fixed size {declared}"
        raise ConfigError(msg)
    return size


class _OnnxSteering:
    """An onnxruntime session checked against the steering contract."""

    def __init__(self, path: Path, input_size: tuple[int, int] | None) -> None:
        self.name = f"onnx:{path.name}"
        self._session = onnx_session(path, "the ONNX steering policy")
        inputs: list[Any] = list(self._session.get_inputs())  # Any: onnxruntime NodeArgs
        outputs: list[Any] = list(self._session.get_outputs())

        def part(args: list[Any]) -> str:
            return ", ".join(f"{a.name} {a.type} {list(a.shape)}" for a in args)

        ins, outs = part(inputs), part(outputs)
        shape = list(inputs[0].shape) if len(inputs) == 1 else []
        ok = (
            len(shape) == 4
            and fixed_dim(shape[0]) in (None, 1)
            and fixed_dim(shape[1]) in (None, 3)
            and inputs[0].type in ONNX_FLOAT_TYPES
        )
        if not ok:
            raise _contract_error(self.name, "wrong inputs", ins, outs)
        names = [o.name for o in outputs]
        if len(names) != 1 and "steering" not in names:
            raise _contract_error(self.name, "one output (or one named steering) needed", ins, outs)
        self._fetch = names[0] if len(names) == 1 else "steering"
        self._input, self._dtype = inputs[0].name, ONNX_FLOAT_TYPES[inputs[0].type]
        h, w = fixed_dim(shape[2]), fixed_dim(shape[3])
        self.size = _fit_size((w, h) if w and h else None, input_size, self.name)
        meta = self._session.get_modelmeta().custom_metadata_map.get(DAVE2_METADATA)
        self.dave2 = None if meta is None else Dave2Config.from_json(meta)
        if self.dave2 is not None and self.dave2.input_size != self.size:
            msg = f"{self.name}: metadata input size {self.dave2.input_size} != graph {self.size}"
            raise ConfigError(msg)

    def __call__(self, x: npt.NDArray[np.float32]) -> float:
        try:
            (value,) = self._session.run([self._fetch], {self._input: x.astype(self._dtype)})
        except Exception as err:  # onnxruntime's errors derive from Exception only
            msg = f"{self.name}: inference failed on an image of shape {x.shape} ({err})"
            raise ConfigError(msg) from err
        return _steering_value(value, self.name)


class _TorchSteering:
    """A torch.export program or TorchScript module checked against the steering contract."""

    def __init__(self, path: Path, input_size: tuple[int, int] | None, device: str) -> None:
        self.name = f"torch:{path.name}"
        require_module("torch", TORCH_HINT, "the torch steering policy")
        self._device = device
        self._module, n_inputs, declared = load_torch_model(path, device)
        if n_inputs != 1:
            msg = f"forward takes {n_inputs} inputs, the contract is forward(image)"
            raise _contract_error(self.name, msg, f"{n_inputs} tensors", "?")
        self.size = _fit_size(declared, input_size, self.name)
        self.dave2: Dave2Config | None = None

    def __call__(self, x: npt.NDArray[np.float32]) -> float:
        import warnings  # noqa: PLC0415

        import torch  # noqa: PLC0415  (an optional backend; checked in __init__)

        try:
            with torch.inference_mode(), warnings.catch_warnings():
                warnings.filterwarnings("ignore", r".*torch\.jit", DeprecationWarning)
                out = self._module(torch.from_numpy(x).to(self._device))
        except (RuntimeError, ValueError, TypeError) as err:
            msg = f"{self.name}: inference failed on an image of shape {x.shape} ({err})"
            raise ConfigError(msg) from err
        if isinstance(out, dict) and "steering" in out:
            out = out["steering"]
        elif isinstance(out, (tuple, list)) and len(out) == 1:
            out = out[0]
        if isinstance(out, (dict, tuple, list)):
            msg = f"{self.name} returned a {type(out).__name__}; return one tensor (or steering=)"
            raise ConfigError(msg)
        return _steering_value(out, self.name)


class _KerasSteering:
    """A Keras ``.h5`` DAVE-2 (the reference system's ``final.h5``), via TensorFlow.

    Takes the published preprocessing (:func:`cam2sim.ads.dave2.preprocess`, values in
    ``[0, 255]``) channels last, ``(1, 66, 200, 3)``; the first output value is the steering
    (the reference model returns ``[steering, throttle]``).
    """

    def __init__(self, path: Path) -> None:
        self.name = f"keras:{path.name}"
        tf = require_module("tensorflow", _KERAS_HINT, "the Keras steering policy")
        try:
            self._model = tf.keras.models.load_model(str(path), compile=False, safe_mode=False)
        except (OSError, ValueError, TypeError) as err:
            msg = f"cannot load Keras model {str(path)!r}: {err}"
            raise ConfigError(msg) from err
        self.dave2: Dave2Config | None = Dave2Config()
        self.size = self.dave2.input_size

    def __call__(self, x: npt.NDArray[np.float32]) -> float:
        out = to_numpy(self._model(x.transpose(0, 2, 3, 1), training=False))
        return _steering_value(out.reshape(-1)[:1], self.name)


def _dave2_image(obs: Observation, config: Dave2Config, model: str) -> npt.NDArray[np.float32]:
    """The frame preprocessed as the DAVE-2 training did (crop honoured), ``[0, 255]``."""
    if obs.image is None:
        msg = f"{model} steers from the camera image, but the run has none; configure a camera"
        raise ConfigError(msg)
    return preprocess(np.asarray(obs.image), config)


class ModelPolicy:
    """An image model that steers (contract in the module doc): ONNX, torch or Keras.

    ONNX models exported by cam2sim (:mod:`cam2sim.ads.export`) carry their DAVE-2
    preprocessing in metadata: the frame is resized, cropped and resized as in training, and
    passed in ``[0, 255]``. Keras ``.h5`` models get the published DAVE-2 preprocessing.

    Args:
        path: The ``.onnx`` file, a ``.pt`` / ``.pth`` / ``.ts`` torch archive, or a Keras
            ``.h5`` (needs TensorFlow).
        input_size: ``(width, height)`` the model takes; needed when it declares none.
        device: torch device (torch models only).
    """

    def __init__(
        self, path: Path | str, *, input_size: tuple[int, int] | None = None, device: str = "cpu"
    ) -> None:
        path = local_file(Path(path), "steering model")
        suffix = path.suffix.lower()
        if suffix not in _MODEL_SUFFIXES:
            msg = f"steering model {path.name!r} must be one of {', '.join(_MODEL_SUFFIXES)}"
            raise ConfigError(msg)
        self._model: _OnnxSteering | _TorchSteering | _KerasSteering
        if suffix == ".onnx":
            self._model = _OnnxSteering(path, input_size)
        elif suffix == ".h5":
            self._model = _KerasSteering(path)
        else:
            self._model = _TorchSteering(path, input_size, device)

    @property
    def name(self) -> str:
        """``onnx:FILE``, ``torch:FILE`` or ``keras:FILE``."""
        return self._model.name

    @property
    def needs_image(self) -> bool:
        """True."""
        return True

    @property
    def input_size(self) -> tuple[int, int]:
        """``(width, height)`` the camera frame is resized to."""
        return self._model.size

    def reset(self) -> None:
        """Nothing to forget (the model is stateless)."""

    def image_rows(self, height: int) -> tuple[int, int] | None:
        """The rows the DAVE-2 crop reads (:meth:`Dave2Config.rows_read`).

        None for models without DAVE-2 preprocessing: they see the whole frame.
        """
        dave2 = self._model.dave2
        return None if dave2 is None else dave2.rows_read(height)

    def predict(self, obs: Observation) -> float:
        """The model's steering for ``obs.image``."""
        if self._model.dave2 is not None:
            return self._model(_dave2_image(obs, self._model.dave2, self.name))
        return self._model(_model_image(obs, self._model.size, self.name))

    def close(self) -> None:
        """Nothing to release beyond the model object."""


# --------------------------------------------------------------------------------------------
# Remote policies


def _parse_address(address: str) -> tuple[str, int]:
    rest = address.removeprefix("tcp://")
    host, sep, port = rest.rpartition(":")
    if not address.startswith("tcp://") or not sep or not host or not port.isdigit():
        msg = f"remote policy address {address!r} must look like tcp://HOST:PORT"
        raise ConfigError(msg)
    if not 0 < int(port) < 65536:
        msg = f"remote policy port {port} must lie in 1..65535"
        raise ConfigError(msg)
    return host.strip("[]"), int(port)


class RemotePolicy:
    """A policy served by another process (wire protocol in :mod:`cam2sim.ads.wire`).

    Speaks the published tool's protocol, so it drives either a :mod:`cam2sim.ads.serve`
    server (``cam2sim ads serve``) or the published model server. Connects when built, so an
    unreachable server fails at once. When the connection drops (a server restart) the next
    request reconnects once and is sent again; a second failure, or no reply within
    ``timeout_s``, raises :class:`~cam2sim.core.errors.StageError` naming the server.

    Args:
        address: ``tcp://HOST:PORT`` of the server.
        encoding: ``raw`` (lossless, no codec cost: the default), ``png`` (lossless) or
            ``jpeg`` (quality 75, what the published client sends and its server reads).
        timeout_s: Longest wait to connect and for each reply, seconds.
        smoothing: Server-side EMA factor for this connection (0.85: the published server);
            None: no smoothing. Needs ``control``.
        control: Send control messages (:meth:`reset`, ``smoothing``); False for the published
            server, which does not understand them (:meth:`reset` then does nothing).
    """

    def __init__(
        self,
        address: str,
        *,
        encoding: str = "raw",
        timeout_s: float = 10.0,
        smoothing: float | None = None,
        control: bool = True,
    ) -> None:
        self.host, self.port = _parse_address(address)
        if encoding not in wire.ENCODINGS:
            msg = f"remote policy encoding {encoding!r} must be one of {', '.join(wire.ENCODINGS)}"
            raise ConfigError(msg)
        if smoothing is not None and not control:
            msg = "smoothing is a control message; the published server (control=False) has its own"
            raise ConfigError(msg)
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            msg = f"timeout_s must be a positive number of seconds, got {timeout_s!r}"
            raise ConfigError(msg)
        self._encoding = cast("wire.Encoding", encoding)
        self._timeout = float(timeout_s)
        self._controls = wire.control_message(smoothing=smoothing) if smoothing is not None else b""
        self._control = control
        self.last_throttle: float | None = None
        """Throttle of the last reply (the policy interface steers only)."""
        self._sock: socket.socket | None = None
        self._connect()

    @property
    def name(self) -> str:
        """``tcp://HOST:PORT``."""
        return f"tcp://{self.host}:{self.port}"

    @property
    def needs_image(self) -> bool:
        """True: the protocol sends the camera image."""
        return True

    def _where(self) -> str:
        return f"remote policy at {self.host}:{self.port}"

    def _connect(self) -> None:
        self.close()
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self._timeout)
        except OSError as err:
            msg = (
                f"cannot reach the {self._where()} ({err}); start it first (cam2sim ads serve) "
                "and check the host and port"
            )
            raise StageError(msg) from err
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        if self._controls:
            self._exchange(self._controls)

    def _exchange(self, payload: bytes) -> bytes:
        """One request/reply on the open socket (OSError/EOF propagate; timeout: StageError)."""
        if self._sock is None:
            raise ConnectionResetError
        try:
            self._sock.sendall(wire.frame(payload))
            reply = wire.recv_message(self._sock, 1 << 20)
        except TimeoutError as err:
            self.close()
            msg = f"{self._where()} sent no reply within {self._timeout:g} s; is it hung?"
            raise StageError(msg) from err
        except wire.ProtocolError as err:
            raise ConnectionResetError(str(err)) from err
        if reply is None:
            msg = "the server closed the connection"
            raise ConnectionResetError(msg)
        return reply

    def _call(self, payload: bytes) -> bytes:
        try:
            return self._exchange(payload)
        except OSError as err:
            _log.info("%s: connection lost (%s); reconnecting once", self._where(), err)
        self._connect()
        try:
            return self._exchange(payload)
        except OSError as err:
            self.close()
            msg = f"lost the {self._where()} again after reconnecting ({err}); is it running?"
            raise StageError(msg) from err

    def reset(self) -> None:
        """Start of a run: the server forgets this connection's smoothing state."""
        if self._control:
            self._call(wire.control_message(reset=True))

    def predict(self, obs: Observation) -> float:
        """Send ``obs.image`` and return the server's steering (throttle: ``last_throttle``)."""
        if obs.image is None:
            msg = f"the {self._where()} steers from the camera image, but the run has none"
            raise StageError(msg)
        payload = wire.encode_image(obs.image, self._encoding)
        try:
            steering, self.last_throttle = wire.parse_reply(self._call(payload))
        except wire.ProtocolError as err:
            msg = f"{self._where()}: {err}"
            raise StageError(msg) from err
        return steering

    def close(self) -> None:
        """Close the connection (the server keeps running)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None


# --------------------------------------------------------------------------------------------
# Specs


def load_policy(
    spec: str,
    *,
    route_xy: npt.ArrayLike | None,
    wheelbase_m: float,
    calibration: SteeringCalibration,
    input_size: tuple[int, int] | None = None,
) -> SteeringPolicy:
    """The policy a spec names (forms in the module doc).

    Args:
        spec: ``pure-pursuit``, ``constant:VALUE``, a model path or ``tcp://HOST:PORT``.
        route_xy: ``(N, 2)`` rear axle route (``pure-pursuit`` only; None when there is none).
        wheelbase_m: Vehicle wheelbase, metres.
        calibration: The run's steering calibration.
        input_size: ``(width, height)`` for image models that declare no fixed size.
    """
    text = spec.strip()
    if text == "pure-pursuit":
        if route_xy is None:
            msg = "pure-pursuit follows the recorded route, but none was given"
            raise ConfigError(msg)
        return PurePursuitPolicy(route_xy, wheelbase_m, calibration)
    if text.startswith("constant:"):
        try:
            value = float(text.removeprefix("constant:"))
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            msg = f"policy {spec!r}: constant:VALUE needs a finite number, e.g. constant:-10"
            raise ConfigError(msg)
        return ConstantPolicy(value)
    if text.startswith("tcp://"):
        return RemotePolicy(text)
    if Path(text).suffix.lower() in _MODEL_SUFFIXES:
        return ModelPolicy(text, input_size=input_size)
    msg = f"unknown policy {spec!r}; give {_SPECS}"
    raise ConfigError(msg)
