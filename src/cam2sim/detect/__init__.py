"""Parked-vehicle detection: detectors behind one interface, fusion across frames, the editor.

Detectors (:mod:`.lidar`, the learned ones of :mod:`.learned` for LiDAR or camera, chosen by
:mod:`.detector`) turn one scan or one image into
:class:`~cam2sim.detect.boxes.Boxes` in the sensor frame. :mod:`.fusion` moves every box into
the world frame and fuses them into :class:`~cam2sim.detect.vehicles.ParkedVehicles`, the
editable list that ``cam2sim refine`` (:mod:`.editor`) changes by hand.
"""
