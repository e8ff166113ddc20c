"""photonmc: a physically based renderer with MCMC-guided photon mapping, in Taichi.

    import photonmc
    image = photonmc.render("scene.xml", method="spatial-tf", time=30, seed=1)   # (H, W, 3) float32
    for frame in photonmc.iterate(method="sppm", iterations=64):                # progressive
        ...
"""
from .api import Frame, iterate, render
from .errors import PhotonmcError, SceneError, SettingsError
from .scene import load_scene

__version__ = "0.1.0"
__all__ = ["Frame", "PhotonmcError", "SceneError", "SettingsError", "__version__", "iterate", "load_scene",
           "render"]
