"""``/v1/environment``: the current environment - a built-in, a key light, an upload
(.hdr/.exr/.png/.jpg lat-long map) or a photo made into one - its rotation and exposure, and a
tone-mapped preview."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter, Query, Request, Response

from ..codec import (
    ENV_MAX_BODY,
    ENV_TYPES,
    binary_body,
    load_uploaded_environment,
    parse_rotation,
    preview_png,
    read_body,
)
from ..controls import RANGES, environment_source
from ..dependencies import ServiceDep
from ..errors import ServiceError
from ..settings import PRESETS

router = APIRouter()


@router.get("/v1/environment", summary="The current environment and the built-ins")
async def get_environment(engine: ServiceDep):
    return {"current": engine.env_name, "rotation": engine.default_rotation, "exposure": engine.default_exposure,
            "builtins": list(PRESETS)}

@router.put("/v1/environment", summary="Choose a built-in or a key light, or upload an environment or a photo",
         openapi_extra=binary_body(*ENV_TYPES, required=False), responses={400: {}, 413: {}, 415: {}, 422: {}})
async def put_environment(request: Request, engine: ServiceDep,
                          builtin: str | None = Query(None, description="a built-in (" + ", ".join(PRESETS)
                                                      + ") or a key light, key:az=30,el=25,size=30,kelvin=5000,"
                                                        "fill=0.3,power=1 (every field optional)"),
                          rotation: str | None = Query(None, description="yaw,pitch,roll (degrees)"),
                          exposure: float | None = Query(None, ge=RANGES["exposure"][0], le=RANGES["exposure"][1],
                                                         description="stops (EV)"),
                          photo: bool = Query(False, description="the body is a photo (any picture: a place, a "
                                              "virtual background) to be made into an environment, not a 2:1 "
                                              "lat-long map")):
    rot = parse_rotation(rotation)
    ctype = (request.headers.get("content-type") or "").split(";")[0].strip().lower()
    body = await read_body(request, ENV_MAX_BODY)
    if builtin is not None:
        await engine.choose(environment_source(builtin, "builtin=", "bad_query"))
    elif body:
        suffix = ENV_TYPES.get(ctype)
        if suffix is None:
            raise ServiceError(415, "content_type", f"content type {ctype or 'none'!r}: send "
                               + ", ".join(ENV_TYPES) + " (an .hdr, .exr, .png or .jpg lat-long map, or any "
                               "picture with ?photo=true)")
        env = await asyncio.to_thread(load_uploaded_environment, body, suffix, photo)
        await engine.upload(("photo" if photo else "uploaded") + suffix, env)
    if rot is not None:
        engine.default_rotation = rot
    if exposure is not None:
        engine.default_exposure = float(exposure)
    return await get_environment(engine)

@router.get("/v1/environment/light.png", summary="A grey and a skin-toned ball lit by an environment",
            response_class=Response, responses={200: {"content": {"image/png": {}}}, 422: {}})
async def light_balls(engine: ServiceDep,
                      env: str | None = Query(None, description="a preset (" + ", ".join(PRESETS) + ") or a key "
                                              "light key:az=..,el=..; default: the current environment")):
    """What the page shows of a light, and where dragging places the key light (the bright spot's
    direction: relight.light_preview.ball_direction)."""
    import relight
    from relight.light_preview import LOAD_WIDTH, balls_png

    if env is not None:
        source = environment_source(env, "env=", "bad_query")
        arr = await asyncio.to_thread(relight.load_environment, source, width=LOAD_WIDTH)
    else:
        arr = await engine.current_environment()  # turned by the current rotation
    return Response(await asyncio.to_thread(balls_png, arr), media_type="image/png")


@router.get("/v1/environment/preview.png", summary="The current environment, tone-mapped",
         response_class=Response, responses={200: {"content": {"image/png": {}}}})
async def preview_environment(engine: ServiceDep):
    env = await engine.current_environment()
    return Response(await asyncio.to_thread(preview_png, env, engine.default_exposure), media_type="image/png")

