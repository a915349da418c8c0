"""Tolerances of the test suite, named once (loosen only with a reason in the commit message)."""

#: OpenCL synth shading vs its NumPy twin: allowed difference of a shaded value, absolute plus
#: relative (float32 kernel vs float64 twin; a sharp GGX lobe peaks in the thousands), and the
#: share of pixels allowed to differ more (a shadow test that lands exactly on a float32
#: rounding boundary may flip one sample).
SHADE_ABS = 2e-4
SHADE_REL = 1e-4
SHADE_FLIP_FRACTION = 2e-3
#: Horizon slopes, OpenCL vs NumPy (slopes are O(1); float32 rounding of t and bilinear taps).
HORIZON_ABS = 1e-4
#: Sensor kernel vs NumPy twin: 8-bit codes (float rounding at a code boundary may differ by one).
SENSOR_CODE = 1
SENSOR_MISMATCH_FRACTION = 1e-3
#: Re-rendering a captured frame from the truth: mean absolute difference in 8-bit sRGB codes
#: over the head (sensor noise is 2-3 codes RMS in the dark parts, H.264 at crf 16 adds about
#: one), and the mean signed difference, which noise does not move.
FRAME_REPRO_MEAN_CODES = 3.5
FRAME_REPRO_BIAS_CODES = 0.75
#: A wrong light direction must be clearly worse than this.
FRAME_WRONG_LIGHT_MEAN_CODES = 6.0
#: Mirror-sphere highlight centroid vs the mirror law's prediction, pixels (median / max), on
#: a 320x180 capture (sphere radius 18 px: 0.1 px is about 0.6 degrees of light direction).
HIGHLIGHT_MEDIAN_PX = 0.15
HIGHLIGHT_MAX_PX = 0.5
#: Share of no-flash frames in which the Haar cascade must find the face.
HAAR_MIN_HIT_RATE = 0.9
#: A point environment and a one-light image toward the same direction: median relative
#: difference over lit pixels (a 1-degree disc is not a point: its penumbrae are wider).
POINT_VS_OLAT_REL = 0.02
#: sRGB encode/decode round trip (linear units).
SRGB_ROUNDTRIP = 1e-6
#: Reflectance maps, OpenCL vs NumPy: largest difference relative to the largest value (float32
#: kernel with a fast arctangent vs float64 twin).
MAPS_TWIN_REL = 1e-4
#: Capture accuracy goals (issue: capture pipeline), checked on small synthetic captures.
FLASH_PRECISION = 0.98
FLASH_RECALL = 0.85
REGISTRATION_RMS_PX = 0.25
LIGHT_DIR_MEAN_DEG = 1.0
LIGHT_DIR_P95_DEG = 2.5
NORMAL_MEDIAN_DEG = 10.0
#: A capture re-encoded as a phone stores it (a second lossy generation: HEVC 10-bit HLG turned
#: portrait, or H.264 at a variable frame rate): its light directions may miss the plain
#: capture's goals by this much (degrees; the portrait H.264 re-encode measured 0.53-0.54 mean
#: against 0.54 unturned, once 1.67 in a full run).
PHONE_CAPTURE_EXTRA_DEG = 1.0
#: --face-pixels for the downscaled-capture test (the 480x270 synth's head has ~17k pixels).
DOWNSCALED_FACE_PIXELS = 6000
#: The variable-frame-rate test video: share of frames dropped, timestamp jitter (seconds).
VFR_DROP_SHARE = 0.2
VFR_JITTER_S = 0.003
#: Held-out relighting on the real Dome/Test set: PSNR floor (dB, sRGB, inside the mask) and the
#: least margin of `full` over PTM.
DOME_FULL_PSNR = 22.0
DOME_MARGIN_OVER_PTM = 1.0
#: A real face (Extended Yale B, half size, every 6th light held out): `full` over the best of
#: barycentric and PTM (measured +2.6 to +3.1 dB on the three subjects).
FACE_MARGIN_DB = 1.5
#: Relighting kernels vs their NumPy twins: largest difference relative to the largest value.
RELIGHT_TWIN_REL = 1e-5
#: ... plus, on the compact path, this share of a pixel's exact-texel part: a recipe bundle's
#: texel rows are made twice - by recipe.cl for the kernel, by the NumPy recipe for the twin - and
#: each rounded to float16, so an entry may differ by one step (2^-11 .. 2^-10 relative; measured:
#: 1 entry in 7000, adding up to 5.3e-4 of the part).
RELIGHT_TWIN_ROW_REL = 1e-3
#: The compact path against the exact one may exceed the tolerance it was chosen for by this
#: factor on the validation's own environments (float16 storage of the basis images).
COMPACT_TOLERANCE_SLACK = 1.2
#: Relighting is linear in the light: splitting an environment must add up to float precision.
LINEARITY_REL = 1e-5
#: Rotating the head vs rotating the environment map the other way (two resamplings of a
#: smooth environment): relative L2.
ROTATION_EQUIV_REL = 0.03
#: Head pose from exact projections of the landmark model (with outliers): degrees per angle.
POSE_SYNTHETIC_DEG = 0.05
#: The piecewise-affine warp of an affine map: largest error (px) of the interpolated grid.
WARP_AFFINE_PX = 0.02
#: Re-anchoring by pose-warped templates: median landmark error (px) on a reference moved by a
#: known sub-pixel similarity (sub-pixel peak of the correlation).
REFIND_MEDIAN_PX = 0.25
#: warp_composite kernel vs its NumPy twin: largest difference in 8-bit codes (float rounding
#: at a LUT step), and it may touch at most 1 % of the pixels.
COMPOSITE_TWIN_CODES = 1
#: Dark strokes of another colour than the face drawn over a frame (glasses' rims) and composited
#: in mode live: the share of their pixels that stay darker than this share of what the face
#: there is composited as without them (measured 0.88 of them - where the live light leaves the
#: face black, black has no colour to tell a stroke by; without the rule that keeps them,
#: FOREIGN_RAMP, the bundle's prediction replaced them: 0.13).
STROKE_DARKER = 0.8
STROKES_KEPT_SHARE = 0.75
#: Mode live's trusted face over its bound T max(f / E, 1) where the target darkens the live light:
#: the 99th percentile's excess in 8-bit codes (the 8-bit round trip of the frame and the output).
LIVE_RATIO_BOUND_CODES = 1
#: The live light: the estimated dominant direction within this angle of the light that made the
#: frame (degrees), and the frame relit by the estimate within this mean relative error of it.
LIGHT_DIRECTION_DEG = 12.0
LIGHT_REFIT_REL = 0.05
#: ... and of a frame 20 times the capture's exposure (86 % of the face clipped, fitted on the
#: face turned from the light): its intensity against 20 x the unclipped fit's, relative
#: (measured 6 %; the direction is not checked: from the dim side alone it is 22 degrees off).
LIGHT_CLIPPED_REL = 0.15
#: A real face lit from one side (half-size Extended Yale B clip): found in at least this share of
#: the frames, and transfer toward a held-out light at least this much (dB) closer to its photo
#: than the unchanged input (the issue's goal is +6 dB; measured +16 to +18 at full size).
REAL_CLIP_FOUND = 0.95
REAL_CLIP_GAIN_DB = 6.0
#: ... and at most this far below the bundle's still prediction of that light (dB; the issue's goal:
#: within 2 dB on every real face).
REAL_CLIP_STILL_GAP_DB = 2.0

