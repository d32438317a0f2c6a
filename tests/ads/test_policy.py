"""Steering policies: pure pursuit, constant, image models (ONNX, torch.export), remote TCP."""

from __future__ import annotations

import math
import socket
from pathlib import Path

import numpy as np
import pytest
from onnx import TensorProto, helper, numpy_helper, save_model

from cam2sim.ads.policy import (
    ConstantPolicy,
    ModelPolicy,
    Observation,
    PurePursuitPolicy,
    RemotePolicy,
    SteeringPolicy,
    load_policy,
)
from cam2sim.ads.serve import PolicyServer
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.sim.interface import SteeringCalibration, VehicleState

CAL = SteeringCalibration(curvature_per_unit=0.02, offset=0.001, source="config")
WHEELBASE = 2.8


def _state(x: float, y: float, heading: float, speed: float = 5.0, t: float = 0.0) -> VehicleState:
    return VehicleState(
        t=t,
        x=x + 1.4 * math.cos(heading),
        y=y + 1.4 * math.sin(heading),
        z=0.0,
        heading=heading,
        speed=speed,
        wheel_angle=0.0,
        steering=0.0,
        rear_axle=(x, y),
    )


def _obs(state: VehicleState, image: np.ndarray | None = None) -> Observation:
    return Observation(t=state.t, image=image, state=state)


def _drive(policy: PurePursuitPolicy, x: float, y: float, h: float, seconds: float) -> list[float]:
    """Kinematic bicycle from the rear axle at 5 m/s, policy at 10 Hz; returns lateral y."""
    dt, v, ys = 0.1, 5.0, []
    for _ in range(int(seconds / dt)):
        cmd = policy.predict(_obs(_state(x, y, h, v)))
        kappa = CAL.curvature_per_unit * cmd
        x, y, h = x + v * math.cos(h) * dt, y + v * math.sin(h) * dt, h + v * kappa * dt
        ys.append(y)
    return ys


@pytest.mark.parametrize("y0", [2.0, -2.0])
def test_pure_pursuit_returns_to_a_straight_route(y0: float) -> None:
    route = np.c_[np.linspace(0.0, 300.0, 301), np.zeros(301)]
    policy = PurePursuitPolicy(route, WHEELBASE, CAL)
    assert not policy.needs_image
    assert policy.name == "pure-pursuit"
    first = policy.predict(_obs(_state(0.0, y0, 0.0)))
    assert np.sign(CAL.curvature_per_unit * first) == -np.sign(y0)
    ys = _drive(policy, 0.0, y0, 0.0, 20.0)
    assert abs(ys[-1]) < 0.05
    assert max(abs(y) for y in ys) <= abs(y0) + 1e-9


def test_pure_pursuit_on_a_circle_gives_its_curvature() -> None:
    radius = 30.0
    a = np.linspace(0.0, 1.5 * math.pi, 600)
    route = radius * np.c_[np.cos(a), np.sin(a)]
    for sign in (1.0, -1.0):  # counter-clockwise (left) and clockwise (right)
        policy = PurePursuitPolicy(route * [1.0, sign], WHEELBASE, CAL)
        theta = 0.3
        state = _state(
            radius * math.cos(theta), sign * radius * math.sin(theta), sign * (theta + math.pi / 2)
        )
        cmd = policy.predict(_obs(state))
        expected = (sign / radius) / CAL.curvature_per_unit
        assert cmd == pytest.approx(expected, rel=0.05)


