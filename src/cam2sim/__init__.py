"""cam2sim: a real driving recording in, a closed-loop simulation of the same street out."""

__version__ = "0.1.0"

__all__ = ["__version__"]