#: The stability suite (tests/test_stability.py), production against float64: the maps, largest
#: difference over the largest value - float16 storage rounds to 2^-11 (4.9e-4) relative and the
#: OpenCL kernel adds at most 1e-4 (float32, a fast arctangent; measured 2.4e-4 .. 4.7e-4).
STABILITY_MAPS_REL = 1e-3
#: ... the exact render path: float32 sums of a few hundred float16 texels times float32 light
#: (measured 1.2e-7 .. 1.9e-7).
STABILITY_RENDER_REL = 1e-5
#: ... a map's largest value over its pixel's brightest sample: the shading model's albedo at most
#: the brightest sample over the least cosine a fit uses (0.2: x5), its lobe's weight at most it
#: over the least lobe it must see (0.1: x10); interpolation stays within the samples (measured
#: at most 2.1; an unseen lobe once reached 8e3).
STABILITY_MAP_GAIN = 15.0

# ------------------------------------------------------------------ numeric precision classes
#: Identities that hold to the arithmetic's precision, by the dtype the code computes in. A test
#: comparing two computations of the same quantity picks the class of the less precise one.
#: float64, exact up to rounding (a few operations) / after a solve or a long sum:
F64_EXACT = 1e-12
F64_CLOSE = 1e-9
F64_SOLVE = 1e-8
#: float64 values expected to be zero (absolute) and the floor under a relative comparison of
#: values that span many decades (an HDR sun at exposure 2^-20):
F64_ZERO = 1e-15
F64_TINY = 1e-30
#: float32: exact up to rounding / after a few dozen operations / after a fit or resampling,
#: and float32 values expected to be zero (absolute):
F32_EXACT = 1e-6
F32_CLOSE = 1e-5
F32_LOOSE = 1e-4
F32_ZERO = 1e-7
#: float16 storage (11 significant bits, 4.9e-4 relative) and one more rounding step:
HALF_REL = 1e-3
HALF_STORE_REL = 2e-3
#: An ambient frame read from 16-bit PNG codes and stored as float16 (absolute, linear).
AMBIENT_16BIT_ABS = 2e-5
#: A sample read from 16-bit codes minus the ambient, stored as float16 (absolute, linear).
SAMPLE_16BIT_ABS = 2e-3

