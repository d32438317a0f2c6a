"""Stage scenario: the reconstructed street as one simulator-neutral description.

:mod:`.model` holds ``scenario.json`` (:class:`~cam2sim.scenario.model.Scenario`), the single
description every simulator backend loads; :mod:`.body` derives the trajectory of the three
body points from the vehicle geometry; :mod:`.checks` tests parked vehicles against the map;
:mod:`.carla_export` writes the published tool's CARLA JSON files and :mod:`.openscenario` an
OpenSCENARIO 1.x file.
"""
