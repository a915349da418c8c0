"""``relight.Relighter``: relight a bundle's face under environments, on the OpenCL device.

The one stateful object of the relighting engine: it holds the bundle's arrays on the device
(the texel-major maps memory-mapped from the bundle, not copied; the chosen rank of the basis
repacked for the kernel; the exact path's maps copied into aligned memory on first use), the
built kernels and the output frame, and caches the last environment's lights and the last
result (nothing is recomputed when neither the environment nor the rotation changed).

Per call: the environment's lights (computed once per environment) are turned by the head
rotation and splatted into the map's texels (:mod:`relight.kernels.transport`); then one kernel
launch either evaluates the compact transport (a rank-k basis plus the brightest texels
exactly) or, with ``exact=True``, the full sum over the maps. Only the head's pixels are
computed; the output is the full reference frame, linear RGB, zero outside ``bundle.mask``.

Beside it: the kernels' operands (:mod:`relight.kernels.relight_packing`), the recipe bundle's
texel rows (:mod:`relight.kernels.row_cache`), the checks of a call's inputs
(:mod:`relight.kernels.relight_inputs`; ``frozen`` and ``rotation_angle_deg`` importable from
here too) and the NumPy twin (:mod:`relight.kernels.relight_twin`).
"""

from __future__ import annotations

import hashlib

import numpy as np

from relight.errors import InputError
from relight.numerics import EPS_NORM

from . import texel_lights, transport
from .layout import padded_texels
from .relight_inputs import check_light, check_rotation, rotation_angle_deg
from .relight_packing import (
    LANES,
    compact_coefficients,
    exact_light_blocks,
    exact_maps,
    pack_basis,
    read_transport,
    unpack_basis,
)
from .row_cache import (
    PREFETCH_PITCH_DEG,
    PREFETCH_STEP_DEG,
    PREFETCH_YAW_DEG,
    RowCache,
    prefetch_texels,
    prefetch_turns,
    row_slots,
)
from .runtime import aligned_zeros, build_program, get_runtime

#: Relative L2 error a relight may have against the exact sum unless told otherwise: the finest the
#: bundle's compact transport serves (:data:`relight.kernels.transport.STORE_TOLERANCE`).
DEFAULT_TOLERANCE = transport.STORE_TOLERANCE

#: Work-group sizes (PoCL picks poorly for odd global sizes: measured 2-3x slower with None).
COMPACT_GROUP = 8
PIXEL_GROUP = 64


def _round_up(n: int, m: int) -> int:
    return (n + m - 1) // m * m


def _host_buffer(ctx, a: np.ndarray):
    """A read-only device buffer over the host array ``a`` itself (no copy)."""
    import pyopencl as cl

    return cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR, hostbuf=a)


def _shared_buffer(ctx, a):
    """A read-only device buffer over one of the bundle's arrays, used in place where the device
    can (PoCL on the CPU: the host's memory-mapped file, no copy), else over a contiguous copy."""
    import pyopencl as cl

    a = np.asarray(a)
    if a.flags.c_contiguous:
        return cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR, hostbuf=a)
    return cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))


