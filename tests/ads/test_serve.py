"""The policy server: published protocol compatibility, lossless variants, smoothing, fuzzing."""

from __future__ import annotations

import contextlib
import logging
import random
import socket
import struct
import threading
import time
from typing import TYPE_CHECKING

import cv2
import numpy as np
import pytest

from cam2sim.ads.policy import ConstantPolicy, Observation, RemotePolicy
from cam2sim.ads.serve import PolicyServer, serve
from cam2sim.ads.wire import control_message, decode_image, encode_image, frame
from cam2sim.core.errors import ConfigError, StageError
from cam2sim.sim.interface import VehicleState

if TYPE_CHECKING:
    from collections.abc import Iterator

STATE = VehicleState(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, (0.0, 0.0))


class RedMean:
    """Steering = mean of the red channel / 255 * 10 - 5, exact in float64; throttle 0.25."""

    name = "red-mean"
    needs_image = True

    def __init__(self) -> None:
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def predict(self, obs: Observation) -> float:
        assert obs.image is not None
        return float(obs.image[..., 0].astype(np.float64).mean()) / 25.5 - 5.0

    def predict_controls(self, obs: Observation) -> tuple[float, float]:
        return self.predict(obs), 0.25

    def close(self) -> None:
        pass


def _image(seed: int, h: int = 66, w: int = 200) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _expected(image: np.ndarray) -> float:
    return RedMean().predict(Observation(0.0, image, STATE))


