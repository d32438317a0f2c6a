"""Parked-vehicle detection: detectors behind one interface, fusion across frames, the editor.

Detectors (:mod:`.lidar`, :mod:`.camera`, :mod:`.learned`) turn one scan or one image into
:class:`~cam2sim.detect.boxes.Boxes` in the sensor frame. :mod:`.fusion` moves every box into
the world frame and fuses them into :class:`~cam2sim.detect.vehicles.ParkedVehicles`, the
editable list that ``cam2sim refine`` (:mod:`.editor`) changes by hand.
"""
