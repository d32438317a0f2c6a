"""The parked-vehicle editor: a local web page to fix ``WS/detections/parked_vehicles.json``.

``cam2sim refine WS`` runs :func:`serve_editor`; tests and tools use :class:`EditorServer`. The
page (``static/``) is plain JavaScript, served from the package, with no build step and nothing
loaded from outside 127.0.0.1.
"""

from cam2sim.detect.editor.server import EditorServer, serve_editor

__all__ = ["EditorServer", "serve_editor"]
