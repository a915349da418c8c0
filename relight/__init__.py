"""relight: real-time relighting of a human face in video on a CPU.

Public API (stable names)::

    relight.load_environment(path_or_builtin)   # (H, 2H, 3) float32 linear radiance
    relight.load_bundle(path)                   # a reflectance bundle from `relight capture`
    r = relight.Relighter(bundle, tolerance=0.01, exact=False)
    img = r.relight(env, rotation=None)         # (H, W, 3) float32 linear, face inside bundle.mask

Architecture (docs/developing.md): ``relight.pipeline`` (offline capture -> reflectance bundle,
and the synthetic capture studio), ``relight.kernels`` (OpenCL C kernels on PoCL + host
wrappers), ``relight.engine`` (the per-frame engine), ``relight.service`` (the HTTP service),
``relight.apps`` (``relight filter``, ``relight live``), ``relight.cli`` (the command line).
Conventions are in :mod:`relight.directions`.
"""

from .envmap import load_environment
from .errors import InputError, NumericalError, RelightError


def __getattr__(name):
    # The relighting engine pulls in PyOpenCL: imported on first use only.
    if name == "Relighter":
        from .kernels.relighter import Relighter

        return Relighter
    raise AttributeError(f"module 'relight' has no attribute {name!r}")


def load_bundle(path, *, verify: bool = True):
    """Open a reflectance bundle written by ``relight capture`` (see :mod:`relight.kernels.bundle`)."""
    from .kernels.bundle import load_bundle as _load

    return _load(path, verify=verify)

__version__ = "0.1.0"

__all__ = ["InputError", "NumericalError", "RelightError", "Relighter", "__version__", "load_bundle",
           "load_environment"]
