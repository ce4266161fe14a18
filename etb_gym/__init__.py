"""etb-gym: electronic throttle body plants (Alt et al. models 1A..3C), Gymnasium envs, controllers."""
from .plant import MODELS, Plant, Trajectory, make_plant

__version__ = "0.1.0"
__all__ = ["MODELS", "Plant", "Trajectory", "make_plant", "__version__"]
