"""The OpenCL context, queue and program cache shared by every kernel wrapper."""

from __future__ import annotations

import os
import shutil
import threading
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


@lru_cache(maxsize=1)
def get_runtime() -> Runtime:
    """The process-wide runtime (created on first use)."""
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
            with as_file(files("relight.kernels")) as folder:
                src = kernel_source(name)
                prg = cl.Program(rt.context, src).build(options=[*options, "-I", str(folder)])
            rt.programs[key] = prg
    return prg