# ------------------------------------------------------------------ domain tolerances
#: Transfer curves (PQ nits, HLG's 1/12 ratio) against their published reference values.
CURVE_REL = 2e-3
#: Video timestamps kept through the filter (seconds).
TIMESTAMP_S = 1e-3
#: Flash detection on a synthetic trace: the rate (Hz) and the count of peaks found.
FLASH_HZ_ABS = 0.05
FLASH_PEAKS_ABS = 2
#: Photometric stereo on a synthetic sphere: the median albedo, relative.
ALBEDO_REL = 0.02
#: An environment's power kept by a rotation (bilinear resampling at 2x supersampling).
ROTATED_POWER_REL = 0.03
#: Order-2 SH irradiance of a point-like light against the clamped cosine (a share of pi: the
#: ringing of the 9-term approximation).
SH_COSINE_ABS = 0.1

# ------------------------------------------------------------------ the per-frame path (test_filter)
#: The One Euro filter: the spread (deg) left of a 0.5-deg jitter at rest, and the lag (deg) behind
#: a 30 deg/s turn after two seconds.
ONE_EURO_REST_STD = 0.2
ONE_EURO_LAG_DEG = 1.5
#: Head pose with a fifth of the landmarks displaced as outliers (RANSAC): degrees off.
POSE_OUTLIER_DEG = 0.5
#: Re-anchoring: share of the landmarks it must find, and the median error (px) the misplaced
#: pose must start from for the test to mean something.
REFIND_FOUND_SHARE = 0.5
REFIND_START_PX = 1.5
#: The batched normalised correlation: a template cut from its window peaks at (nearly) 1.
NCC_SELF_PEAK = 0.999999
#: The coarse inverse warp covers at least this share of the control points' hull.
WARP_HULL_SHARE = 0.8
#: A still head's estimated rotation, degrees per angle (synthetic clip; and a frame of another size).
STILL_HEAD_DEG = 3.0
STILL_HEAD_RESIZED_DEG = 4.0
#: Share of the bundle's face pixels a new light must visibly change (> 3 codes).
RELIT_SHARE = 0.3
#: The two-stage pipeline against the serial path: mean absolute difference (8-bit codes) per frame.
PIPELINE_VS_SERIAL_CODES = 2.0
#: The whole person relit against the face alone: pixels changed, at least this many times as many
#: (the neck and hair of the synthetic head).
WHOLE_PERSON_SHARE = 1.2
#: The person's wide blurs on halved grids against a direct Gaussian: largest difference, as a
#: share of the blurred peak (measured 0.4 % at sigma 8, 10 % at sigma 54 on a 60 px box - the
#: maps it smooths are a face's size and larger).
SMOOTH_BLUR_SHARE = 0.12
#: ... and off the person, the change (8-bit codes, largest channel): issue 32's goals, the 99.9th
#: percentile and the mean (a stray pixel of the matte reaches 9 here, one in 10 000).
OFF_PERSON_CODES = 8
OFF_PERSON_MEAN_CODES = 0.5
#: Live trust in the layer: at least this share of the face distrusted (< 0.05) and trusted (> 0.95).
TRUST_LOW_SHARE = 0.02
TRUST_HIGH_SHARE = 0.2

