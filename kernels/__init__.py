"""OpenCL kernels (``*.cl``, package data) and their thin PyOpenCL host wrappers.

Kernels run on PoCL's CPU driver (installed with ``pyopencl[pocl]``). Programs are built
once per process and cached on disk by PyOpenCL/PoCL, so a second start is fast; every
kernel has a NumPy twin that the tests compare it with.
"""

from .runtime import Runtime, build_program, get_runtime

__all__ = ["Runtime", "build_program", "get_runtime"]
