"""etb-gym: electronic throttle body plants (Alt et al. models 1A..3C), Gymnasium envs, controllers."""
from .plant import MODELS, Plant, Trajectory, make_plant
from . import envs  # noqa: E402,F401  registers the Gymnasium ids ETB-1A-v0 .. ETB-3C-v0

__version__ = "0.1.0"
__all__ = ["MODELS", "Plant", "Trajectory", "make_plant", "__version__"]