# ------------------------------------------------------------------ the synthetic live clips (test_synth_live)
#: The audio track: its duration (s) against the video's, the tone's frequency (Hz), the RMS and
#: peak bounds of a 440 Hz tone at -20 dBFS peak (RMS 0.0707), and of white noise at RMS 0.05.
AUDIO_DURATION_S = 0.025
TONE_HZ_ABS = 2.0
TONE_RMS_RANGE = (0.05, 0.09)
TONE_PEAK_MAX = 0.2
NOISE_RMS_RANGE = (0.04, 0.06)
#: Pose tracks: each channel spans at least this share of its +-amplitude range, and moves by at
#: most this share of the amplitude between frames.
POSE_RANGE_SHARE = 1.6
POSE_STEP_SHARE = 0.15
#: Silhouettes (IoU) of the live head against the studio's, straight on; a mirrored pose must be
#: clearly worse.
SILHOUETTE_IOU = 0.97
SILHOUETTE_RIGHT_IOU = 0.95
SILHOUETTE_MIRRORED_IOU = 0.85
#: The live clip's reference frame against the static studio's: median relative difference of the
#: head's colour, mean absolute difference on the wall (linear), and the coverage's mean error.
REFERENCE_HEAD_REL = 0.05
REFERENCE_WALL_ABS = 0.003
COVERAGE_MEAN_ABS = 0.005
#: The head's radiance straight on against the studio's: mean and 95th-percentile relative error.
RADIANCE_MEAN_REL = 0.05
RADIANCE_P95_REL = 0.2
#: A landmark's rendered position against its predicted one (px).
LANDMARK_PX = 1.5
#: Shading follows the light: the brighter side at least this many times the other.
SHADING_TOP_RATIO = 1.1
SHADING_BOTTOM_RATIO = 1.2
SHADING_SIDE_RATIO = 1.05
#: A head turned 25 deg toward one side light against 25 deg away from it (live truth): the face
#: turned to the light reflects at least this much more (measured 2.2 on the procedural head).
TURNED_LIGHT_RATIO = 1.5
#: The chin's bottom row of a turned head against the straight one's width (share range).
CHIN_ROW_RANGE = (0.8, 1.3)
#: A decoded frame against its own pose's render (8-bit codes, mean over the head), and how much
#: worse another pose's must be.
FRAME_RENDER_CODES = 2.5
FRAME_OTHER_POSE_RATIO = 2.0

