"""Round trip through the policy server on loopback (issue 9): target <= 5 ms.

One :class:`~cam2sim.ads.policy.RemotePolicy` client sends camera frames to a
:class:`~cam2sim.ads.serve.PolicyServer` in the same process (its own thread) over 127.0.0.1 and
waits for each reply, as a closed-loop run does. Reported per encoding (``png``, ``jpeg``,
``raw``) and image size: p50/p95 milliseconds of ``predict`` (encode + send + decode + policy +
reply) with a trivial policy (mean of the red channel), so the numbers are the protocol's cost.
``--onnx`` adds a DAVE-2-sized ONNX model (5 convolutions + 4 dense layers on 66x200, random
weights, onnxruntime CPU) behind the server, in-process time shown beside it.

Run from the repository root::

    python benchmarks/ads_roundtrip.py [--requests 1000] [--onnx]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from cam2sim.ads.policy import ModelPolicy, Observation, RemotePolicy
from cam2sim.ads.serve import PolicyServer
from cam2sim.sim.interface import VehicleState

TARGET_MS = 5.0
SIZES = ((200, 66), (800, 503))
STATE = VehicleState(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, (0.0, 0.0))


class RedMean:
    name = "red-mean"
    needs_image = True

    def reset(self) -> None:
        pass

    def predict(self, obs: Observation) -> float:
        assert obs.image is not None
        return float(obs.image[..., 0].mean()) / 255.0

    def close(self) -> None:
        pass


def _frames(w: int, h: int, n: int = 8) -> list[np.ndarray]:
    """Smooth camera-like frames (random noise would make PNG/JPEG unrealistically slow)."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:h, 0:w]
    out = []
    for _ in range(n):
        base = 128 + 60 * np.sin(xx / rng.uniform(10, 40)) * np.cos(yy / rng.uniform(10, 40))
        img = np.stack([base, base * 0.8 + 20, 255 - base], axis=-1)
        img += rng.normal(0, 4, img.shape)
        out.append(np.clip(img, 0, 255).astype(np.uint8))
    return out


def _measure(address: str, encoding: str, frames: list[np.ndarray], n: int) -> np.ndarray:
    remote = RemotePolicy(address, encoding=encoding, timeout_s=10.0)
    try:
        obs = [Observation(0.0, f, STATE) for f in frames]
        for o in obs:  # warm-up
            remote.predict(o)
        times = np.empty(n)
        for i in range(n):
            t0 = time.perf_counter()
            remote.predict(obs[i % len(obs)])
            times[i] = time.perf_counter() - t0
    finally:
        remote.close()
    return times * 1e3


def _dave2_onnx(path: Path) -> Path:
    from onnx import TensorProto, helper, numpy_helper, save_model  # noqa: PLC0415

    rng = np.random.default_rng(0)
    nodes, inits = [], []
    x, c = "image", 3
    convs = ((24, 5, 2), (36, 5, 2), (48, 5, 2), (64, 3, 1), (64, 3, 1))
    for i, (k, size, stride) in enumerate(convs):
        w = rng.normal(0, 0.05, (k, c, size, size)).astype(np.float32)
        inits += [
            numpy_helper.from_array(w, f"w{i}"),
            numpy_helper.from_array(np.zeros(k, np.float32), f"b{i}"),
        ]
        nodes += [
            helper.make_node("Conv", [x, f"w{i}", f"b{i}"], [f"c{i}"], strides=[stride, stride]),
            helper.make_node("Elu", [f"c{i}"], [f"e{i}"]),
        ]
        x, c = f"e{i}", k
    nodes.append(helper.make_node("Flatten", [x], ["flat"]))
    x, n_in = "flat", 64 * 1 * 18
    for i, n_out in enumerate((100, 50, 10, 1)):
        w = rng.normal(0, 0.05, (n_in, n_out)).astype(np.float32)
        inits += [
            numpy_helper.from_array(w, f"fw{i}"),
            numpy_helper.from_array(np.zeros(n_out, np.float32), f"fb{i}"),
        ]
        nodes.append(helper.make_node("Gemm", [x, f"fw{i}", f"fb{i}"], [f"f{i}"]))
        x, n_in = f"f{i}", n_out
    nodes.append(helper.make_node("Reshape", [x, "shape"], ["steering"]))
    inits.append(numpy_helper.from_array(np.array([1], np.int64), "shape"))
    graph = helper.make_graph(
        nodes,
        "dave2",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, 66, 200])],
        [helper.make_tensor_value_info("steering", TensorProto.FLOAT, [1])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], ir_version=8)
    save_model(model, path)
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--requests", type=int, default=1000)
    parser.add_argument("--onnx", action="store_true", help="also a DAVE-2-sized ONNX model")
    args = parser.parse_args()
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, loopback")
    print(f"{'policy':<10} {'encoding':<6} {'size':>8} {'p50 ms':>8} {'p95 ms':>8}  target")
    with PolicyServer(RedMean()).start() as server:
        for w, h in SIZES:
            frames = _frames(w, h)
            for encoding in ("raw", "png", "jpeg"):
                ms = _measure(server.address, encoding, frames, args.requests)
                p50, p95 = np.percentile(ms, [50, 95])
                ok = "ok" if p50 <= TARGET_MS else "MISS"
                print(f"{'trivial':<10} {encoding:<6} {w:>4}x{h:<4} {p50:8.3f} {p95:8.3f}  {ok}")
    if args.onnx:
        with tempfile.TemporaryDirectory() as tmp:
            model = ModelPolicy(_dave2_onnx(Path(tmp) / "dave2.onnx"))
            frames = _frames(200, 66)
            local = np.empty(args.requests)
            for i in range(args.requests):
                t0 = time.perf_counter()
                model.predict(Observation(0.0, frames[i % len(frames)], STATE))
                local[i] = time.perf_counter() - t0
            p50, p95 = np.percentile(local * 1e3, [50, 95])
            print(f"{'dave2':<10} {'local':<6} {200:>4}x{66:<4} {p50:8.3f} {p95:8.3f}")
            with PolicyServer(model).start() as server:
                for encoding in ("raw", "png", "jpeg"):
                    ms = _measure(server.address, encoding, frames, args.requests)
                    p50, p95 = np.percentile(ms, [50, 95])
                    print(f"{'dave2':<10} {encoding:<6} {200:>4}x{66:<4} {p50:8.3f} {p95:8.3f}")
            model.close()


if __name__ == "__main__":
    main()
