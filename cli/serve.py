"""``relight serve`` and ``relight-serve``: a bundle kept loaded, relighting frames sent over HTTP."""

from __future__ import annotations

import os
import re
from pathlib import Path

from .common import COMMANDS, ENV_KINDS, REGION_HELP, DefaultsUnlessNone, focal_default, parse_focal


def add_arguments(p) -> None:
    from ..engine.composite import MODES, REGIONS
    from ..service.settings import DEFAULT_PORT, ServeConfig  # the defaults: the service's own settings

    p.add_argument("bundle", type=Path, help="reflectance bundle to serve (relight capture)")
    p.add_argument("--env", default=ServeConfig.env, metavar="FILE|builtin:NAME",
                   help="starting environment: " + ENV_KINDS)
    p.add_argument("--host", default=ServeConfig.host,
                   help="address to listen on (beyond loopback - e.g. 0.0.0.0 - a --token is required)")
    p.add_argument("--token", default=None,
                   help="a secret every request must carry (Authorization: Bearer TOKEN or ?token=TOKEN; the "
                        "page's URL is printed with it); default: $RELIGHT_TOKEN, or none on loopback")
    p.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN",
                   help="a web page origin (https://example.org) allowed to drive this server besides its own "
                        "page; give it again for more")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help="port to listen on")
    p.add_argument("--mode", choices=MODES, default=ServeConfig.mode,
                   help="transfer: the live light measured from the face and swapped for the target; ambient: the "
                        "ratio to the capture room's light; paste: the relit reference face (the paper)")
    p.add_argument("--region", choices=REGIONS, default=ServeConfig.region,
                   help=REGION_HELP)
    p.add_argument("--max-clients", type=int, default=ServeConfig.max_clients, help="most stream clients at once")
    p.add_argument("--focal", type=parse_focal, default=None, metavar="PIXELS|ortho",
                   help=f"the frames' focal length in pixels, or 'ortho' (default: {focal_default()})")


def serve_command(args) -> int:
    import relight

    from ..errors import InputError
    from ..service.app import serve
    from ..service.security import check_token, is_loopback

    if not args.bundle.is_file():
        raise InputError(f"{args.bundle}: no such bundle file")
    # A broken bundle (header, sizes): a one-line error here, not a server traceback. The lifespan
    # loads it again and checks every array's CRC, so that pass is not done twice.
    relight.load_bundle(args.bundle, verify=False)
    if not (1 <= args.port <= 65535):
        raise InputError(f"--port {args.port}: use 1 to 65535")
    if not (1 <= args.max_clients <= 1024):
        raise InputError(f"--max-clients {args.max_clients}: use 1 to 1024")
    try:
        token = check_token(args.token if args.token is not None else os.environ.get("RELIGHT_TOKEN"))
    except ValueError as exc:
        raise InputError(f"--token: {exc}") from None
    if token is None and not is_loopback(args.host):
        raise InputError(f"--host {args.host} opens the service to the network: give --token (or set "
                         "RELIGHT_TOKEN) so only its user can drive it, or listen on 127.0.0.1")
    for o in args.allow_origin:
        if o != "*" and not re.match(r"^https?://[^/\s]+$", o):
            raise InputError(f"--allow-origin {o!r}: write an origin as scheme://host[:port], e.g. https://example.org")
    return serve(args.bundle, env=args.env, host=args.host, port=args.port, mode=args.mode, region=args.region,
                 max_clients=args.max_clients, focal=args.focal, token=token,
                 allowed_origins=tuple(args.allow_origin))


def add_parser(sub) -> None:
    sp = sub.add_parser("serve", help=COMMANDS["serve"],
                        description="Keep a bundle loaded and relight frames sent over HTTP (POST /v1/relight); "
                                    "health at /livez and /readyz, Prometheus metrics at /metrics, OpenAPI at /docs.",
                        formatter_class=DefaultsUnlessNone)
    add_arguments(sp)
    sp.set_defaults(func=serve_command)