def _recv_exact(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            msg = "closed"
            raise EOFError(msg)
        data += chunk
    return data


def _ask(sock: socket.socket, payload: bytes) -> str:
    """A client written from the protocol description: length-prefixed both ways."""
    sock.sendall(struct.pack(">I", len(payload)) + payload)
    (n,) = struct.unpack(">I", _recv_exact(sock, 4))
    return _recv_exact(sock, n).decode()


@pytest.fixture
def server() -> Iterator[PolicyServer]:
    with PolicyServer(RedMean()).start() as srv:
        yield srv


def test_a_published_style_client_gets_steering_and_throttle(server: PolicyServer) -> None:
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as sock:
        for seed in range(3):
            image = _image(seed)
            ok, jpeg = cv2.imencode(".jpg", image[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 75])
            assert ok
            steering, throttle = _ask(sock, jpeg.tobytes()).split(",")
            seen = cv2.imdecode(jpeg, cv2.IMREAD_COLOR)[..., ::-1]  # what the server decodes
            assert float(steering) == _expected(seen)
            assert float(throttle) == 0.25


@pytest.mark.parametrize("encoding", ["png", "raw"])
def test_lossless_requests_give_the_in_process_prediction(
    server: PolicyServer, encoding: str
) -> None:
    remote = RemotePolicy(server.address, encoding=encoding, timeout_s=5.0)
    try:
        for seed, (h, w) in enumerate([(66, 200), (503, 800), (1, 1)]):
            image = _image(seed, h, w)
            assert remote.predict(Observation(0.0, image, STATE)) == _expected(image)
            assert remote.last_throttle == 0.25
    finally:
        remote.close()
    for seed in range(3):
        image = _image(seed, 5, 7)
        assert np.array_equal(decode_image(encode_image(image, "png")), image)
        assert np.array_equal(decode_image(encode_image(image, "raw")), image)


def test_our_client_talks_to_a_minimal_published_server() -> None:
    seen: list[bytes] = []

    def published(listener: socket.socket) -> None:  # sequential, JPEG in, "s,t" out
        for _ in range(2):
            conn, _ = listener.accept()
            with conn:
                while True:
                    try:
                        (n,) = struct.unpack(">I", _recv_exact(conn, 4))
                        data = _recv_exact(conn, n)
                    except EOFError:
                        break
                    seen.append(data[:3])
                    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
                    reply = f"{img[..., 2].mean() / 255:.6f},0.5".encode()
                    conn.sendall(struct.pack(">I", len(reply)) + reply)

    with socket.create_server(("127.0.0.1", 0)) as listener:
        thread = threading.Thread(target=published, args=(listener,))
        thread.start()
        remote = RemotePolicy(
            f"tcp://127.0.0.1:{listener.getsockname()[1]}", encoding="jpeg", control=False
        )
        try:
            remote.reset()  # no control message: the published server would not understand it
            image = np.full((66, 200, 3), 200, np.uint8)
            assert remote.predict(Observation(0.0, image, STATE)) == pytest.approx(200 / 255, 1e-2)
            assert remote.last_throttle == 0.5
        finally:
            remote.close()
            with socket.create_connection(listener.getsockname()):
                pass  # lets the server's second accept return
            thread.join(5)
    assert seen == [b"\xff\xd8\xff"]
    with pytest.raises(ConfigError, match="control"):
        RemotePolicy("tcp://127.0.0.1:1", smoothing=0.85, control=False)


def test_smoothing_and_reset_are_per_connection() -> None:
    images = [_image(seed) for seed in range(5)]
    preds = [_expected(img) for img in images]
    with PolicyServer(RedMean, clip=0.2).start() as srv:
        smooth = RemotePolicy(srv.address, encoding="raw", smoothing=0.85)
        plain = RemotePolicy(srv.address, encoding="raw")
        try:
            for _ in range(2):  # reset between runs starts the EMA afresh
                smooth.reset()
                ema: float | None = None
                for img, p in zip(images, preds, strict=True):
                    ema = p if ema is None else 0.85 * ema + 0.15 * p
                    got = smooth.predict(Observation(0.0, img, STATE))
                    assert got == pytest.approx(min(max(ema, -0.2), 0.2), abs=1e-12)
                    expected = min(max(p, -0.2), 0.2)
                    assert plain.predict(Observation(0.0, img, STATE)) == expected
        finally:
            smooth.close()
            plain.close()


def test_several_clients_at_once_get_their_own_answers(server: PolicyServer) -> None:
    errors: list[BaseException] = []

    def client(k: int) -> None:
        try:
            remote = RemotePolicy(server.address, encoding="raw", timeout_s=10.0)
            try:
                for i in range(20):
                    image = _image(100 * k + i, 8, 8)
                    assert remote.predict(Observation(0.0, image, STATE)) == _expected(image)
            finally:
                remote.close()
        except BaseException as err:  # noqa: BLE001  (re-raised in the main thread)
            errors.append(err)

    threads = [threading.Thread(target=client, args=(k,)) for k in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert not errors, errors


def _fuzz_messages(rng: random.Random, limit: int) -> Iterator[tuple[bytes, bool]]:
    """Bad messages, and whether the client also shuts its sending side (else the server must
    close by itself)."""
    for _ in range(25):
        yield rng.randbytes(rng.randint(1, 300)), True  # random bytes
        yield rng.randbytes(rng.randint(1, 3)), True  # truncated length prefix
        n = rng.randint(2, 5000)
        yield struct.pack(">I", n) + rng.randbytes(rng.randint(0, n - 1)), True  # truncated
        yield struct.pack(">I", rng.randint(limit + 1, 2**32 - 1)), False  # oversized
        for magic in (b"\xff\xd8\xff", b"\x89PNG\r\n\x1a\n", b"C2SR", b"C2SC", b""):
            body = magic + rng.randbytes(rng.randint(0, 200))
            yield frame(body), False  # garbage images / controls
    huge_png = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + struct.pack(">II", 60000, 60000)
    yield frame(huge_png + bytes(20)), False
    yield frame(b"C2SR" + struct.pack(">HHB", 4, 4, 3) + bytes(47)), False
    yield frame(control_message() + b"x"), False
    yield frame(b"C2SC" + b'{"smoothing": 1.5}'), False


def test_fuzzed_clients_are_dropped_and_the_server_keeps_serving(
    caplog: pytest.LogCaptureFixture,
) -> None:
    rng = random.Random(1234)
    limit = 1 << 16
    image = _image(7)
    caplog.set_level(logging.WARNING, logger="cam2sim.ads.serve")
    with PolicyServer(RedMean(), max_message_bytes=limit).start() as srv:
        good = RemotePolicy(srv.address, encoding="raw")
        try:
            count = 0
            t0 = time.monotonic()
            for message, shut in _fuzz_messages(rng, limit):
                with socket.create_connection(("127.0.0.1", srv.port), timeout=5) as sock:
                    with contextlib.suppress(OSError):  # the server may close mid-send
                        sock.sendall(message)
                        if shut:
                            sock.shutdown(socket.SHUT_WR)
                    with contextlib.suppress(ConnectionResetError):
                        while sock.recv(4096):  # no reply to a bad message; then EOF
                            pytest.fail(f"server replied to {message[:16]!r}")
                count += 1
                if count % 50 == 0:
                    assert good.predict(Observation(0.0, image, STATE)) == _expected(image)
            assert time.monotonic() - t0 < 15
            assert good.predict(Observation(0.0, image, STATE)) == _expected(image)
        finally:
            good.close()
    assert sum("closing the connection" in r.getMessage() for r in caplog.records) >= count // 2
    assert "exceeds the limit" in caplog.text
    assert "does not decode" in caplog.text


def test_the_client_reconnects_after_a_server_restart() -> None:
    first = PolicyServer(ConstantPolicy(1.0)).start()
    port = first.port
    remote = RemotePolicy(first.address, encoding="raw", timeout_s=5.0)
    obs = Observation(0.0, _image(1, 4, 4), STATE)
    try:
        assert remote.predict(obs) == 1.0
        first.close()
        with PolicyServer(ConstantPolicy(2.0), port=port).start():
            assert remote.predict(obs) == 2.0
            assert remote.predict(obs) == 2.0
    finally:
        remote.close()
        first.close()


def test_a_hung_server_times_out_with_a_stage_error() -> None:
    with socket.create_server(("127.0.0.1", 0)) as listener:  # accepts (backlog), never replies
        port = listener.getsockname()[1]
        remote = RemotePolicy(f"tcp://127.0.0.1:{port}", encoding="raw", timeout_s=0.3)
        try:
            t0 = time.monotonic()
            with pytest.raises(StageError, match=f"127.0.0.1:{port} sent no reply within 0.3 s"):
                remote.predict(Observation(0.0, _image(1, 4, 4), STATE))
            assert time.monotonic() - t0 < 2.0
        finally:
            remote.close()


def test_serve_entry_point_and_configuration_errors() -> None:
    ready = threading.Event()
    servers: list[PolicyServer] = []

    def on_ready(srv: PolicyServer) -> None:
        servers.append(srv)
        ready.set()

    kwargs = {"port": 0, "on_ready": on_ready}
    thread = threading.Thread(target=serve, args=("constant:1.5",), kwargs=kwargs)
    thread.start()
    try:
        assert ready.wait(10)
        remote = RemotePolicy(servers[0].address, encoding="jpeg")
        try:
            assert remote.predict(Observation(0.0, _image(3), STATE)) == 1.5
        finally:
            remote.close()
    finally:
        if servers:
            servers[0].close()
        thread.join(10)
    assert not thread.is_alive()
    with pytest.raises(ConfigError, match="allow_remote"):
        PolicyServer(RedMean(), host="0.0.0.0")
    with pytest.raises(ConfigError, match="png, jpeg, raw"):
        RemotePolicy("tcp://127.0.0.1:1", encoding="bmp")
    with pytest.raises(ConfigError, match="smoothing"):
        control_message(smoothing=1.0)
