"""The service's state: the loaded bundle and per-frame path (:class:`FrameService`, one frame at a
time under its lock) and the Prometheus metrics. Made in the app's lifespan, kept on ``app.state``
and handed to the routes by :mod:`relight.service.dependencies`.

The engine's lock is behind its API: its ``async`` methods take it (and run the work off the
event loop), so no route can forget it; the sessions share the relighter, one frame at a time.
Frames are decoded and encoded outside the lock (a client's JPEG work runs beside another's
relight). ``POST /v1/relight`` with a session id (:data:`SESSION_HEADER`, or the ``session``
query) keeps the client's track, filters and light between its requests (:meth:`FrameService.named_session`:
at most :data:`MAX_NAMED_SESSIONS`, the least recently used dropped, and any idle for
:data:`SESSION_IDLE_S`)."""

from __future__ import annotations

import asyncio
import re
import time
from collections import OrderedDict

import numpy as np

from relight.env_cache import EnvironmentCache

from .settings import ServeConfig

#: A single request's session id: this header, or the ``session`` query parameter.
SESSION_HEADER = "X-Relight-Session"
#: What a session id may be (letters, digits, "-", "_", ".": 1 to 64 of them).
SESSION_ID = re.compile(r"^[A-Za-z0-9._-]{1,64}$")
#: Named sessions kept at most, and how long one may sit unused before it is dropped (s).
MAX_NAMED_SESSIONS = 16
#: Environment maps kept loaded (each turned copy counts; uploads are kept besides).
ENV_CACHE = 16
SESSION_IDLE_S = 120.0


class Metrics:
    """The service's Prometheus metrics, in a registry of their own."""

    def __init__(self):
        from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

        self.registry = CollectorRegistry()
        self.frames = Counter("relight_frames", "Frames relit", registry=self.registry)
        self.dropped = Counter("relight_dropped_frames", "Stale stream frames dropped", registry=self.registry)
        self.errors = Counter("relight_errors", "Requests that failed, by kind", ["kind"], registry=self.registry)
        self.latency = Histogram("relight_frame_latency_seconds", "Time to relight one frame (s)",
                                 buckets=(0.005, 0.01, 0.015, 0.02, 0.03, 0.05, 0.1, 0.25, 1.0),
                                 registry=self.registry)
        self.clients = Gauge("relight_clients", "Connected stream clients (websocket and WebRTC)",
                             registry=self.registry)
        self.webrtc_sessions = Gauge("relight_webrtc_sessions", "Open WebRTC sessions", registry=self.registry)
        self.webrtc_sessions_total = Counter("relight_webrtc_sessions_opened", "WebRTC sessions opened",
                                             registry=self.registry)
        self.webrtc_frames = Counter("relight_webrtc_frames", "Frames relit on WebRTC tracks", registry=self.registry)
        self.webrtc_closed = Counter("relight_webrtc_sessions_closed", "WebRTC sessions closed, by reason",
                                     ["reason"], registry=self.registry)


class Session:
    """One client's per-frame path: its own tracker, filters and live light (a stream client's
    head is not another's), sharing the engine's :class:`~relight.kernels.relighter.Relighter`."""

    def __init__(self, path, env: np.ndarray):
        self.path = path
        self.env = env  # the environment array the path was last given (identity: unchanged)


