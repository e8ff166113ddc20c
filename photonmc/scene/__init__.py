"""Scene loading: Mitsuba 3 XML subset -> numpy Scene."""
from .loader import load_scene
from .scene import Scene

__all__ = ["Scene", "load_scene"]
