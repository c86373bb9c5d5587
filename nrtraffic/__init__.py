"""nrtraffic: co-simulation of signal-free intersections (SUMO + energy-optimal planning +
Newton-Raphson-flow tracking with control barrier functions).

The Python API, the same operations as the ``nrtraffic`` command (imported when first used, so
``import nrtraffic`` stays light):

- ``nrtraffic.run(scenario, *, seed=None, duration_s=None, out=None, overrides=None)`` -> ``Run``
- ``nrtraffic.baseline(scenario, junction, ...)`` -> ``Run``
- ``nrtraffic.sweep(scenario, seeds, *, grid=None, baselines=(), ...)`` -> ``Sweep``
- ``nrtraffic.Run(run_dir)`` opens a finished run directory.
"""

__version__ = "0.1.0"

from nrtraffic._kernel_cache import ensure_fresh as _ensure_fresh

_ensure_fresh()

_API = ("run", "baseline", "sweep", "Run", "Sweep")


def __getattr__(name: str):
    if name in _API:
        from runners import api  # (the API is the runners': the library itself never imports them)

        return getattr(api, name)
    raise AttributeError(f"module 'nrtraffic' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_API])