class FrameService:
    """The loaded bundle and per-frame path, one frame at a time; environments cached by name.
    Each stream client gets a :class:`Session` (:meth:`session`); single requests share one."""

    def __init__(self, config: ServeConfig):
        import relight

        from ..engine.frame_path import FramePath
        from ..engine.frame_settings import FrameSettings

        self.config = config
        self.bundle = relight.load_bundle(config.bundle)
        self._envs = EnvironmentCache(ENV_CACHE)
        self.env_name = config.env
        # The service's current environment (PUT /v1/environment): used when a request names none.
        self.default_rotation: tuple[float, float, float] | None = None
        self.default_exposure = 0.0
        # The environment array the frame path was last given (the engine's cached arrays are
        # never edited in place, so identity says whether it changed; FramePath copies it).
        env = self.environment(config.env)
        settings = FrameSettings(mode=config.mode, focal=config.focal, region=config.region)
        self.shared = Session(FramePath(self.bundle, env, settings), env)
        self.path = self.shared.path
        # every kernel built and run once before the first request (none waits for a compile)
        self.warm_up_s = self.path.warm_up()
        # The stream clients' slow stages share two workers (.engine.threads.Worker: the field's,
        # the maps'): one of each kind runs at a time, whichever client's it is - per-client
        # workers ran eight slow stages at once for four clients, and their frames waited for the
        # cores (measured: 20 relit fps in all at 120 % CPU; one client alone, 29).
        from ..engine.threads import Worker

        self._workers = (Worker("relight-field", background=True), Worker("relight-maps", background=True))
        self._named: OrderedDict = OrderedDict()  # session id -> (Session, perf_counter of its last use)
        self._lock = asyncio.Lock()

    def close(self) -> None:
        """Stop the slow stages' worker threads the sessions share (the app's shutdown)."""
        for worker in self._workers:
            worker.close()

    # ------------------------------------------------------------------ the API (takes the lock)
    async def new_session(self) -> Session:
        """A new stream client's own per-frame path (its tracker, filters and live light)."""
        async with self._lock:
            return await asyncio.to_thread(self._session)

    async def relight_frame(self, rgb: np.ndarray, *, session: Session | None = None,
                            started: asyncio.Event | None = None, **settings):
        """(relit frame, FrameInfo) of one frame through ``session``'s path; without a session, a
        single request: the shared path starts afresh (a track, filters and a light of its own -
        one caller's frames are not another's), so every request is relit as a first frame.
        ``started`` is set once the frame has the engine (the other clients' frames before it done)."""
        async with self._lock:
            if started is not None:
                started.set()
            return await asyncio.to_thread(self._relight, rgb, session=session, **settings)

    async def named_session(self, name: str) -> Session:
        """The session a client named (made on its first request): its own track, filters and light,
        kept between its requests (module docstring)."""
        async with self._lock:
            now = time.perf_counter()
            for key in [k for k, (_, used) in self._named.items() if now - used > SESSION_IDLE_S]:
                del self._named[key]
            got = self._named.pop(name, None)
            session = got[0] if got is not None else await asyncio.to_thread(self._session, False)
            self._named[name] = (session, now)
            while len(self._named) > MAX_NAMED_SESSIONS:
                self._named.popitem(last=False)
            return session

    async def choose(self, name: str) -> None:
        """A built-in or loaded environment ``name`` becomes the current one (loaded now)."""
        async with self._lock:
            await asyncio.to_thread(self.environment, name)
            self.env_name = name

    async def upload(self, name: str, env: np.ndarray) -> None:
        """An uploaded (validated) environment becomes the current one under ``name``."""
        async with self._lock:
            self.set_uploaded(name, env)

    async def current_environment(self) -> np.ndarray:
        """The current environment turned by the current rotation (made off the event loop)."""
        async with self._lock:
            return await asyncio.to_thread(self.environment, self.env_name, self.default_rotation)

    # ------------------------------------------------------------------ under the lock
    def _session(self, live_source: bool = True) -> Session:
        from ..engine.frame_path import FramePath
        from ..engine.frame_settings import FrameSettings

        env = self.environment(self.env_name)
        # a stream is a live source: its person's maps made beside its frames (no device work); a
        # named session's requests make theirs in the request (each answer is its frame's)
        c = self.config
        settings = FrameSettings(mode=c.mode, focal=c.focal, region=c.region, live_source=live_source)
        return Session(FramePath(self.bundle, env, settings, relighter=self.path.relighter, workers=self._workers), env)

    def set_uploaded(self, name: str, env: np.ndarray) -> None:
        """An uploaded (validated) environment becomes the current one under ``name`` (kept loaded)."""
        self._envs.put(name, env)
        self.env_name = name

    def environment(self, name: str, rotation: tuple[float, float, float] | None = None) -> np.ndarray:
        """The map of ``name`` (built-in, file or upload) turned by ``rotation``, loaded once."""
        return self._envs.get(name, rotation)

    def _relight(self, rgb: np.ndarray, *, env: str | None = None, rotation=None, exposure: float | None = None,
                 strength: float | None = None, mode: str | None = None, spin: float | None = None,
                 session: Session | None = None):
        """The relit frame and its FrameInfo, through ``session``'s path (None: the shared one,
        reset first). Under the lock (the sessions share the relighter)."""
        if session is None:
            session = self.shared
            session.path.reset()
        fp = session.path
        if env is None and rotation is None:
            rotation = self.default_rotation
        env_array = self.environment(env or self.env_name, rotation)
        if env_array is not session.env:  # not copied and hashed again every frame
            fp.set_environment(env_array)
            session.env = env_array
        fp.set_mode(mode or self.config.mode)
        fp.set_strength(1.0 if strength is None else strength)
        fp.set_exposure(self.default_exposure if exposure is None else exposure)
        if (spin or 0.0) != fp.settings.env_spin:  # (set only on a change: a spin counts from when it was set)
            fp.set_env_spin(spin or 0.0)
        return fp.process(rgb, time.perf_counter())