class Relighter:
    """Relights one bundle.

    tolerance : relative L2 error allowed against the exact path; the compact rank is the
    smallest whose error on the capture's validation environments meets it (no rank does: the
    exact path is used). exact : always evaluate the full maps.
    """

    def __init__(self, bundle, tolerance: float = DEFAULT_TOLERANCE, exact: bool = False):
        import pyopencl as cl

        if not (np.isfinite(tolerance) and tolerance > 0):
            raise InputError(f"tolerance {tolerance}: use a positive number such as 0.01 (1 %)")
        self.bundle = bundle
        self.rt = get_runtime()
        ctx = self.rt.context
        # Denormals flushed: see relight.numerics.HALF_TINY (halves below 2^-14 read as zero).
        prg = build_program("relight", ("-cl-denorms-are-zero",))
        self._k_compact = cl.Kernel(prg, "relight_compact")
        self._k_exact = cl.Kernel(prg, "relight_exact")
        frame_size = self._read_bundle(bundle)
        self.tolerance = float(tolerance)
        self.rank = None if exact else self.transport.rank_for(self.tolerance)
        self.exact = self.rank is None
        self._make_frame(frame_size)
        # The exact texels' maps: the bundle's own (memory-mapped) when it stores them, else a
        # cache of texel rows made from its recipe on first use (least recently used reused).
        if bundle.has_maps:
            self.row_cache = None
            self._rows_buf = _shared_buffer(ctx, bundle.maps_rows)
        else:
            self.row_cache = RowCache(bundle, row_slots(bundle.n_pixels))
            self._rows_buf = self.row_cache.buf
        self._upload_basis()
        self._fidx = cl.Buffer(ctx, cl.mem_flags.READ_ONLY | cl.mem_flags.COPY_HOST_PTR, hostbuf=self.frame_index)
        # The frame lives in host memory the device writes into directly (no copy back). More
        # frames ("slots", e.g. the face under the live light beside the target) on request.
        self._frame_buf = cl.Buffer(ctx, cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR, hostbuf=self.frame)
        self._slots = {"main": (self.frame, self._frame_buf)}
        self._make_light_operands()
        self._set_compact_args()
        # The exact path's maps: built on first use (see _exact_maps).
        self.t_exact = _round_up(self.t_pad, LANES)
        self._maps_buf = None
        self._lp = cl.Buffer(ctx, cl.mem_flags.READ_ONLY, 3 * self.t_exact * 4)
        self._blocks = cl.Buffer(ctx, cl.mem_flags.READ_ONLY, (self.t_exact // LANES) * 4)
        self._queue = self.rt.queue
        self._pending = None  # (buf, frame) of a launch not yet waited for (relight(wait=False))
        if self.exact:
            self._exact_maps()
        self._init_caches()

    def _read_bundle(self, bundle) -> tuple[int, int]:
        """The bundle's layout - its map texels, pixels, sample scale (checked), compact transport
        and the texels' hull cone - and its frame size (W, H)."""
        self.texels = np.asarray(bundle.map_texels, dtype=np.int64)
        self.map_size = bundle.map_size
        # Samples and maps are stored divided by this power of two (float16 range; 1 for ordinary
        # captures): the light is multiplied by it instead, so results are in capture units.
        self.sample_scale = float(bundle.meta.get("sample_scale", 1.0))
        if not (np.isfinite(self.sample_scale) and self.sample_scale > 0):
            raise InputError(f"{bundle.path}: sample_scale {self.sample_scale} must be a positive number; "
                             "the bundle is damaged - capture it again")
        self.n_pix = bundle.n_pixels
        self.t_pad = padded_texels(int(self.texels.size))
        self._maps = None
        frame_size = bundle.frame_size
        self.frame_index = bundle.frame_index
        self.transport = read_transport(bundle)
        self.cone = texel_lights.hull_cone(self.map_size, self.texels)
        return frame_size

    def _make_frame(self, frame_size) -> None:
        """The output frame (H, W, 3) float32, zero, and the flat float range of its rows the
        face spans, from its first to its last (:meth:`fresh_copy`)."""
        w, h = frame_size
        self.frame = np.zeros((h, w, 3), dtype=np.float32)
        fi = np.asarray(self.frame_index)
        self._face_span = ((int(fi.min()) // w) * w * 3, (int(fi.max()) // w + 1) * w * 3) if fi.size else (0, 0)

    def _upload_basis(self) -> None:
        """Only the chosen rank of the basis, in the kernel's blocks as the bundle stores it, and
        device buffers over it (8-bit steps and units, 4-bit steps and units)."""
        self._basis = pack_basis(self.transport, self.rank, self.n_pix)
        self.rank8, self.rank4, self._q8, self._units, self._q4, self._units4 = self._basis
        ctx = self.rt.context
        self._q8_buf, self._units_buf = _host_buffer(ctx, self._q8), _host_buffer(ctx, self._units)
        self._q4_buf, self._units4_buf = _host_buffer(ctx, self._q4), _host_buffer(ctx, self._units4)

    def _make_light_operands(self) -> None:
        """The per-call light (the basis coefficients (rank, 4); the exact texels' light and rows
        (n, 4)) in host memory the kernel reads in place: written between launches (each call
        waits for its kernel), no enqueued copies (each cost ~0.3 ms of PyOpenCL overhead)."""
        self._n_direct_max = max(self.transport.direct, 4)
        self._coef4 = aligned_zeros((max(self.rank or 1, 1), 4), np.float32)
        self._direct4 = aligned_zeros((self._n_direct_max, 4), np.float32)
        self._coef = _host_buffer(self.rt.context, self._coef4)
        self._direct = _host_buffer(self.rt.context, self._direct4)
        # u^T of the chosen rank in float64 (the light is float64: a float32 u was cast every call)
        self._ut = np.ascontiguousarray(self.transport.u[:, :self.rank].T, dtype=np.float64) if self.rank else None

    def _set_compact_args(self) -> None:
        """The compact kernel's arguments set once (a call sets the rank, the texel count and the
        frame) and its launch grid."""
        self._k_compact.set_args(self._q8_buf, np.int32(0), np.int32(self._q8.shape[1]), self._units_buf,
                                 self._q4_buf, np.int32(0), np.int32(self._q4.shape[1]), self._units4_buf,
                                 self._coef, self._rows_buf, np.int32(self.n_pix), self._direct, np.int32(0),
                                 self._fidx, np.int32(self.n_pix), self._frame_buf)
        self._compact_grid = ((_round_up(-(-self.n_pix // LANES), COMPACT_GROUP),), (COMPACT_GROUP,))

    def _init_caches(self) -> None:
        """Nothing cached yet: no environment's lights, no last relight; the call counters at 0."""
        self._env_key = None  # (shape, dtype, digest) of the environment whose lights are cached
        self._env_array = None  # that environment (identity: a frozen array is not hashed again)
        self._env_lights = None
        self._env_generation = 0  # bumped when the cached lights change
        self._last_key = None  # (environment generation, rotation, exposure) of the last relight
        self._last_rotation = None
        self._last_frame = None  # the array the last relight filled
        self._prefetched_generation = -1  # the environment prefetch_rows last made rows for
        self._bound = None  # (buffer, array) of the last caller's out
        self.relit = 0  # relights run by relight() (figures for benchmarks)
        self.reused = 0  # calls of relight() answered by the last result (reuse_deg)

    @property
    def maps(self) -> np.ndarray:
        """(P, 3, Tp) float16 pixel-major maps (the bundle's, or gathered from its texel-major rows
        once: :meth:`relight.kernels.bundle.Bundle.pixel_maps`)."""
        if self._maps is None:
            self._maps = self.bundle.pixel_maps() if self.bundle.has_maps else \
                self._exact_maps_host()[:, :, :self.t_pad]
        return self._maps

    # ------------------------------------------------------------------ direction space
    def lights(self, env: np.ndarray) -> texel_lights.EnvLights:
        """The environment's lights, cached by the array's contents: an environment edited in
        place is seen as new. A read-only array that owns its data (``env.flags.writeable =
        False``: :class:`relight.engine.frame_path.FramePath` freezes its environment) is
        recognised again by identity alone; any other array is hashed (BLAKE2b, ~4 ms for a
        512x256 map, a tenth of what making its lights takes)."""
        arr = np.asarray(env)
        frozen = arr is self._env_array and not arr.flags.writeable and arr.flags.owndata
        if not frozen:
            digest = hashlib.blake2b(memoryview(np.ascontiguousarray(arr)).cast("B"), digest_size=16)
            key = (arr.shape, arr.dtype.str, digest.digest())
            if key != self._env_key:
                self._env_lights = texel_lights.environment_lights(arr)
                self._env_key = key
                self._env_generation += 1
            self._env_array = arr
        return self._env_lights

    def prefetch_rows(self, env, *, yaw_deg: float = PREFETCH_YAW_DEG, pitch_deg: float = PREFETCH_PITCH_DEG,
                      step_deg: float = PREFETCH_STEP_DEG) -> None:
        """A recipe bundle: make ahead, on a thread of its own
        (:meth:`relight.kernels.row_cache.RowCache.prefetch`), the texel rows the exact part of
        relighting ``env`` asks for while the head turns within +-``yaw_deg`` and +-``pitch_deg``
        - the brightest texels at each turn of a grid ``step_deg`` apart, the smaller turns first
        (:func:`relight.kernels.row_cache.prefetch_texels`). A live video's first turns toward a sun
        then find its rows made instead of stopping for them (~30 ms each at 100k pixels, most
        of it per launch: ahead, eight share one). Nothing for a bundle that stores its maps, nor
        again for the environment last asked for (the service's sessions share one Relighter and
        each sets the environment it starts with)."""
        if self.row_cache is None or self.exact:
            return
        lights, n = self.lights(env), self.transport.direct
        if self._prefetched_generation == self._env_generation:
            return
        self._prefetched_generation = self._env_generation
        turns = prefetch_turns(yaw_deg, pitch_deg, step_deg)
        self.row_cache.prefetch(lambda: prefetch_texels(lights, turns, n, self.map_size, self.texels,
                                                        self.sample_scale, self.cone))

    def texel_light(self, env, rotation=None, exposure: float = 1.0) -> np.ndarray:
        """(T, 3) ``Lp``: the environment in the map's texels for a head turned by ``rotation``."""
        return texel_lights.texel_light(self.lights(env), check_rotation(rotation), self.map_size, self.texels,
                                     exposure * self.sample_scale, self.cone)

    # ------------------------------------------------------------------ relighting
    def relight(self, env: np.ndarray, rotation=None, *, exposure: float = 1.0, reuse_deg: float = 0.0,
                out: np.ndarray | None = None, wait: bool = True, direct: int | None = None) -> np.ndarray:
        """The reference frame relit: a new (H, W, 3) float32 array of linear RGB, the face
        inside ``bundle.mask`` and zero elsewhere - or ``out``, filled in place.

        What a call costs, beyond the kernel (measured by ``relight bench relight``, "plain"
        against "ms/call"): an environment from :func:`relight.load_environment` (read-only) or
        :func:`frozen` is known by identity after its first call - nothing more; any other array
        is hashed on every call to see whether it changed (BLAKE2b, ~1 ms for a 512x256 map), so
        pass the same frozen array each call. Without ``out`` the result is a new zeroed array
        with the frame's rows that hold the face copied in (:meth:`fresh_copy`; its other pages
        never touched): ~0.2-0.3 ms more than filling ``out`` at 640x360, ~1.2x the hot path in
        all. With ``out`` nothing is allocated (the hot path, :class:`relight.engine.frame_path.
        FramePath`'s).

        env : (H, 2H, 3) linear radiance (see :func:`relight.load_environment`). rotation : 3x3
        head rotation (camera from head) or None. exposure : linear scale of the environment.
        direct : how many of the light's brightest texels go through their exact rows (None: the
        bundle's, 8); 0 - a draft while a light is being moved - makes no row and reads none
        (measured on the live clip: ~0.7 % relative L2 from the exact maps for a smooth light).
        reuse_deg : when > 0, a call whose environment and exposure are the last relight's and
        whose rotation is within this angle (degrees) of its rotation, into the same ``out``,
        leaves that result instead of relighting (``reused`` counts them, ``relit`` the
        relights): the error added is about 1.7 % per degree at worst on the bench's scenes (a
        point light), see :data:`relight.engine.frame_settings.REUSE_DEG`.
        out : the hot path's target, as NumPy's ``out=``: a writeable C-contiguous (H, W, 3)
        float32 array the kernel writes the face pixels into directly (no copy; the pixels
        outside the face are left as they are). Pass the same array every frame; a call that
        reuses the last result leaves ``out`` as the last call made it, so do not write into it
        between calls.
        wait : False (only with ``out``) returns as soon as the kernel is queued, so the host
        may do other work while it runs: call :meth:`sync` before reading ``out``; kernels
        queued later on the runtime's queue (the compositor's) run after it anyway.
        """
        if not (np.isfinite(exposure) and exposure > 0):
            raise InputError(f"exposure {exposure}: must be a positive finite scale")
        if out is None and not wait:
            raise InputError("relight(wait=False) needs out=: the array the kernel fills while the host goes on")
        buf, frame = self._frame_buf, self.frame
        if out is not None:
            buf, frame = self._bind(out)
        r = check_rotation(rotation)
        self.lights(env)
        key = (self._env_generation, None if r is None else r.round(12).tobytes(), float(exposure), direct)
        same_target = frame is self._last_frame
        if same_target and key == self._last_key:
            return self._result(out)
        if (same_target and reuse_deg > 0 and r is not None and self._last_rotation is not None
                and self._last_key is not None and self._last_key[0] == key[0] and self._last_key[2:] == key[2:]
                and rotation_angle_deg(self._last_rotation, r) < reuse_deg):
            # Leave out a relight the head's small turn does not need: the result of the last
            # relight (its rotation within reuse_deg of this one; drift cannot build up).
            self.reused += 1
            return self._result(out)
        lp = check_light(texel_lights.texel_light(self._env_lights, r, self.map_size, self.texels,
                                               exposure * self.sample_scale, self.cone))
        if self.exact:
            self._run_exact(lp, buf, frame)
        else:
            self._run_compact(lp, buf, frame, wait=wait, direct=direct)
        self._last_key, self._last_rotation = key, r
        self._last_frame = frame
        self.relit += 1
        return self._result(out)

    def _result(self, out: np.ndarray | None) -> np.ndarray:
        if out is not None:
            return out
        self.sync()
        return self.fresh_copy()

    def fresh_copy(self) -> np.ndarray:
        """A new array holding the Relighter's frame: zeroed (untouched pages are the system's
        zero pages, costing nothing) with only the rows the face spans copied - the frame is zero
        outside the face, so this is the frame, for ~a third of a full copy's cost."""
        out = np.zeros(self.frame.shape, np.float32)
        a, b = self._face_span
        out.reshape(-1)[a:b] = self.frame.reshape(-1)[a:b]
        return out

    def _bind(self, out: np.ndarray):
        """(buffer, array) of a caller's ``out`` (the buffer wraps its memory; kept for the next call)."""
        if not isinstance(out, np.ndarray) or out.shape != self.frame.shape or out.dtype != np.float32 \
                or not out.flags.c_contiguous or not out.flags.writeable:
            shape = getattr(out, "shape", None)
            dtype = getattr(out, "dtype", type(out).__name__)
            raise InputError(f"out of shape {shape} ({dtype}): pass a writeable C-contiguous float32 array of "
                             f"shape {self.frame.shape}, e.g. np.zeros({self.frame.shape}, np.float32)")
        if out is self.frame:
            return self._frame_buf, self.frame
        if self._bound is None or self._bound[1] is not out:
            import pyopencl as cl

            self.sync()
            self._bound = (cl.Buffer(self.rt.context, cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR,
                                     hostbuf=out), out)
        return self._bound

    def buffer(self, out: np.ndarray | None = None):
        """The OpenCL buffer that holds ``out`` (an array :meth:`relight` fills in place), or the
        Relighter's own frame (None): what kernels queued after a relight read it from."""
        return self._frame_buf if out is None else self._bind(out)[0]

    def relight_light(self, direction, *, exposure: float = 1.0) -> np.ndarray:
        """The reference frame under one directional light as strong as the capture flash: a new
        (H, W, 3) float32 array. Reads only the (up to four) map texels around ``direction`` -
        no environment needed.
        """
        d = np.asarray(direction, dtype=np.float64)
        if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) < EPS_NORM:
            raise InputError(f"light direction {direction}: three finite numbers, not all zero")
        lp = check_light(texel_lights.point_light(d, self.map_size, self.texels) * (exposure * self.sample_scale))
        self._run_rows(lp)
        self._forget_main()
        return self.frame.copy()

    def _forget_main(self) -> None:
        """The Relighter's own frame was overwritten: the next relight into it runs again."""
        if self._last_frame is self.frame:
            self._last_key = None

    def relight_texels(self, lp: np.ndarray, *, slot: str = "main", direct: int | None = None) -> np.ndarray:
        """The reference frame under a light given in the map's texels: ``lp`` (T, 3) the power
        each stored texel (``bundle.map_texels``) sends, over pi, in flash units (a light as
        strong as the capture flash sums to 1). Written into the frame ``slot`` (a name: each slot
        is one (H, W, 3) frame owned by the Relighter, "main" the one :meth:`relight` fills);
        returns it (read-only until the slot's next call). direct : how many of the brightest
        texels are relit exactly, outside the low-rank part (None: the transport's
        ``DIRECT_TEXELS``; 0: none - no texel row of a recipe bundle is ever made for it)."""
        lp = np.asarray(lp, dtype=np.float64)
        if lp.shape != (self.texels.size, 3):
            raise InputError(f"texel light of shape {lp.shape}: expected ({self.texels.size}, 3)")
        lp = check_light(lp * self.sample_scale)
        frame, buf = self.slot(slot)
        if self.exact:
            self._run_exact(lp, buf, frame)
        else:
            self._run_compact(lp, buf, frame, direct=direct)
        if slot == "main":
            self._forget_main()
        return self._view(frame)

    def slot(self, name: str):
        """(frame (H, W, 3) float32, its OpenCL buffer) of an output slot, made on first use."""
        hit = self._slots.get(name)
        if hit is None:
            import pyopencl as cl

            frame = np.zeros_like(self.frame)
            buf = cl.Buffer(self.rt.context, cl.mem_flags.READ_WRITE | cl.mem_flags.USE_HOST_PTR, hostbuf=frame)
            hit = self._slots[name] = (frame, buf)
        return hit

    def _view(self, frame: np.ndarray | None = None) -> np.ndarray:
        out = (self.frame if frame is None else frame).view()
        out.flags.writeable = False
        return out

    def sync(self) -> None:
        """Wait for a relight queued with ``wait=False`` (nothing when none is pending)."""
        if self._pending is not None:
            buf, frame = self._pending
            self._pending = None
            self._finish(buf, frame)

    def _finish(self, buf=None, frame: np.ndarray | None = None) -> None:
        import pyopencl as cl

        # The one host sync per frame: mapping a host-pointer buffer waits for the kernel and,
        # on a CPU device, moves nothing.
        frame = self.frame if frame is None else frame
        mapped, _ = cl.enqueue_map_buffer(self._queue, self._frame_buf if buf is None else buf, cl.map_flags.READ, 0,
                                          frame.shape, frame.dtype)
        mapped.base.release()

    def _exact_maps(self):
        """The maps for the exact path, copied once into aligned anonymous memory padded to 32
        texels (the kernel streams them ~1.5x faster than from the bundle's memory map: page-cache
        pages are 4 kB and scattered) and checked finite on the way."""
        import pyopencl as cl

        if self._maps_buf is None:
            maps = exact_maps(self.bundle, self.t_pad, self.t_exact)
            self._maps_exact = maps
            self._maps_buf = cl.Buffer(self.rt.context, cl.mem_flags.READ_ONLY | cl.mem_flags.USE_HOST_PTR,
                                       hostbuf=maps)
        return self._maps_buf

    def _exact_maps_host(self) -> np.ndarray:
        self._exact_maps()
        return self._maps_exact

    def _launch_compact(self, rank: int, coef: np.ndarray | None, tex: np.ndarray, light: np.ndarray,
                        buf=None, frame=None, wait: bool = True) -> None:
        """One compact kernel launch and the frame's sync (``wait``; else left pending: :meth:`sync`):
        ``rank`` basis images with ``coef`` (rank, 3) plus the texels ``tex`` with their (n, 3)
        light, exactly (into ``buf``, the main frame's by default)."""
        import pyopencl as cl

        self.sync()  # the coefficients and rows below are host memory a pending launch still reads

        if tex.size > self._n_direct_max or rank > self._coef4.shape[0]:
            raise InputError(f"{tex.size} exact texels / rank {rank}: at most {self._n_direct_max} / "
                             f"{self._coef4.shape[0]} for this Relighter")
        if rank:
            self._coef4[:rank, :3] = compact_coefficients(coef, min(rank, self.rank8), max(rank - self.rank8, 0))
        self._direct4[:tex.size, :3] = light
        # rows of the texels in the rows buffer (the bundle's maps, or the recipe's cache), exact
        # in float32 (< 2^24)
        self._direct4[:tex.size, 3] = tex if self.row_cache is None else self.row_cache.slots(tex)
        k = self._k_compact
        k.set_arg(1, np.int32(min(rank, self.rank8)))  # the first ranks, 8-bit
        k.set_arg(5, np.int32(max(rank - self.rank8, 0)))  # the rest, 4-bit
        k.set_arg(12, np.int32(tex.size))
        k.set_arg(15, self._frame_buf if buf is None else buf)
        cl.enqueue_nd_range_kernel(self._queue, k, *self._compact_grid)
        if wait:
            self._finish(buf, frame)
        else:
            self._pending = (buf, frame)

    def _run_compact(self, lp: np.ndarray, buf=None, frame=None, wait: bool = True, direct: int | None = None) -> None:
        """``direct``: how many brightest texels go exact (None: the transport's)."""
        tex, rest = texel_lights.split_direct(lp, self.transport.direct if direct is None else direct)
        self._launch_compact(self.rank, self._ut @ rest, tex, lp[tex], buf, frame, wait)

    def _run_exact(self, lp: np.ndarray, buf=None, frame=None) -> None:
        import pyopencl as cl

        self.sync()
        maps = self._exact_maps()
        light, blocks = exact_light_blocks(lp, self.t_exact)
        q = self._queue
        cl.enqueue_copy(q, self._lp, light, is_blocking=False)
        cl.enqueue_copy(q, self._blocks, blocks.astype(np.int32) if blocks.size else np.zeros(1, np.int32),
                        is_blocking=False)
        grid = (_round_up(self.n_pix, PIXEL_GROUP),), (PIXEL_GROUP,)
        self._k_exact(q, *grid, maps, np.int32(self.t_exact), np.int32(self.n_pix), self._lp,
                      self._blocks, np.int32(blocks.size), self._fidx, self._frame_buf if buf is None else buf)
        self._finish(buf, frame)

    def _run_rows(self, lp: np.ndarray) -> None:
        """A few lit texels (a point light): the compact kernel with rank 0 reads just their rows."""
        lit = np.flatnonzero(np.abs(lp).sum(axis=1) > 0)
        if lit.size > self._n_direct_max:  # more than a few texels: the exact path
            self._run_exact(lp)
            return
        self._launch_compact(0, None, lit, lp[lit])

    def basis_f32(self) -> np.ndarray:
        """(P, 3, rank) float32: the chosen rank's basis images as the kernel reads them (steps x
        their step size), for references and tests."""
        return unpack_basis(self._basis, self.n_pix)

    def direct_rows(self, index: np.ndarray) -> np.ndarray:
        """(n, 3, P) float16 maps of the stored texels ``index`` (as the compact kernel reads them)."""
        index = np.asarray(index, dtype=np.int64)
        if self.row_cache is None:
            return np.asarray(self.bundle.maps_rows[index])
        return self.row_cache.rows[self.row_cache.slots(index)]

    # ------------------------------------------------------------------ references
    def relight_numpy(self, env, rotation=None, *, exposure: float = 1.0, exact: bool | None = None) -> np.ndarray:
        """The same relight computed by the NumPy twin from the bundle's stored arrays, in float64
        (:func:`relight.kernels.relight_twin.relight_numpy`, at this Relighter's tolerance; exact:
        None - this Relighter's path): (H, W, 3) float32 (for tests and benchmarks)."""
        from .relight_twin import relight_numpy

        return relight_numpy(self.bundle, env, check_rotation(rotation), exposure=exposure,
                             exact=self.exact if exact is None else exact, tolerance=self.tolerance)
