"""Simulator backends: the :class:`~cam2sim.sim.interface.Simulator` protocol and ``builtin``.

``interface`` holds the protocol and its typed records (controls, states, events, the steering
calibration); ``builtin`` is the embedded, deterministic CPU backend.
"""
