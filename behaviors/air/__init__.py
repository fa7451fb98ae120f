"""Air model (Nucleus section 5; Avatar supplement section 2): ``wind`` (the air velocity field),
``drag`` (implicit drag matrices and explicit lift) and their numba ``kernels``."""

from .drag import AirDrag
from .wind import WindField

__all__ = ["AirDrag", "WindField"]
