"""A stand-in for a CARLA server's client, world and actors (tests of the CARLA backend).

It records what the backend asks for and moves the hero at its Ackermann speed on every tick,
sending small camera images, so the backend's whole life cycle runs without a server.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class FakeSettings:
    synchronous_mode: bool = False
    fixed_delta_seconds: float | None = None


@dataclass
class FakeBlueprint:
    id: str
    attributes: dict[str, str] = field(default_factory=dict)

    def has_attribute(self, name: str) -> bool:
        return name == "role_name" or name in self.attributes

    def set_attribute(self, name: str, value: str) -> None:
        self.attributes[name] = value


class FakeLibrary:
    def __init__(self, ids: tuple[str, ...]) -> None:
        self.ids = ids

    def filter(self, pattern: str) -> list[FakeBlueprint]:
        prefix = pattern.rstrip("*")
        return [FakeBlueprint(i) for i in self.ids if i.startswith(prefix)]

    def find(self, name: str) -> FakeBlueprint:
        return FakeBlueprint(name)


@dataclass
class FakeImage:
    frame: int
    width: int
    height: int
    raw_data: bytes


class FakeActor:
    def __init__(self, world: FakeWorld, bp: FakeBlueprint, tf: Any, parent: Any) -> None:
        self.world, self.type_id, self.attributes = world, bp.id, dict(bp.attributes)
        self.transform, self.parent = tf, parent
        self.physics = True
        self.callback: Any = None
        self.destroyed = self.stopped = False
        self.controls: list[Any] = []
        self.velocity = (0.0, 0.0, 0.0)

    def set_simulate_physics(self, on: bool) -> None:
        self.physics = on

    def set_transform(self, tf: Any) -> None:
        self.transform = tf

    def get_transform(self) -> Any:
        return self.transform

    def set_target_velocity(self, v: Any) -> None:
        self.velocity = (v.x, v.y, v.z)

    def set_target_angular_velocity(self, v: Any) -> None:
        pass

    def get_velocity(self) -> Any:
        import carla

        return carla.Vector3D(*self.velocity)

    def apply_ackermann_control(self, control: Any) -> None:
        self.controls.append(control)

    def listen(self, callback: Any) -> None:
        self.callback = callback

    def stop(self) -> None:
        self.stopped = True

    def destroy(self) -> bool:
        self.destroyed = True
        self.world.destroyed.append(self)
        return True


class FakeWorld:
    def __init__(
        self,
        xodr: str,
        fail_vehicle_spawn: int | None = None,
        interrupt_sensor: bool = False,
        available: tuple[str, ...] = (),
    ) -> None:
        import carla

        self.available = available
        self.map = carla.Map("fake", xodr)
        self.applied: list[FakeSettings] = []
        self.current = FakeSettings()
        self.actors: list[FakeActor] = []
        self.destroyed: list[FakeActor] = []
        self.frame = 100
        self.fail_vehicle_spawn = fail_vehicle_spawn
        self.interrupt_sensor = interrupt_sensor
        self.vehicle_spawns = 0

    def get_settings(self) -> FakeSettings:
        return FakeSettings(self.current.synchronous_mode, self.current.fixed_delta_seconds)

    def apply_settings(self, s: FakeSettings) -> None:
        self.applied.append(s)
        self.current = s

    def get_map(self) -> Any:
        return self.map

    def get_blueprint_library(self) -> FakeLibrary:
        return FakeLibrary(self.available)

    def spawn_actor(self, bp: FakeBlueprint, tf: Any, attach_to: Any = None) -> FakeActor:
        if bp.id.startswith("vehicle."):
            self.vehicle_spawns += 1
            if self.vehicle_spawns == self.fail_vehicle_spawn:
                msg = "Spawn failed because of collision at spawn position"
                raise RuntimeError(msg)
        if bp.id.startswith("sensor.") and self.interrupt_sensor:
            raise KeyboardInterrupt
        actor = FakeActor(self, bp, tf, attach_to)
        self.actors.append(actor)
        return actor

    def tick(self) -> int:
        """Move the hero at its Ackermann speed and send the camera images."""
        import carla

        self.frame += 1
        for a in self.actors:
            if a.attributes.get("role_name") == "hero" and a.controls:
                v, tf = a.controls[-1].speed, a.transform
                yaw = math.radians(tf.rotation.yaw)
                loc = carla.Location(
                    x=tf.location.x + v * math.cos(yaw) / 30.0,
                    y=tf.location.y + v * math.sin(yaw) / 30.0,
                    z=tf.location.z,
                )
                a.transform = carla.Transform(loc, tf.rotation)
                a.velocity = (v * math.cos(yaw), v * math.sin(yaw), 0.0)
            if a.type_id.startswith("sensor.camera") and a.callback is not None:
                w = int(a.attributes.get("image_size_x", 8))
                h = int(a.attributes.get("image_size_y", 5))
                raw = np.zeros((h, w, 4), np.uint8)
                raw[..., 0], raw[..., 2] = 10, 7  # B, R
                raw[h - h // 2 :, :, 1] = 200  # G: the lower half
                a.callback(FakeImage(self.frame, w, h, raw.tobytes()))
        return self.frame


class FakeClient:
    def __init__(self, **world_kw: Any) -> None:
        self.world_kw = world_kw
        self.world: FakeWorld | None = None
        self.params: Any = None

    def get_server_version(self) -> str:
        return "0.9.16"

    def generate_opendrive_world(self, xodr: str, params: Any) -> FakeWorld:
        self.params = params
        self.world = FakeWorld(xodr, **self.world_kw)
        return self.world