# ------------------------------------------------------------------ capture and relighting (test_capture, test_relight)
#: The captured head mask against the truth's (IoU).
CAPTURE_MASK_IOU = 0.85
#: A --face-pixels capture keeps about that many face pixels (relative).
FACE_PIXELS_REL = 0.5
#: The background's sRGB encoding: mean bias (8-bit codes) of the JPEG-stored frame, and the
#: bias a plain 1/2.2 power would show on the same values.
SRGB_BIAS_CODES = 0.3
POWER_BIAS_CODES = 1.0
#: Normals of a capture given the truth's own mesh (--mesh): median angle to the truth (deg).
MESH_NORMAL_DEG = 3.0
#: The low-rank part alone against the exact maps for a light (relative L2), and a one-light
#: relight against the point environment it approximates (a 1-degree disc: relative L2).
LOW_RANK_LIGHT_REL = 0.05
POINT_LIGHT_VS_DISC_REL = 0.05
#: A one-light relight in flash units against the truth's one-light image: the least-squares gain.
FLASH_UNIT_GAIN_RANGE = (0.8, 1.3)

# ------------------------------------------------------------------ stages and I/O (the other test files)
#: Flash detection on synthetic traces: precision and recall (clean trace; noisy, irregular one),
#: and the largest normalised level a frame called dark may have.
TRACE_PRECISION = 0.98
TRACE_RECALL = 0.95
TRACE_RECALL_NOISY = 0.9
TRACE_DARK_MAX = 0.06
#: Photometric stereo on a synthetic dome: normals' median and 99th-percentile error (deg); the
#: integrated depth's largest error (px, a 34-pixel dome); a rasterised mesh's normals (deg,
#: median); the head mask's agreement with the truth (share of pixels).
PS_NORMAL_MEDIAN_DEG = 0.5
PS_NORMAL_P99_DEG = 3.0
INTEGRATION_PX = 0.5
RASTER_NORMAL_DEG = 3.0
HEAD_MASK_AGREE = 0.98
#: Registration: a recovered rigid motion's largest displacement error over the frame (px), and a
#: frame warped there and back (mean absolute difference, linear x 255 codes).
RIGID_FIT_PX = 0.1
WARP_ROUND_TRIP = 0.5
#: The mirror sphere: its fitted centre and radius (px), a light direction from its highlight
#: (deg), and an orthographic against a perspective reading of a centred sphere (deg).
SPHERE_FIT_PX = 0.05
SPHERE_LIGHT_DEG = 0.3
SPHERE_PROJECTION_DEG = 0.01
#: Environment maps: turned and turned back (mean relative difference), and a texel's position
#: from its direction (texels).
ROTATE_ROUND_TRIP_REL = 0.05
TEXEL_POSITION = 1.5
#: The live light's fit on its own model's frame (relative residual).
LIGHT_FIT_RESIDUAL = 0.05
#: The face detector on a side-lit face: its least score, how far the similarity of its face to the
#: reference's puts the face's points (px per 100 px of the face's diagonal: a first guess, within
#: the reach of LK's pyramid), the least share of the face's variance the bundle's illumination
#: subspace explains there, and the landmarks' median error once LK has followed them (px).
FACE_DETECT_SCORE = 0.7
FACE_DETECT_PX = 8.0
FACE_SUBSPACE_SHARE = 0.8
FACE_TRACK_PX = 1.5
#: A detected face's box centre from the centre of the head's pixels (x; a share of their box's
#: diagonal: the neck and shoulders widen the head's pixels below the face).
FACE_DETECT_CENTRE = 0.15
#: Video written and read back: mean signed and mean absolute difference (8-bit codes: colour
#: conversion only); a phone's display-rotated video shown upright (mean codes over the inside).
VIDEO_BIAS_CODES = 0.1
VIDEO_MEAN_CODES = 0.6
#: relight.video_yuv's own planes <-> RGB conversions against swscale's exact settings on a real
#: photo with saturated edges (scikit-image's astronaut): mean absolute difference (their chroma
#: filters differ: bilinear against bicubic), and a round trip's mean absolute error (4:2:0's loss
#: at colour edges; swscale's own: 1.2 codes there).
YUV_FAST_MEAN_CODES = 0.6
#: The person's maps made beside the frames (live_source) against made in them: mean change of
#: the changed pixels between the two paths' frames (8-bit codes; the maps a frame or two older on a
#: head that turns ~1 deg a frame).
PERSON_ASYNC_MEAN_CODES = 2.0
YUV_FAST_ROUNDTRIP_CODES = 1.5
DISPLAY_MATRIX_CODES = 3.0
#: The fast sRGB encoder against the exact curve: share of codes that may differ (by one).
FAST_SRGB_MISMATCH = 0.01
#: The sensor's noise field: mean, unit deviation and lag-1 correlation within this.
NOISE_STATS_ABS = 0.01

