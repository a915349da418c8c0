"""``POST /v1/webrtc/offer``: a browser's SDP offer in, the answer out (:mod:`relight.service.webrtc`)."""

from __future__ import annotations

import json

from fastapi import APIRouter, Request
from pydantic import BaseModel

from ..errors import ServiceError
from ..webrtc import MAX_SDP

router = APIRouter()


class Offer(BaseModel):
    sdp: str
    type: str = "offer"


class Answer(BaseModel):
    sdp: str
    type: str
    session: str


@router.post("/v1/webrtc/offer", response_model=Answer, summary="Start a WebRTC session: the camera's track in, "
             "the relit track back",
             responses={413: {"description": "offer too large"}, 422: {"description": "not a usable offer"},
                        503: {"description": "loading, or at the client cap (Retry-After)"}},
             openapi_extra={"requestBody": {"required": True, "content": {"application/json": {
                 "schema": Offer.model_json_schema()}}}})
async def offer(request: Request):
    """Body ``{"sdp": ..., "type": "offer"}`` (a video transceiver sendrecv, optionally a data
    channel for controls: the websocket's JSON). Answer ``{"sdp", "type": "answer", "session"}``.
    The relit track keeps each frame's timestamp; after each relit frame the data channel gets
    ``{"frame", "latency_ms", "dropped", "face", "pts"}``."""
    body = b""
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_SDP + 1024:
            raise ServiceError(413, "too_large", f"SDP offers are at most {MAX_SDP} bytes")
    try:
        doc = json.loads(body)
    except ValueError:
        raise ServiceError(422, "bad_offer", 'send JSON {"sdp": "<the offer>", "type": "offer"}') from None
    return await request.app.state.webrtc.answer(doc)
