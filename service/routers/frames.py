"""``POST /v1/relight``: one encoded frame in, the relit frame out."""

from __future__ import annotations

import json
import time

from fastapi import APIRouter, Query, Request, Response

from relight.errors import RelightError

from ...engine.composite import MODES
from ..codec import CONTENT_TYPES, binary_body, decode_frame, encode_frame, parse_rotation, read_body
from ..controls import RANGES, environment_source
from ..dependencies import MetricsDep, ServiceDep, SettingsDep
from ..errors import ServiceError
from ..settings import PRESETS
from ..state import SESSION_HEADER, SESSION_ID

router = APIRouter()


@router.post("/v1/relight", summary="Relight one frame", openapi_extra=binary_body("image/png", "image/jpeg"),
          responses={200: {"content": {"image/png": {}, "image/jpeg": {}}}, 400: {}, 413: {}, 415: {}, 422: {}})
async def relight_frame(request: Request, engine: ServiceDep, metrics: MetricsDep, config: SettingsDep,
                        env: str | None = Query(None, description="a built-in preset (" + ", ".join(PRESETS)
                                                + ") or a key light, key:az=30,el=25,size=30,kelvin=5000,fill=0.3,"
                                                  "power=1 (every field optional)"),
                        rotation: str | None = Query(None, description="environment yaw,pitch,roll (degrees)"),
                        exposure: float | None = Query(None, ge=RANGES["exposure"][0], le=RANGES["exposure"][1],
                                                       description="stops (EV)"),
                        strength: float | None = Query(None, ge=RANGES["strength"][0], le=RANGES["strength"][1],
                                                       description="blend, 0 to 1"),
                        mode: str | None = Query(None, pattern=f"^({'|'.join(MODES)})$",
                                                 description="transfer (the live light measured and swapped), "
                                                             "ambient (ratio to the capture room), paste"),
                        session: str | None = Query(None, description="a name (letters, digits, '-', '_', '.': "
                                                    "up to 64) that keeps this client's track, filters and light "
                                                    f"between its requests; or the {SESSION_HEADER} header. "
                                                    "Without one each request is relit on its own.")):
    source = environment_source(env, "env=", "bad_query") if env is not None else None
    rot = parse_rotation(rotation)
    name = session if session is not None else request.headers.get(SESSION_HEADER)
    if name is not None and not SESSION_ID.match(name):
        raise ServiceError(422, "bad_session", f"session {name[:80]!r}: use 1 to 64 letters, digits, '-', '_' or '.'")
    ctype = (request.headers.get("content-type") or "").split(";")[0].strip().lower()
    if ctype not in CONTENT_TYPES:
        raise ServiceError(415, "content_type", f"content type {ctype or 'none'!r}: send image/png or image/jpeg")
    state = request.app.state
    if state.pending >= config.max_pending:  # a bounded wait, never an unbounded queue
        metrics.errors.labels(kind="busy").inc()
        raise ServiceError(503, "busy", f"{state.pending} frames are being relit or wait; retry shortly")
    state.pending += 1
    try:
        return await _relight(request, engine, metrics, config, ctype, source, rot, exposure, strength, mode, name)
    finally:
        state.pending -= 1


async def _relight(request, engine, metrics, config, ctype, env, rot, exposure, strength, mode, name):
    import asyncio

    body = await read_body(request, config.max_body)
    # (a JPEG relit and encoded in its own planes: codec.decode_frame)
    rgb = await asyncio.to_thread(lambda: decode_frame(body, ctype, config.max_pixels, planes=True))
    accept = (request.headers.get("accept") or "").lower()
    out_type = "image/jpeg" if "image/jpeg" in accept and "image/png" not in accept else \
        "image/png" if "image/png" in accept and "image/jpeg" not in accept else ctype
    t0 = time.perf_counter()
    try:
        session = await engine.named_session(name) if name is not None else None
        out, info = await engine.relight_frame(rgb, env=env, rotation=rot, exposure=exposure, strength=strength,
                                               mode=mode, session=session)
    except RelightError as exc:
        raise ServiceError(400, "bad_request", str(exc)) from None
    metrics.latency.observe(time.perf_counter() - t0)
    metrics.frames.inc()
    timing = ", ".join(f"{k};dur={v:.2f}" for k, v in info.timings.items())
    headers = {"Server-Timing": timing, "X-Relight-Face": "found" if info.face else "none"}
    if not info.face and info.note:
        headers["X-Relight-Note"] = info.note
    if info.light is not None:
        headers["X-Relight-Light"] = json.dumps(info.light.as_json(), separators=(",", ":"))
    if session is not None:  # the frames this session has seen (this one counted)
        headers[SESSION_HEADER] = name
        headers[SESSION_HEADER + "-Frames"] = str(session.path.schedule.frame)
    return Response(await asyncio.to_thread(encode_frame, out, out_type), media_type=out_type, headers=headers)