# ------------------------------------------------------------------ effect sizes (an option must matter this much)
#: Largest change of a map value (flash units) when visibility is switched off, and when the
#: shading model's trend or the paper's adaptation is switched.
VISIBILITY_EFFECT = 0.05
TREND_EFFECT = 0.1
#: --sparse-sides scenes: the sides still reached (share of the azimuth range), and their share of
#: the samples at most this share of the dense scene's.
SPARSE_SIDES_REACH = 0.9
SPARSE_SIDES_SHARE = 0.5
#: One-light error of every variant below this (relative RMSE), and extrapolation must cut the
#: whole-sphere error of `full` at least to this share.
OLAT_REL_RMSE_MAX = 1.5
EXTRAPOLATION_GAIN = 0.9
#: The nose's shadow: share of the cheek beside it in shadow, and of the lit cheek.
NOSE_SHADOW_SHARE = 0.3
LIT_CHEEK_SHADOW_SHARE = 0.05
#: Camera drift: the exposure gain's range over a clip, the red white-balance's spread, and the
#: correlation of the wall's brightness with the recorded gains.
DRIFT_GAIN_RANGE = (0.05, 0.6)
DRIFT_WB_STD = 0.002
DRIFT_WALL_CORR = 0.8
#: The spline halves the interpolation error of a smooth field at least.
SPLINE_GAIN = 0.5
#: Changes the compositor makes outside the warped face (share of all changed pixels).
OUTSIDE_FACE_SHARE = 0.03

# relight live (tests/test_live.py)
#: A file played as the camera arrives at its own rate: never faster than this share above it
#: (startup, scheduling), and never below LIVE_FRAME_SHARE of it (a reader the busy cores slow -
#: in a fresh clone's `make test` the other worker's captures took it to 26.9 of 30 fps).
LIVE_RATE_SHARE = 0.1
#: Shares of frames that must come through: with a face of those relit, recorded of the run's
#: length (less its start). (How many of those read are relit is the cores' business - latest
#: wins: in `make test` another worker shares them; 74 % and 44 % were seen on two machines,
#: ~97 % alone - `relight bench live` measures it.)
LIVE_FRAME_SHARE = 0.5
#: Frames read but neither relit nor dropped when the run stops: the one waiting in the slot and
#: the ones the two relight stages hold.
LIVE_IN_FLIGHT = 3
#: A relit frame differs from the camera's by more than this many codes on at least this share of
#: its pixels (the face's light changed).
LIVE_CHANGED_CODES = 20
LIVE_CHANGED_SHARE = 0.005