def test_pure_pursuit_progress_is_monotone_on_a_hairpin_and_a_loop() -> None:
    # Out along y = 0, a U-turn, back along y = 3: the outbound leg at y = 1.6 lies nearer to
    # the return leg, which a global nearest-point search would pick.
    out = np.c_[np.linspace(0.0, 60.0, 61), np.zeros(61)]
    turn = np.c_[
        60.0 + 1.5 * np.sin(np.linspace(0, math.pi, 9)),
        1.5 - 1.5 * np.cos(np.linspace(0, math.pi, 9)),
    ]
    back = np.c_[np.linspace(60.0, 0.0, 61), np.full(61, 3.0)]
    policy = PurePursuitPolicy(np.r_[out, turn[1:-1], back], WHEELBASE, CAL)
    progress = []
    for x in np.arange(0.0, 50.0, 0.5):
        policy.predict(_obs(_state(float(x), 1.6, 0.0)))
        progress.append(policy.progress_m)
    assert np.all(np.diff(progress) >= 0.0)
    assert progress[-1] == pytest.approx(49.5, abs=0.1)
    # Two laps of a closed circle: progress passes the first lap's length.
    radius = 20.0
    a = np.linspace(0.0, 4.0 * math.pi, 801)
    policy = PurePursuitPolicy(radius * np.c_[np.cos(a), np.sin(a)], WHEELBASE, CAL)
    progress = []
    for theta in np.linspace(0.0, 3.5 * math.pi, 200):
        state = _state(radius * math.cos(theta), radius * math.sin(theta), theta + math.pi / 2)
        policy.predict(_obs(state))
        progress.append(policy.progress_m)
    assert np.all(np.diff(progress) >= 0.0)
    assert progress[-1] == pytest.approx(radius * 3.5 * math.pi, rel=0.01)
    policy.reset()
    assert policy.progress_m == 0.0


def test_pure_pursuit_rejects_bad_routes() -> None:
    with pytest.raises(ConfigError, match="2 distinct"):
        PurePursuitPolicy(np.zeros((5, 2)), WHEELBASE, CAL)
    with pytest.raises(ConfigError, match=r"\(N, 2\)"):
        PurePursuitPolicy(np.zeros(5), WHEELBASE, CAL)


def test_constant_policy() -> None:
    policy = load_policy("constant:-10", route_xy=None, wheelbase_m=WHEELBASE, calibration=CAL)
    assert isinstance(policy, ConstantPolicy)
    assert isinstance(policy, SteeringPolicy)
    assert policy.name == "constant:-10"
    assert policy.predict(_obs(_state(0.0, 0.0, 0.0))) == -10.0
    with pytest.raises(ConfigError, match="finite number"):
        load_policy("constant:left", route_xy=None, wheelbase_m=WHEELBASE, calibration=CAL)


def _onnx_model(path: Path, size: int | str) -> Path:
    """steering = mean(red) - 0.5 on image (1, 3, size, size)."""
    nodes = [
        helper.make_node("Constant", [], [n], value=numpy_helper.from_array(np.array(v), n))
        for n, v in (("s0", [0]), ("e1", [1]), ("a1", [1]), ("half", np.float32(0.5)))
    ]
    nodes += [
        helper.make_node("Slice", ["image", "s0", "e1", "a1"], ["red"]),
        helper.make_node("ReduceMean", ["red"], ["mean"], axes=[1, 2, 3], keepdims=0),
        helper.make_node("Sub", ["mean", "half"], ["steering"]),
    ]
    graph = helper.make_graph(
        nodes,
        "steer",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, size, size])],
        [helper.make_tensor_value_info("steering", TensorProto.FLOAT, [1])],
    )
    save_model(
        helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8), path
    )
    return path


def _image(red: int, h: int = 16, w: int = 24) -> np.ndarray:
    img = np.zeros((h, w, 3), np.uint8)
    img[..., 0] = red
    img[..., 1] = 255
    return img


def test_onnx_model_policy(tmp_path: Path) -> None:
    path = _onnx_model(tmp_path / "steer.onnx", 8)
    policy = load_policy(str(path), route_xy=None, wheelbase_m=WHEELBASE, calibration=CAL)
    assert policy.needs_image
    assert policy.name == "onnx:steer.onnx"
    value = policy.predict(_obs(_state(0.0, 0.0, 0.0), _image(200)))
    assert value == pytest.approx(200 / 255 - 0.5, abs=1e-6)
    with pytest.raises(ConfigError, match="has none"):
        policy.predict(_obs(_state(0.0, 0.0, 0.0)))
    dynamic = _onnx_model(tmp_path / "dyn.onnx", "s")
    with pytest.raises(ConfigError, match="input_size"):
        ModelPolicy(dynamic)
    assert ModelPolicy(dynamic, input_size=(4, 4)).predict(
        _obs(_state(0.0, 0.0, 0.0), _image(51))
    ) == pytest.approx(-0.3, abs=1e-6)


