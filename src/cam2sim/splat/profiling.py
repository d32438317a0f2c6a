"""Opt-in per-phase timing of splat training steps (``TrainOptions.profile`` or the environment).

:class:`PhaseTimer` splits each step into phases (render, loss, backward, optimizer, densify,
validate) and sums, per phase, the host time (``perf_counter``: what Python and the launches
cost, plus any wait on the device) and, on CUDA, the device time between CUDA events recorded at
the phase borders (read back only every ``flush_every`` steps, so the timer adds no
synchronisation of its own in between). Disabled, every call is a no-op.

Enable with ``TrainOptions(profile=True)`` or ``CAM2SIM_SPLAT_PROFILE=1``.
"""

from __future__ import annotations

import itertools
import os
import time
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import torch

__all__ = ["ENV_VAR", "PhaseTimer", "profiling_requested"]

ENV_VAR = "CAM2SIM_SPLAT_PROFILE"
"""Set to ``1`` to time the phases of every training step (see :class:`PhaseTimer`)."""


def profiling_requested(option: bool) -> bool:
    """Whether ``option`` or the environment (:data:`ENV_VAR`) asks for phase timing."""
    return option or os.environ.get(ENV_VAR, "").strip().lower() in {"1", "true", "yes", "on"}


class PhaseTimer:
    """Host and device time per training phase (see the module doc)."""

    def __init__(self, *, enabled: bool, device: str, flush_every: int = 200) -> None:
        self.enabled = enabled
        self.cuda = enabled and device.startswith("cuda")
        self.flush_every = flush_every
        self.steps = 0
        self.host_s: dict[str, float] = {}
        self.device_ms: dict[str, float] = {}
        self._pending: list[list[tuple[str, Any]]] = []
        self._events: list[tuple[str, Any]] = []
        self._t = 0.0
        self._step_start = 0.0
        self.step_s = 0.0

    def _event(self) -> torch.cuda.Event:
        import torch  # noqa: PLC0415

        event = torch.cuda.Event(enable_timing=True)  # type: ignore[no-untyped-call]
        event.record()
        return event

    def begin(self) -> None:
        """Start a step."""
        if not self.enabled:
            return
        self._t = self._step_start = time.perf_counter()
        self._events = [("", self._event())] if self.cuda else []

    def mark(self, phase: str) -> None:
        """End ``phase`` (started at the previous mark or at :meth:`begin`)."""
        if not self.enabled:
            return
        now = time.perf_counter()
        self.host_s[phase] = self.host_s.get(phase, 0.0) + now - self._t
        self._t = now
        if self.cuda:
            self._events.append((phase, self._event()))

    def end(self) -> None:
        """End a step; reads the device times back every ``flush_every`` steps."""
        if not self.enabled:
            return
        self.steps += 1
        self.step_s += time.perf_counter() - self._step_start
        if self.cuda:
            self._pending.append(self._events)
            if len(self._pending) >= self.flush_every:
                self.flush()

    def flush(self) -> None:
        """Wait for the recorded events and add their intervals to the device times."""
        if not self._pending:
            return
        self._pending[-1][-1][1].synchronize()
        for events in self._pending:
            for (_, start), (phase, stop) in itertools.pairwise(events):
                self.device_ms[phase] = self.device_ms.get(phase, 0.0) + start.elapsed_time(stop)
        self._pending = []

    def summary(self) -> dict[str, float]:
        """``{"steps", "step_ms", "<phase>.host_ms", "<phase>.device_ms"}``, per step."""
        if not self.enabled or not self.steps:
            return {}
        self.flush()
        n = self.steps
        out = {"steps": float(n), "step_ms": 1e3 * self.step_s / n}
        for phase, seconds in self.host_s.items():
            out[f"{phase}.host_ms"] = 1e3 * seconds / n
        for phase, ms in self.device_ms.items():
            out[f"{phase}.device_ms"] = ms / n
        return out
