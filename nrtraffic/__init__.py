__version__ = "0.1.0"

from nrtraffic._kernel_cache import ensure_fresh as _ensure_fresh

_ensure_fresh()