def test_onnx_model_breaking_the_contract_is_named(tmp_path: Path) -> None:
    graph = helper.make_graph(
        [helper.make_node("Identity", ["x"], ["y"])],
        "bad",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 5])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 5])],
    )
    path = tmp_path / "bad.onnx"
    save_model(
        helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8), path
    )
    with pytest.raises(ConfigError, match=r"inputs \[x tensor\(float\) \[1, 5\]\]"):
        ModelPolicy(path)


def test_torch_export_model_policy(tmp_path: Path) -> None:
    pytest.importorskip("torch")
    import torch

    class Steer(torch.nn.Module):
        def forward(self, image: torch.Tensor) -> torch.Tensor:
            return image[:, 0].mean(dim=(1, 2)) - 0.5

    program = torch.export.export(Steer(), (torch.zeros(1, 3, 8, 12),))
    path = tmp_path / "steer.pt"
    torch.export.save(program, path)
    policy = load_policy(str(path), route_xy=None, wheelbase_m=WHEELBASE, calibration=CAL)
    assert isinstance(policy, ModelPolicy)
    assert policy.input_size == (12, 8)
    value = policy.predict(_obs(_state(0.0, 0.0, 0.0), _image(100)))
    assert value == pytest.approx(100 / 255 - 0.5, abs=1e-6)


def test_remote_policy_matches_in_process(tmp_path: Path) -> None:
    model = ModelPolicy(_onnx_model(tmp_path / "steer.onnx", 8))
    state = _state(3.0, 4.0, 0.5, t=1.5)
    with PolicyServer(model).start() as server:
        remote = load_policy(server.address, route_xy=None, wheelbase_m=1.0, calibration=CAL)
        try:
            assert isinstance(remote, RemotePolicy)
            assert remote.needs_image
            assert remote.name == server.address
            remote.reset()
            for red in (0, 180, 255):
                got = remote.predict(_obs(state, _image(red)))
                assert got == pytest.approx(model.predict(_obs(state, _image(red))), abs=1e-7)
                assert remote.last_throttle == 0.0
            with pytest.raises(StageError, match="has none"):
                remote.predict(_obs(state))
        finally:
            remote.close()

    class Failing(ConstantPolicy):
        def predict(self, obs: Observation) -> float:
            msg = "no model"
            raise ConfigError(msg)

    with PolicyServer(Failing(1.0)).start() as server:  # the server's error, relayed
        remote = RemotePolicy(server.address, encoding="raw", timeout_s=5.0)
        try:
            with pytest.raises(StageError, match="ConfigError: no model"):
                remote.predict(_obs(state, np.zeros((4, 4, 3), np.uint8)))
        finally:
            remote.close()


def test_remote_policy_unreachable_and_bad_specs() -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(StageError, match=f"127.0.0.1:{port}"):
        RemotePolicy(f"tcp://127.0.0.1:{port}", timeout_s=1.0)
    with pytest.raises(ConfigError, match="tcp://HOST:PORT"):
        RemotePolicy("tcp://nohost")
    for spec in ("steer-well", "model.txt", "pure_pursuit"):
        with pytest.raises(ConfigError, match="pure-pursuit.*constant:VALUE.*tcp://HOST:PORT"):
            load_policy(spec, route_xy=None, wheelbase_m=WHEELBASE, calibration=CAL)
    with pytest.raises(ConfigError, match="route"):
        load_policy("pure-pursuit", route_xy=None, wheelbase_m=WHEELBASE, calibration=CAL)
    with pytest.raises(ConfigError, match="does not exist"):
        load_policy("missing.onnx", route_xy=None, wheelbase_m=WHEELBASE, calibration=CAL)


def test_closing_the_server_drops_a_connected_client() -> None:
    server = PolicyServer(ConstantPolicy(2.5)).start()
    remote = RemotePolicy(server.address, timeout_s=2.0)
    obs = _obs(_state(0.0, 0.0, 0.0), _image(10))
    try:
        assert remote.predict(obs) == 2.5
        server.close()
        with pytest.raises(StageError, match=f"127.0.0.1:{server.port}"):
            remote.predict(obs)
    finally:
        remote.close()
        server.close()
