"""photonmc: a physically based renderer with MCMC-guided photon mapping, in Taichi."""
from .errors import PhotonmcError, SceneError, SettingsError
from .scene import load_scene

__version__ = "0.1.0"
__all__ = ["PhotonmcError", "SceneError", "SettingsError", "__version__", "load_scene"]
