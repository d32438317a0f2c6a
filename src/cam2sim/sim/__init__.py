"""Simulator backends: the :class:`~cam2sim.sim.interface.Simulator` protocol and ``builtin``.

``interface`` holds the protocol and re-exports its typed records (controls, states, events,
the steering calibration), which live in :mod:`cam2sim.core.vehicle`; ``builtin`` is the
embedded, deterministic CPU backend.
"""
