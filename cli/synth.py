"""``relight synth``: the synthetic capture studio (a capture of a known head, or with ``--live``
a live video of it), with its ground truth."""

from __future__ import annotations

from pathlib import Path

from .common import COMMANDS, DefaultsUnlessNone, parse_size


def add_parser(sub) -> None:
    from ..pipeline.synth.config import DEFAULT_TRUTH_ENVS, SynthConfig
    from ..pipeline.synth.live_clip import AUDIO_KINDS, LiveConfig

    d = SynthConfig()
    live = LiveConfig()
    p = sub.add_parser(
        "synth", help=COMMANDS["synth"],
        description="Simulate the paper's acquisition on a procedural head whose truth is known: a phone "
                    "films the face while a second phone's flash blinks and is waved over the front "
                    "hemisphere, a mirror sphere beside the head shows the flash. Writes OUT/capture.mp4 "
                    "(H.264) and OUT/truth/ (meta.json, mask.png, normals/depth/albedo EXR, head.ply, "
                    "relit_<env>.exr per truth environment, olat_<name>.exr one-light images, ambient.exr). "
                    "With --live: OUT/live.mp4 (H.264 + AAC) of the same head (same --seed and --size) turning "
                    "and moving under the room light, and OUT/truth/ (meta.json with the head rotation and "
                    "translation of every frame, reference.png, mask_reference.png; with --truth-env, every frame "
                    "under each environment, truth/live_<stem>/NNNN.png, and truth/silhouette/NNNN.png).",
        formatter_class=DefaultsUnlessNone)
    p.add_argument("out", type=Path, help="output folder (created if missing)")
    p.add_argument("--seed", type=int, default=d.seed,
                   help="random seed: flash timing, hand path, head motion, noise, skin texture")
    p.add_argument("--fps", type=float, default=d.fps, help="camera frame rate (frames per second)")
    p.add_argument("--flash-hz", type=float, default=d.flash_hz,
                   help="flash blink rate (Hz); not synchronised with the camera")
    p.add_argument("--duration", type=float, default=None,
                   help=f"capture length in seconds (default {d.duration:g}; with --live {live.duration:g})")
    p.add_argument("--size", type=parse_size, default=(d.width, d.height), metavar="WxH",
                   help="frame size in pixels (even numbers)")
    p.add_argument("--truth-env", action="append", default=None, metavar="FILE|builtin:NAME",
                   help="environment to render the truth under (repeatable; default: "
                        + ", ".join(DEFAULT_TRUTH_ENVS) + "); with --live none by default, and each "
                        "writes every frame with the person under it (truth/live_<stem>/NNNN.png, 8-bit sRGB) "
                        "and the person's pixels (truth/silhouette/NNNN.png)")
    p.add_argument("--head-motion", "--head", dest="head_motion", type=float, default=d.head_motion,
                   help="head motion, times the paper's limits (3 px at 540 rows, 0.35 deg); 0 = still")
    p.add_argument("--head-mesh", metavar="FILE",
                   help="a textured head mesh (.glb/.gltf/.obj/.ply, +Y up, facing +Z) instead of the procedural "
                        "head; its face is placed and sized as the procedural face")
    p.add_argument("--head-texture", metavar="FILE",
                   help="with --head-mesh: its colour map (used as albedo), when the mesh does not embed one")
    p.add_argument("--head-normal-map", metavar="FILE",
                   help="with --head-mesh: a tangent-space normal map (OpenGL convention: green toward +v)")
    p.add_argument("--head-specular-map", metavar="FILE",
                   help="with --head-mesh: a grey specular map (white: the oiliest skin)")
    p.add_argument("--head-texture-flip", action="store_true",
                   help="with --head-mesh: its images are stored the other way up from its texture coordinates "
                        "(texture coordinates count v up from the bottom row, as OBJ and trimesh do)")
    p.add_argument("--ambient", type=float, default=d.ambient, help="room light strength, times the default")
    p.add_argument("--noise", type=float, default=d.noise, help="sensor noise, times the default; 0 = none")
    p.add_argument("--camera-drift", action="store_true",
                   help="simulate a phone's auto-exposure and white-balance drift")
    p.add_argument("--sparse-sides", action="store_true",
                   help="wave the flash quickly through the sides: sparse samples there (the paper's Fig. 14)")
    p.add_argument("--crf", type=int, default=None,
                   help=f"H.264 quality, lower = better and bigger (default {d.crf}; with --live {live.crf})")
    p.add_argument("--live", action="store_true",
                   help="a video of the head turning and moving under room light, with an audio track, and "
                        "per-frame head rotation truth, instead of a capture (uses --size, --seed, --fps, "
                        "--duration, --noise, --ambient, --crf, --audio, --quiet)")
    p.add_argument("--start-yaw", type=float, default=None, metavar="DEG",
                   help="--live only: the clip starts with the head turned this far about the vertical "
                        "(degrees; + turns the nose toward the image's right) and eases into its motion over "
                        "1.5 s; up to 45 (75 with --head-mesh). The truth's meta.json says so (start_pose)")
    p.add_argument("--start-pitch", type=float, default=None, metavar="DEG",
                   help="--live only: the clip starts with the head tilted this far (degrees; + tilts the nose "
                        "down) and eases into its motion; up to 30 (45 with --head-mesh)")
    p.add_argument("--fov", type=float, default=None, metavar="DEG",
                   help="a pinhole camera (a phone's or a webcam's) of this horizontal field of view, in degrees, "
                        "for the capture or the --live video; the truth's meta.json holds it (camera) and its images "
                        "go through it (default: an orthographic camera, as every clip before)")
    p.add_argument("--distance", type=float, default=live.distance, metavar="CM",
                   help="with --fov: the camera's distance from the head's middle, in cm (a person's head: "
                        "22.5 cm crown to chin)")
    p.add_argument("--audio", choices=AUDIO_KINDS, default=live.audio,
                   help="--live only: the audio track, a 440 Hz tone, white noise, or none (no audio stream)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_run_synth)


def _head_mesh_args(args) -> dict:
    """The --head-mesh flags as SynthConfig / LiveConfig fields."""
    return {"head_mesh": args.head_mesh, "head_texture": args.head_texture, "head_normal_map": args.head_normal_map,
            "head_specular_map": args.head_specular_map, "head_texture_flip": args.head_texture_flip}


def _run_synth(args) -> int:
    from ..errors import InputError
    from ..pipeline.synth.live_clip import LiveConfig

    if args.live:
        return _run_synth_live(args)
    if args.audio != "tone":
        raise InputError("--audio applies to --live videos only; add --live or leave --audio out")
    if args.start_yaw is not None or args.start_pitch is not None:
        raise InputError("--start-yaw and --start-pitch apply to --live videos only; add --live or leave them out")
    if args.fov is None and args.distance != LiveConfig().distance:
        raise InputError("--distance places a pinhole camera: give its field of view with --fov, or leave "
                         "--distance out")
    from ..pipeline.synth.config import DEFAULT_TRUTH_ENVS, SynthConfig
    from ..pipeline.synth.studio import synthesize

    d = SynthConfig()
    cfg = SynthConfig(width=args.size[0], height=args.size[1], fps=args.fps, flash_hz=args.flash_hz,
                      duration=d.duration if args.duration is None else args.duration, seed=args.seed,
                      head_motion=args.head_motion, ambient=args.ambient, noise=args.noise,
                      camera_drift=args.camera_drift, sparse_sides=args.sparse_sides,
                      truth_envs=tuple(args.truth_env or DEFAULT_TRUTH_ENVS),
                      crf=d.crf if args.crf is None else args.crf, fov=args.fov, distance=args.distance,
                      **_head_mesh_args(args))
    res = synthesize(args.out, cfg, progress=not args.quiet)
    print(f"wrote {res.video} ({res.frame_count} frames, {res.flash_frames} flash frames) and {res.truth}/")
    print("timings: " + ", ".join(f"{k} {v:.1f}s" for k, v in res.timings.items()))
    return 0


def _run_synth_live(args) -> int:
    from ..envmap import environment_stem
    from ..errors import InputError
    from ..pipeline.synth.config import SynthConfig
    from ..pipeline.synth.live_clip import LiveConfig, synthesize_live

    d, s = LiveConfig(), SynthConfig()
    capture_only = [flag for flag, used in (("--flash-hz", args.flash_hz != s.flash_hz),
                                            ("--head-motion", args.head_motion != s.head_motion),
                                            ("--camera-drift", args.camera_drift),
                                            ("--sparse-sides", args.sparse_sides)) if used]
    if args.fov is None and args.distance != d.distance:
        raise InputError("--distance places a pinhole camera: give its field of view with --fov, or leave "
                         "--distance out")
    if capture_only:
        raise InputError(f"{', '.join(capture_only)} apply to captures, not --live videos; leave them out "
                         f"(a live video's light is the room's alone)")
    cfg = LiveConfig(width=args.size[0], height=args.size[1], fps=args.fps,
                     duration=d.duration if args.duration is None else args.duration, seed=args.seed,
                     ambient=args.ambient, noise=args.noise, crf=d.crf if args.crf is None else args.crf,
                     audio=args.audio, truth_envs=tuple(args.truth_env or ()), start_yaw=args.start_yaw,
                     start_pitch=args.start_pitch, fov=args.fov, distance=args.distance, **_head_mesh_args(args))
    res = synthesize_live(args.out, cfg, progress=not args.quiet)
    audio = "no audio" if cfg.audio == "none" else f"{cfg.audio} audio"
    print(f"wrote {res.video} ({res.frame_count} frames, {cfg.width}x{cfg.height} at {cfg.fps:g} fps, {audio}), "
          f"{res.meta} (per-frame head rotation and translation), {res.reference} and {res.mask}")
    if cfg.truth_envs:
        stems = ", ".join(f"live_{environment_stem(e)}/" for e in cfg.truth_envs)
        print(f"wrote the live truth: {res.truth}/{{{stems}}} (every frame under each environment) and "
              f"{res.truth}/silhouette/")
    print("timings: " + ", ".join(f"{k} {v:.1f}s" for k, v in res.timings.items()))
    return 0