# The live path's extreme cases (tests/test_live_stability.py)
#: The live light fit is linear in the frame's exposure (robust weights and ridge are scale-free):
#: intensity at exposure s against s x the unscaled fit, relative.
LIVE_LIGHT_SCALE_RTOL = 1e-6
#: ... and when some pixels fall under the noise floor or clip (fitted on the rest), relative.
LIVE_LIGHT_PARTIAL_RTOL = 0.05
#: ... its direction then within this angle of the unscaled fit's (degrees; exact scaling: 0.1).
LIVE_LIGHT_PARTIAL_DEG = 2.0
#: A frame kept in its Y'CbCr planes (relight.video_yuv) against the RGB path: the tracker's grey
#: (made from scaled planes: rounding and one clip apart, 8-bit codes).
YUV_GREY_CODES = 2
#: A work-scale copy made from the planes scaled first (the person's maps) against the RGB frame
#: scaled: the mean absolute difference (8-bit codes; chroma filtered at a coarser grid, then
#: converted).
YUV_SMALL_MEAN_CODES = 1.0
#: The relit frame through the planes against the same frame relit through RGB: mean absolute
#: difference over the pixels either changed (8-bit codes) - the face alone and with the whole
#: person (measured up to 1.6 and 2.0 on a frame; per channel 1.0-1.6, unbiased: mean signed
#: differences under 0.25; the person's maps are made from either path's own small copy, and the
#: matte's edge moves with a code's difference). The planes' light field maps each pixel's own
#: luma but one chroma change per 2x2 block (4:2:0 can hold no more), and is made from a copy
#: converted with OpenCV's bilinear chroma where the RGB path's frame is swscale's bicubic; a
#: wrong conversion differs by tens of codes.
YUV_RELIT_MEAN_CODES = 2.0
YUV_RELIT_PERSON_MEAN_CODES = 2.5
#: The live frame's edge cases (tests/test_live_edge_cases.py): a pixel counts as changed beyond
#: this many 8-bit codes; the person may change within this margin of the reference's head mask
#: (px, 320x180: the live clip turns the head by up to 10 degrees in place, which moves its
#: outline ~10 px, and the composite's feather reaches ~3 px past it; measured 10.8 px at most on
#: the clip, 12.5 played six times as fast); the share of frames with the face that must be found.
EDGE_CHANGED_CODES = 2
EDGE_HEAD_MARGIN_PX = 15
#: A still head's output over its last frames: the largest change (8-bit codes). The live light's
#: fit still moves the face's composite by a code; where the person's gain darkens the face's
#: feathered edge, the sRGB curve is steeper and that code becomes two.
EDGE_STILL_CODES = 2
EDGE_MIN_FOUND = 0.9
#: ... and with dark rims over the eyes the reference does not have (glasses): measured 0.87.
EDGE_MIN_FOUND_OCCLUDED = 0.8
#: A room's shadow over a cheek (tests/test_live_edge_cases.py): the face's codes
#: scaled by this (about a quarter of the light), and the share of that drop the relit output may keep
#: there (the bundle's prediction replaces what the live light does not predict; measured 22 %).
SHADOW_CODES_GAIN = 0.55
SHADOW_KEPT_SHARE = 0.25
#: ... after this many frames (the live light's first fits settling on the shadowed frames).
SHADOW_SETTLE_FRAMES = 10

# The key light (test_key_light.py).
#: Chromaticity (r, g over r+g+b) of a colour temperature against colour-science's: Kang 2002's
#: cubic fits and the CIE daylight formulas are the same equations there, so only the blend
#: between the loci (4000-5000 K) and float rounding differ.
KELVIN_XY_TOL = 4e-3
#: A white surface facing a key reads its power: the disc's own cosine falloff (a 3-degree radius:
#: 0.1 %) and the texels at its anti-aliased edge (~1 %).
KEY_POWER_REL = 0.02

# The environment's turn (test_env_turn.py).
#: A frame path given env_turn=90 against one given the map turned by 90 (an exact column shift):
#: the texel light is splatted from rotated directions instead of shifted texels, and the person's
#: low frequencies from rotated 64x32 texels - codes at the 99.9th percentile of the frame.
ENV_TURN_FRAME_CODES = 3

# relight live's page (test_live_page.py).
#: A key dragged from the image's left to its right: the change of the relit/camera log luminance
#: ratio's right-minus-left over the relit region (measured 1.08-1.16 on the small synthetic head,
#: and the photo bright on its left 1.4 below the key from the right).
PAGE_KEY_SIDE_LOG = 0.4
#: A moved light's draft relight (the low-rank part alone) against the full one (8 exact texels),
#: relative L2 over the face: a 10-degree key on the small synthetic head (measured 1.3 %).
DRAFT_REL = 0.05

