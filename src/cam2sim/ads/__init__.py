"""Driving policies for closed-loop runs: what steers the simulated vehicle.

:mod:`.policy` defines the :class:`~cam2sim.ads.policy.SteeringPolicy` interface (one camera
frame in, one steering command out), the built-in ``pure-pursuit`` reference driver, image
models (ONNX, torch) and a small TCP protocol for policies that run in another process.
"""
