"""The OpenCL context, queue and program cache shared by every kernel wrapper."""

from __future__ import annotations

import os
import shutil
import threading
import warnings
from dataclasses import dataclass, field
from functools import lru_cache
from importlib.resources import as_file, files

from relight.errors import RelightError


@dataclass
class Runtime:
    """One OpenCL context + in-order queue on one device, and the programs built for it."""

    context: object
    queue: object
    device: object
    programs: dict = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    @property
    def description(self) -> str:
        d = self.device
        return f"{d.platform.name} / {d.name.strip()} ({d.max_compute_units} compute units)"


def _pick_device(cl):
    """The device named by RELIGHT_CL_DEVICE (substring), else PoCL's CPU device, else any CPU."""
    want = os.environ.get("RELIGHT_CL_DEVICE", "").lower()
    devices = []
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:  # no ICD at all
        raise RelightError(f"no OpenCL platform found ({exc}); reinstall with `pip install 'pyopencl[pocl]'`") from exc
    for platform in platforms:
        for dev in platform.get_devices():
            devices.append(dev)
    if not devices:
        raise RelightError("no OpenCL device found; reinstall with `pip install 'pyopencl[pocl]'`")
    if want:
        for dev in devices:
            if want in f"{dev.platform.name} {dev.name}".lower():
                return dev
        raise RelightError(f"RELIGHT_CL_DEVICE={want!r} matches none of: "
                           + "; ".join(f"{d.platform.name} / {d.name}" for d in devices))
    for dev in devices:
        if "portable computing language" in dev.platform.name.lower():
            return dev
    for dev in devices:
        if dev.type & cl.device_type.CPU:
            return dev
    return devices[0]


def pin_pocl_threads() -> bool:
    """Ask PoCL to pin its worker threads to cores (``POCL_AFFINITY=1``) unless the user chose;
    True when set here. Must run before PoCL starts (before the first platform query).

    Why: unpinned, Linux's wake-affine scheduling puts the PoCL workers woken by the host thread
    on that thread's core after any idle pause, and they stay there: measured on the 2-core
    development machine, a 72k-pixel relight kernel took 1.5 ms on one core (process CPU time /
    wall time 1.0) against 0.75 ms pinned (1.8). PoCL pins worker i to CPU i, so only when this
    process may run on CPUs 0..n-1 (not inside a narrower cpuset).
    """
    if "POCL_AFFINITY" in os.environ:
        return False
    try:
        allowed = os.sched_getaffinity(0)
    except (AttributeError, OSError):
        return False
    if allowed != set(range(os.cpu_count() or 0)):
        return False
    os.environ["POCL_AFFINITY"] = "1"
    return True


@lru_cache(maxsize=1)
def get_runtime() -> Runtime:
    """The process-wide runtime (created on first use)."""
    pin_pocl_threads()
    import pyopencl as cl

    dev = _pick_device(cl)
    if "portable computing language" in dev.platform.name.lower() and shutil.which("ld") is None:
        # PoCL links each compiled kernel with the system linker and aborts the whole process
        # (no exception) when it is missing: say so before that can happen.
        raise RelightError("the OpenCL CPU driver (PoCL) needs the system linker `ld`, which is not on PATH; "
                           "install binutils (e.g. `apt-get install binutils`)")
    ctx = cl.Context([dev])
    return Runtime(context=ctx, queue=cl.CommandQueue(ctx), device=dev)


def kernel_source(name: str) -> str:
    """Text of ``kernels/<name>.cl`` (package data)."""
    return files("relight.kernels").joinpath(f"{name}.cl").read_text(encoding="utf-8")


def build_program(name: str, options: tuple[str, ...] = ()) -> object:
    """Build ``kernels/<name>.cl`` once per process (and per option set); cached on disk too.

    The kernels folder is on the include path, so sources can ``#include "common.h"``.
    """
    import pyopencl as cl

    rt = get_runtime()
    key = (name, tuple(options))
    with rt.lock:
        prg = rt.programs.get(key)
        if prg is None:
            with as_file(files("relight.kernels")) as folder, warnings.catch_warnings():
                if not compiler_output_wanted():
                    # PoCL's log on a successful build (on some CPUs a note about the target) is
                    # noise in a user's terminal: shown with --verbose or PYOPENCL_COMPILER_OUTPUT=1
                    warnings.simplefilter("ignore", cl.CompilerWarning)
                src = kernel_source(name)
                prg = cl.Program(rt.context, src).build(options=[*options, "-I", str(folder)])
            rt.programs[key] = prg
    return prg


#: Set to "1" (``relight --verbose``) to see the OpenCL compiler's output and full tracebacks.
VERBOSE_ENV = "RELIGHT_VERBOSE"


def compiler_output_wanted() -> bool:
    """Whether the OpenCL compiler's messages on successful builds are shown: with
    ``--verbose`` (:data:`VERBOSE_ENV`) or pyopencl's own ``PYOPENCL_COMPILER_OUTPUT=1``."""
    return os.environ.get(VERBOSE_ENV) == "1" or os.environ.get("PYOPENCL_COMPILER_OUTPUT") == "1"


#: Alignment (bytes) of host arrays handed to the device with USE_HOST_PTR: PoCL on the CPU then
#: uses them in place (no device copy).
ALIGN = 64


def _aligned(alloc, shape, dtype, align: int):
    """An array of ``shape`` and ``dtype`` in a buffer from ``alloc`` (np.zeros or np.empty) whose
    data start on an ``align``-byte boundary."""
    import numpy as np

    dtype = np.dtype(dtype)
    n = int(np.prod(shape)) * dtype.itemsize
    raw = alloc(n + align, dtype=np.uint8)
    off = (-raw.ctypes.data) % align
    return raw[off:off + n].view(dtype).reshape(shape)


def aligned_zeros(shape, dtype, align: int = ALIGN):
    """A zeroed C-ordered array whose data start on an ``align``-byte boundary."""
    import numpy as np

    return _aligned(np.zeros, shape, dtype, align)


def aligned_copy(a, align: int = ALIGN):
    """A C-ordered copy of ``a`` whose data start on an ``align``-byte boundary (handed to the
    device with USE_HOST_PTR, PoCL works on it in place)."""
    import numpy as np

    a = np.asarray(a)
    out = _aligned(np.empty, a.shape, a.dtype, align)
    np.copyto(out, a)
    return out