# The light field (issue 48, tests/test_field.py): its kernels and their NumPy twins, the same
# float32 arithmetic (codes: rounding at a .5 boundary may differ by one); person_gain's gains and
# offsets against the twin's, relative to their largest (the 99.9th percentile of a cell: a bilinear
# read of the layer at a texel's edge may differ in its last bits); the planes scaled or read and
# converted against the same from the frame's RGB (codes, mean: the chroma's siting and rounding).
FIELD_TWIN_CODES = 1
FIELD_TWIN_REL = 1e-4
#: ... field_cells' code maps against code_grid's (relative to their largest: float32 sums in
#: another order, and the twin fed the twin's gains).
FIELD_CODES_REL = 1e-3
FIELD_SAMPLE_CODES = 1.5
#: A camera's frame kept in its planes (NV12, YUYV, MJPEG's full-range 4:2:2) converted to RGB
#: against swscale's conversion of the decoded frame: mean absolute difference (8-bit codes; the
#: same conversion, its chroma filter aside).
CAMERA_FORMAT_CODES = 1.0
#: The focal length found (engine.focal) from a known rigid model seen through a pinhole: within
#: this share of the true one (the candidates are 1.25x apart, the parabola refines between them).
FOCAL_FOUND_REL = 0.12
#: The same from exact points of the head's own shape (no noise: the parabola's error alone;
#: measured 1.013 of the truth, and 0.94 with the shape lifted through a long pinhole).
FOCAL_EXACT_REL = 0.025
#: A beard the capture did not have, relit: its luminance below this share of the cheeks' above it
#: (the input's is ~0.45; a beard taken for a shadow and filled with the bundle's skin would be ~1).
BEARD_DARKER_SHARE = 0.85
#: A turned head's pose on the frame it is found (issue 49, test_first_frame), deg: measured 0.1-8.1
#: on the scanned head at |yaw| <= 45 and |pitch| <= 15 at three sizes (relight bench video's
#: first_frame), 0.2-3.1 on the test's own 640x360 capture; the following frames' re-anchorings
#: bring it to the tracked pose's ~2.
FIRST_FRAME_POSE_DEG = 10.0
#: A pose solved from a few exactly projected points (0.05 px of noise), deg.
FEW_POINTS_POSE_DEG = 1.0
#: A flash's direction from a ball seen through a pinhole, its cone fitted (refine_cone), deg:
#: measured 0.03-0.21 at 640x360 through 50-80 degree lenses.
SPHERE_PINHOLE_DEG = 0.5
#: ``--focal auto``: the focal length found from a ball's outline (find_focal), relative to the
#: true one (measured 0.977-1.024 at 640x360-1920x1080 through 40-80 degree lenses), and the
#: flashes' directions read with it, deg (measured at most 0.56).
SPHERE_FOCAL_REL = 0.05
#: A ball's outline: its edge points' median distance (px) from their circle or cone (measured
#: 0.08-0.10 on the studio's balls, with and without noise).
OUTLINE_MISFIT_PX = 0.2
SPHERE_AUTO_DEG = 1.0
#: The small test capture's (320x180, its ball 18 px across) light directions against the truth,
#: mean deg: the orthographic capture measures 1.05 there (LIGHT_DIR_MEAN_DEG is the 480x270 one's goal).
SMALL_CAPTURE_LIGHT_DIR_MEAN_DEG = 1.2
#: Head pose from noisy points (2.5 px Gaussian on every landmark of the bump head, 640x360: the
#: RANSAC threshold's consensus is a fifth of them): the fit over every point must bring the
#: worst of eight heads within this many degrees and the mean under this share of the consensus
#: pose's (measured 0.46-1.75 deg against 1.01-4.60, mean 1.02 against 2.72).
POSE_NOISY_DEG = 2.5
POSE_NOISY_GAIN = 0.6
#: The rig's model normals (from the lifted depth's neighbours) against the bundle's own
#: photometric normals at the landmarks: median degrees (the studio's 640x360 bundles: 3.8-4.1).
MODEL_NORMAL_MEDIAN_DEG = 10.0
