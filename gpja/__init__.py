"""gpja: Geometric-Photometric Joint Alignment for facial mesh registration."""
from gpja.errors import GpjaError, InputError

__version__ = "0.1.0"
__all__ = ["GpjaError", "InputError", "__version__"]
