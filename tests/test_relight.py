"""The relighting engine: kernels vs NumPy twins, compact vs exact, rotations, HDR extremes, bad input."""

import numpy as np
import pytest

from relight import Relighter, load_environment
from relight.cli import main
from relight.directions import rotation_matrix
from relight.envmap import rotate_environment
from relight.errors import InputError
from relight.imageio import read_image

from .tolerances import (
    COMPACT_TOLERANCE_SLACK,
    F32_CLOSE,
    F32_LOOSE,
    F32_ZERO,
    F64_EXACT,
    F64_TINY,
    F64_ZERO,
    FLASH_UNIT_GAIN_RANGE,
    HALF_REL,
    LINEARITY_REL,
    LOW_RANK_LIGHT_REL,
    POINT_LIGHT_VS_DISC_REL,
    RELIGHT_TWIN_REL,
    RELIGHT_TWIN_ROW_REL,
    ROTATION_EQUIV_REL,
)


def _rel(a, b, mask):
    return float(np.linalg.norm(a[mask] - b[mask]) / max(np.linalg.norm(b[mask]), 1e-30))


@pytest.fixture(scope="module")
def relighters(small_bundle):
    return Relighter(small_bundle), Relighter(small_bundle, exact=True)


@pytest.mark.parametrize("name", ["studio", "sunset", "point:0.3,0.2,0.9"])
def test_kernels_match_numpy_and_compact_meets_its_tolerance(relighters, small_bundle, name):
    """Each kernel against the NumPy twin that relights from the bundle's stored arrays in float64
    (relight.kernels.relight_twin: not the kernel's packed operands); the compact path within its
    tolerance of the exact one."""
    from relight.kernels import relight_twin

    compact, exact = relighters
    env = load_environment(f"builtin:{name}")
    r = rotation_matrix(12, -5, 3)
    # The compact path's exact texels: their rows made for the kernel and for the twin, each
    # rounded to float16 (RELIGHT_TWIN_ROW_REL of that part of a pixel).
    lp = relight_twin.texel_light(small_bundle, env, r)
    direct = np.abs(relight_twin.in_frame(small_bundle, relight_twin.compact_parts(small_bundle, lp, compact.rank)[1]))
    for rl in (compact, exact):
        got = np.array(rl.relight(env, r))
        ref = rl.relight_numpy(env, r)
        allowed = RELIGHT_TWIN_REL * max(np.abs(ref).max(), 1e-9) + (0.0 if rl.exact else RELIGHT_TWIN_ROW_REL * direct)
        assert (np.abs(got - ref) <= allowed).all(), (rl.exact, np.abs(got - ref).max() / np.abs(ref).max())
    m = small_bundle.mask
    c = np.array(compact.relight(env, r))
    e = np.array(exact.relight(env, r))
    assert not compact.exact and compact.rank >= 1
    assert _rel(c, e, m) <= COMPACT_TOLERANCE_SLACK * compact.tolerance
    assert (c[~m] == 0).all() and (e[~m] == 0).all() and np.isfinite(c).all()


def test_tighter_tolerance_means_higher_rank(small_bundle):
    from relight.kernels.transport import STORE_TOLERANCE

    ranks = [Relighter(small_bundle, tolerance=t).rank for t in (0.05, 0.02, STORE_TOLERANCE)]
    assert None not in ranks and ranks[0] <= ranks[1] <= ranks[2]
    # Finer than the bundle was stored for (relight capture --store-tolerance): the exact path.
    assert Relighter(small_bundle, tolerance=STORE_TOLERANCE / 2).exact
    assert Relighter(small_bundle, tolerance=1e-9).exact


def test_quarter_turns_are_exact(relighters):
    _, exact = relighters
    env = load_environment("builtin:studio")
    w = env.shape[1]
    turned = np.array(exact.relight(env, rotation_matrix(yaw=90)))
    # The head turned by +90 degrees sees the environment turned by -90: a roll of the columns.
    rolled = np.array(exact.relight(np.roll(env, w // 4, axis=1)))
    np.testing.assert_allclose(turned, rolled, rtol=F32_CLOSE, atol=F32_ZERO)


def test_turning_the_head_equals_turning_the_environment_back(relighters, small_bundle):
    _, exact = relighters
    env = load_environment("builtin:window")
    r = rotation_matrix(20, 10, -5)
    a = np.array(exact.relight(env, r))
    b = np.array(exact.relight(rotate_environment(env, r.T, supersample=4)))
    assert _rel(a, b, small_bundle.mask) < ROTATION_EQUIV_REL


def test_hdr_extremes_stay_linear_and_finite(relighters, small_bundle):
    compact, exact = relighters
    sky = load_environment("builtin:uniform") * np.float32(0.05)
    sun = load_environment("builtin:point:0.4,0.3,0.85") * np.float32(5e3)  # sun / sky radiance ~ 1e7
    both = np.array(exact.relight(sky + sun))
    parts = np.array(exact.relight(sky)) + np.array(exact.relight(sun))
    m = small_bundle.mask
    assert np.isfinite(both).all() and _rel(both, parts, m) < LINEARITY_REL
    # The compact path takes the sun's texels exactly: still within its tolerance.
    assert _rel(np.array(compact.relight(sky + sun)), both, m) < compact.tolerance * COMPACT_TOLERANCE_SLACK
    base = np.array(exact.relight(sky))
    for ev in (1e-3, 1e3):
        scaled = np.array(exact.relight(sky, exposure=ev))
        assert np.isfinite(scaled).all()
        np.testing.assert_allclose(scaled[m], base[m] * ev, rtol=F32_CLOSE, atol=F64_TINY)


def test_bad_environments_rotations_and_settings(relighters, small_bundle):
    compact, _ = relighters
    env = load_environment("builtin:studio")
    bad = env.copy()
    bad[3, 4, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        compact.relight(bad)
    bad[3, 4, 0] = -1.0
    with pytest.raises(InputError, match="negative"):
        compact.relight(bad)
    with pytest.raises(InputError, match="rotation"):
        compact.relight(env, np.eye(3) * 2)
    with pytest.raises(InputError, match="twice as wide"):
        compact.relight(np.ones((10, 10, 3), np.float32))
    with pytest.raises(InputError, match="exposure"):
        compact.relight(env, exposure=float("inf"))
    with pytest.raises(InputError, match="too large"):  # would overflow float32
        compact.relight(env, exposure=1e36)
    with pytest.raises(InputError, match="tolerance"):
        Relighter(small_bundle, tolerance=0)
    with pytest.raises(InputError, match="light direction"):
        compact.relight_light((0, 0, 0))


def test_nothing_is_recomputed_for_the_same_request(relighters, monkeypatch):
    compact, _ = relighters
    env = load_environment("builtin:sunset")
    r = rotation_matrix(5, 0, 0)
    out = np.zeros_like(compact.frame)
    first = compact.relight(env, r, out=out).copy()
    calls = []
    monkeypatch.setattr(compact, "_run_compact", lambda lp, *a, **kw: calls.append(1))
    again = compact.relight(env, r, out=out)
    assert calls == [] and again is out and np.array_equal(out, first)
    compact.relight(env, r)  # another target (the Relighter's own frame, then a new array): relit there
    assert calls == [1]
    compact.relight(env, rotation_matrix(6, 0, 0), out=out)
    assert calls == [1, 1]


def test_a_relight_not_waited_for_gives_the_same_frame_after_sync(relighters):
    """relight(wait=False) queues the kernel and returns; sync() waits. A launch while one is
    pending (another slot) waits for it first: its coefficients are host memory the pending
    kernel still reads."""
    compact, _ = relighters
    env = load_environment("builtin:sunset")
    want = np.array(compact.relight(env, rotation_matrix(11, 2, 0)))
    want_live = np.array(compact.relight_texels(np.full((compact.texels.size, 3), 1e-3), slot="live"))
    compact.relight(env, rotation_matrix(-3, 0, 0))  # something else in the main frame
    out = np.zeros_like(compact.frame)
    got = compact.relight(env, rotation_matrix(11, 2, 0), out=out, wait=False)
    live = compact.relight_texels(np.full((compact.texels.size, 3), 1e-3), slot="live")
    compact.sync()
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(np.array(live), want_live)
    compact.sync()  # nothing pending: a no-op


def test_a_light_relit_without_exact_texels_makes_no_texel_rows(relighters, small_bundle):
    """relight_texels(direct=0) (the frame path's live light): the low-rank part alone, no
    recipe row made, within the Relighter's tolerance of the exact path; the row cache holds
    as many rows as its byte budget allows."""
    from relight.kernels.row_cache import ROW_SLOTS_RANGE, row_slots

    _, exact = relighters
    compact = Relighter(small_bundle)  # its own row cache: no row of another test's light in it
    assert compact.row_cache is not None  # a format-4 (recipe) bundle
    lp = np.zeros((compact.texels.size, 3))
    lp[np.argsort(compact.texels)[len(lp) // 3]] = 0.2  # one sharp light
    lp += 1e-3
    made = compact.row_cache.made
    got = np.array(compact.relight_texels(lp, slot="t0", direct=0))
    assert compact.row_cache.made == made
    ref = np.array(exact.relight_texels(lp))
    assert np.linalg.norm(got - ref) / np.linalg.norm(ref) < LOW_RANK_LIGHT_REL
    with_rows = np.array(compact.relight_texels(lp, slot="t8"))
    assert compact.row_cache.made > made
    assert np.linalg.norm(with_rows - ref) <= np.linalg.norm(got - ref)
    assert row_slots(10**9) == ROW_SLOTS_RANGE[0] and row_slots(1) == ROW_SLOTS_RANGE[1]
    assert compact.row_cache.rows.shape[0] == row_slots(compact.n_pix)


def test_rows_made_ahead_on_their_own_thread_relight_as_rows_made_when_asked(small_bundle):
    """prefetch_rows (the frame path's, at set_environment): the rows a turning head's relight of a
    sunset asks for are made on a thread and a queue of their own; relights that find them made
    are bit for bit the relights that made them on the spot, and a relight asking for a row the
    thread is making waits for it."""
    env = load_environment("builtin:sunset")
    turns = [rotation_matrix(y, p, 0) for y, p in ((0, 0), (5, 5), (-10, -5), (10, 0))]
    plain = Relighter(small_bundle)
    want = [np.array(plain.relight(env, r)) for r in turns]
    ahead = Relighter(small_bundle)
    ahead.prefetch_rows(env, yaw_deg=10.0, pitch_deg=5.0)  # a small range: the test runs on emulated CPUs too
    first = np.array(ahead.relight(env, turns[0]))  # while the thread runs: waits, or makes, as needed
    ahead.row_cache._prefetch[0].join()
    assert ahead.row_cache.prefetched > 0
    made = ahead.row_cache.made
    got = [first] + [np.array(ahead.relight(env, r)) for r in turns[1:]]
    assert ahead.row_cache.made == made  # every row these turns need was made ahead
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w)
    ahead.prefetch_rows(env, yaw_deg=10.0, pitch_deg=5.0)  # the same environment again: nothing more to make
    ahead.row_cache.stop_prefetch()
    assert ahead.row_cache._prefetch is None


def test_one_light_reads_the_maps_directly(relighters, small_bundle, small_capture):
    compact, exact = relighters
    res, _ = small_capture
    d = np.array([0.8, 0.1, 0.6])
    direct = np.array(compact.relight_light(d))
    point_env = np.array(exact.relight(load_environment("builtin:point:0.8,0.1,0.6", width=2048)))
    m = small_bundle.mask
    assert _rel(direct, point_env, m) < POINT_LIGHT_VS_DISC_REL  # a 1-degree disc vs an ideal direction
    truth = read_image(res.truth / "olat_right.exr")
    both = m & (truth.max(axis=2) > 0)
    gain = float((direct[both] * truth[both]).sum() / (direct[both] ** 2).sum())
    # flash units: a light as strong as the capture flash
    assert FLASH_UNIT_GAIN_RANGE[0] < gain < FLASH_UNIT_GAIN_RANGE[1]


def test_render_cli(small_bundle, tmp_path, capsys):
    path = str(small_bundle.path)
    assert main(["render", path, "--env", "builtin:studio", "-o", str(tmp_path / "a.exr"), "--rotate", "10,0,0"]) == 0
    assert main(["render", path, "--light", "0,0,1", "-o", str(tmp_path / "b.png"), "--exact",
                 "--background", "reference"]) == 0
    a = read_image(tmp_path / "a.exr")
    assert a.shape[:2] == small_bundle.mask.shape and a[small_bundle.mask].max() > 0
    # Negative numbers as users type them (argparse alone took "-0.5,0.2,0.8" for a flag).
    assert main(["render", path, "--light", "-0.5,0.2,0.8", "-o", str(tmp_path / "d.exr"), "--rotate", "-10,-5,0"]) == 0
    assert main(["render", path, "--light", "0.5,0.2,0.8", "-o", str(tmp_path / "e.exr"), "--rotate", "-10,-5,0"]) == 0
    d, e = read_image(tmp_path / "d.exr"), read_image(tmp_path / "e.exr")
    assert np.isfinite(d).all() and not np.array_equal(d, e)  # the light from the other side
    assert main(["render", path, "--env", "builtin:nope", "-o", str(tmp_path / "c.exr")]) == 2
    assert main(["render", path, "--env", "builtin:studio", "-o", str(tmp_path / "c.tif")]) == 2
    assert "write .exr" in capsys.readouterr().err


def test_half_decode_matches_numpy_for_every_finite_half():
    """The kernels' integer-op decode of packed half pairs: every finite float16 bit pattern,
    subnormals read as zero (relight.numerics.HALF_TINY)."""
    import pyopencl as cl

    from relight.kernels.runtime import build_program, get_runtime
    from relight.numerics import read_halves

    bits = np.arange(1 << 16, dtype=np.uint16)
    halves = bits.view(np.float16)
    halves = halves[np.isfinite(halves)]
    halves = np.concatenate([halves, np.zeros((-halves.size) % 32, np.float16)])
    rt = get_runtime()
    prg = build_program("relight", ("-cl-denorms-are-zero",))
    mf = cl.mem_flags
    n = halves.size // 32
    src = cl.Buffer(rt.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=halves)
    lo_b, hi_b = (cl.Buffer(rt.context, mf.WRITE_ONLY, n * 64) for _ in range(2))
    cl.Kernel(prg, "decode_half_pairs")(rt.queue, (n,), None, src, lo_b, hi_b)
    lo, hi = np.empty(n * 16, np.float32), np.empty(n * 16, np.float32)
    cl.enqueue_copy(rt.queue, lo, lo_b)
    cl.enqueue_copy(rt.queue, hi, hi_b)
    want = read_halves(halves)
    np.testing.assert_array_equal(lo, want[0::2])
    np.testing.assert_array_equal(hi, want[1::2])


def test_bundles_store_no_subnormal_halves(small_bundle):
    from relight.kernels.transport import dequantise_basis
    from relight.numerics import HALF_TINY

    arrays = small_bundle.arrays
    assert "maps_rows" not in arrays and arrays["transport_v"].dtype == np.int8  # the default: a recipe
    rows = small_bundle.texel_rows(np.arange(0, small_bundle.map_texels.size, 97))  # made from it
    v = dequantise_basis(arrays["transport_v"], arrays["transport_v_scale"], arrays.get("transport_v4"),
                         arrays.get("transport_v4_scale"))  # as the Relighter reads it
    for name, a in (("texel rows", rows), ("transport_v", v)):
        assert a.dtype == np.float16
        assert not ((a != 0) & (np.abs(a) < HALF_TINY)).any(), name


def test_splat_keeps_power_and_the_hull_cone_skips_only_dark_texels(small_bundle):
    from relight.kernels import texel_lights

    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(4000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    power = rng.random((4000, 3))
    splatted = texel_lights.splat(dirs, power, small_bundle.map_size)
    np.testing.assert_allclose(splatted.sum(axis=0), power.sum(axis=0), rtol=F64_EXACT)
    lights = texel_lights.EnvLights(dirs=dirs, power=power)
    texels = np.asarray(small_bundle.map_texels)
    cone = texel_lights.hull_cone(small_bundle.map_size, texels)
    assert -1.0 < cone[1] < 1.0  # a frontal capture's hull: some lights are skipped
    everything = (np.array([0.0, 0.0, 1.0]), -1.0)
    for angles in [(0, 0, 0), (35, -10, 5), (-60, 20, -15), (170, 0, 0)]:
        r = rotation_matrix(*angles)
        np.testing.assert_allclose(texel_lights.texel_light(lights, r, small_bundle.map_size, texels, cone=cone),
                                   texel_lights.texel_light(lights, r, small_bundle.map_size, texels, cone=everything),
                                   rtol=F64_EXACT, atol=F64_ZERO)


def test_pocl_worker_threads_are_pinned_unless_the_user_chose(monkeypatch):
    import os

    from relight.kernels.runtime import pin_pocl_threads

    monkeypatch.setenv("POCL_AFFINITY", "0")
    assert not pin_pocl_threads() and os.environ["POCL_AFFINITY"] == "0"
    monkeypatch.delenv("POCL_AFFINITY")
    full = os.sched_getaffinity(0) == set(range(os.cpu_count()))
    assert pin_pocl_threads() == full
    assert os.environ.get("POCL_AFFINITY") == ("1" if full else None)


@pytest.mark.parametrize("n_pix", [17, 31, 32 * 5 + 3, 32 * 4])
def test_kernel_basis_is_the_storage_rearranged(n_pix):
    """The compact kernel reads the bundle's basis in its own blocks - the first ranks as bytes,
    the rest as nibbles: every pixel's steps times its step size are the stored basis dequantised
    (odd and even storage blocks, ranks cut or padded), and the padding reads as zero."""
    from relight.kernels import transport
    from relight.kernels.relight_packing import LANES, pack_nibbles, pack_quantised
    from relight.numerics import HALF_TINY

    rng = np.random.default_rng(3)
    rank = 21
    nb = -(-n_pix // 16)
    v = np.zeros((nb * 16, 3, rank), dtype=np.float32)
    v[:n_pix] = rng.normal(0, 1, (n_pix, 3, rank)) * rng.uniform(1e-6, 2.0, (n_pix, 3, 1))
    v[:n_pix, :, 16:] *= 0.05  # the later ranks small, as a basis's are
    blocked = np.zeros((nb * 16, 3, 32), dtype=np.float16)
    blocked[:, :, :rank] = v
    blocked = np.ascontiguousarray(blocked.reshape(nb, 16, 3, 32).transpose(0, 2, 3, 1))
    q, scale, q4, scale4 = transport.quantise_basis(blocked, rank)
    assert q.shape[2] == transport.HEAD_RANKS and q4.shape[2:] == (rank - transport.HEAD_RANKS, 8)
    # the 4-bit steps are within +-V4_LEVELS and round the small ranks to their own step
    steps4 = transport.unpack_nibbles(q4)
    assert np.abs(steps4).max() <= transport.V4_LEVELS
    ref = transport.dequantise_basis(q, scale, q4, scale4).astype(np.float32)  # (nb, 3, Kp, 16)
    ref = ref.transpose(0, 3, 1, 2).reshape(-1, 3, ref.shape[2])[:n_pix]  # (P, 3, Kp)
    step4 = scale4.astype(np.float32)[:n_pix] / transport.V4_LEVELS
    # (the dequantised halves flush values below HALF_TINY to zero, as bundles store none)
    # half a 4-bit step, + 1 % for float16 scales (definitional bound, not a tolerance)
    assert (np.abs(ref[:, :, 16:rank] - v[:n_pix, :, 16:]) <= 0.5 * step4[:, :, None] * 1.01 + HALF_TINY).all()
    for kp in (rank, 16, 32):
        q8, units = pack_quantised(q, scale, kp, n_pix)
        assert q8.shape == (-(-n_pix // LANES), kp, 3, LANES) and q8.dtype == np.int8
        assert q8.ctypes.data % 64 == 0 and units.ctypes.data % 64 == 0
        assert units.dtype == np.float16
        step = units.astype(np.float32)[:, None] / transport.V_LEVELS
        got = (q8.astype(np.float32) * step).transpose(0, 3, 2, 1).reshape(-1, 3, kp)
        k = min(kp, 16)
        # dequantise_basis rounds to halves: the kernel's operands are the exact stored values
        np.testing.assert_allclose(got[:n_pix, :, :k], ref[:, :, :k], rtol=HALF_REL, atol=F32_ZERO)
        assert not got[n_pix:].any() and not got[:, :, k:].any()
    for kp in (rank - 16, 8):
        q4k, units4 = pack_nibbles(q4, scale4, kp, n_pix)
        assert q4k.shape == (-(-n_pix // LANES), kp, 3, LANES // 2) and q4k.dtype == np.uint8
        b = q4k.view(np.int8)
        steps = np.concatenate([(b << 4).astype(np.int8) >> 4, b >> 4], axis=-1).astype(np.float32)
        step = units4.astype(np.float32)[:, None] / transport.V4_LEVELS
        got = (steps * step).transpose(0, 3, 2, 1).reshape(-1, 3, kp)
        k = min(kp, rank - 16)
        np.testing.assert_allclose(got[:n_pix, :, :k], ref[:, :, 16:16 + k], rtol=HALF_REL, atol=F32_ZERO)
        assert not got[n_pix:].any() and not got[:, :, k:].any()


def test_small_head_turns_reuse_the_last_relight(relighters):
    """reuse_deg leaves out a relight the head's small turn does not need - measured from the
    last relight, so drift cannot build up - and never across an environment or exposure change."""
    from relight.kernels.relight_inputs import rotation_angle_deg

    compact, _ = relighters
    assert abs(rotation_angle_deg(rotation_matrix(10, 0, 0), rotation_matrix(10.5, 0, 0)) - 0.5) < 1e-6
    env = load_environment("builtin:studio")
    first = np.array(compact.relight(env, rotation_matrix(10, 0, 0)))
    n, reused = compact.relit, compact.reused
    near = compact.relight(env, rotation_matrix(10.06, 0, 0), reuse_deg=0.1)
    assert compact.relit == n and compact.reused == reused + 1 and np.array_equal(near, first)
    compact.relight(env, rotation_matrix(10.12, 0, 0), reuse_deg=0.1)  # 0.12 deg from the last relight
    assert compact.relit == n + 1
    compact.relight(env, rotation_matrix(10.13, 0, 0))  # no reuse_deg: every new rotation relights
    assert compact.relit == n + 2
    compact.relight(env, rotation_matrix(10.13, 0, 0), exposure=2.0, reuse_deg=5.0)
    assert compact.relit == n + 3
    compact.relight(load_environment("builtin:sunset"), rotation_matrix(10.13, 0, 0), exposure=2.0, reuse_deg=5.0)
    assert compact.relit == n + 4


def test_relight_returns_a_new_array_and_fills_out_in_place(relighters, small_bundle):
    """As NumPy does: a call returns an array the caller owns (the next call does not change
    it); ``out=`` is filled in place, the kernel writing into it directly (the hot path)."""
    compact, _ = relighters
    studio, sunset = load_environment("builtin:studio"), load_environment("builtin:sunset")
    a = compact.relight(studio)
    kept = a.copy()
    b = compact.relight(sunset)
    assert a.flags.writeable and a.flags.owndata and np.array_equal(a, kept) and not np.array_equal(a, b)
    out = np.full(compact.frame.shape, -1.0, dtype=np.float32)
    got = compact.relight(studio, out=out)
    m = small_bundle.mask
    assert got is out and np.array_equal(out[m], a[m]) and (out[~m] == -1.0).all()  # the rest left as it was
    queued = compact.relight(sunset, out=out, wait=False)
    compact.sync()
    assert queued is out and np.array_equal(out[m], b[m])
    with pytest.raises(InputError, match="needs out="):
        compact.relight(studio, wait=False)
    for bad in (np.zeros((4, 4, 3), np.float32), np.zeros(compact.frame.shape, np.float64),
                np.zeros(compact.frame.shape, np.float32)[:, ::-1]):
        with pytest.raises(InputError, match="writeable C-contiguous float32"):
            compact.relight(studio, out=bad)


def test_an_environment_edited_in_place_is_relit_anew(relighters, small_bundle):
    """The lights are cached by the environment's contents, not its identity: doubling the same
    array in place doubles the relit face (a cache on id() returned the stale light)."""
    m = small_bundle.mask
    for rl in relighters:
        env = load_environment("builtin:studio").copy()  # (load_environment's own is read-only)
        first = rl.relight(env)
        env *= 2.0
        second = rl.relight(env)
        assert np.allclose(second[m], 2.0 * first[m], rtol=F32_LOOSE, atol=F32_ZERO)
        # A frozen environment (read-only, owning its data) is recognised without hashing.
        from relight.kernels.relight_inputs import frozen

        env = frozen(env)
        assert not env.flags.writeable
        assert np.array_equal(rl.relight(env)[m], second[m]) and np.array_equal(rl.relight(env)[m], second[m])


def test_transport_of_maps_past_the_half_range_is_finite_and_scales_exactly():
    """Bright maps project to ~sqrt(T) times their brightest texel, past float16's 65504 (Yale B06
    seen as sRGB wrote NaN into its bundle so): the stored basis images take a power of two off
    and the basis u puts it back - the same transport as of the maps 2^14 times dimmer, scaled."""
    from relight.kernels import transport
    from relight.kernels.layout import padded_texels

    rng = np.random.default_rng(5)
    map_size = (64, 32)
    texels = np.sort(rng.choice(map_size[0] * map_size[1] // 2, 300, replace=False)).astype(np.int64)
    p, t = 96, texels.size
    # smooth maps: a few lobes per pixel, peaks ~1 (so ~6 x 2^14 projected: past the half range)
    base = rng.uniform(0.2, 1.0, (p, 3, 1)) * np.cos(np.linspace(0, 3, t))[None, None] ** 2
    maps = np.zeros((p, 3, padded_texels(t)), np.float32)
    maps[:, :, :t] = base + 0.2 * rng.uniform(0, 1, (p, 3, 1)) * np.sin(np.linspace(0, 7, t))[None, None] ** 2
    dim = transport.factorize(maps, map_size, texels)
    bright = transport.factorize(maps * np.float32(2.0 ** 14), map_size, texels)
    assert np.isfinite(bright.q_scale.astype(np.float32)).all() and np.isfinite(bright.u).all()
    assert float(np.abs(transport.dequantise_basis(bright.q, bright.q_scale, bright.q4, bright.q4_scale)).max()) \
        <= transport.V_HALF_PEAK
    np.testing.assert_array_equal(bright.rank_errors, dim.rank_errors)  # the errors are relative
    k = len(dim.rank_errors)

    def made(tr):  # the maps as the stored transport makes them (P, 3, T), float64
        v = np.asarray(tr.basis(), np.float64)  # (nb, 3, Kp, 16) -> (P, 3, k)
        v = v.transpose(0, 3, 1, 2).reshape(-1, 3, v.shape[2])[:p, :, :k]
        return np.einsum("pck,tk->pct", v, np.asarray(tr.u, np.float64))

    np.testing.assert_allclose(made(bright), made(dim) * 2.0 ** 14, rtol=HALF_REL, atol=F32_ZERO * 2.0 ** 14)


def test_the_plain_call_hashes_a_loaded_environment_once(relighters, small_bundle, monkeypatch):
    """The README's loop - relight(load_environment(...), rotation=R) with a new R per call -
    is the hot path but for its new result array: the map load_environment returns is read-only
    and known by identity after its first call (no hashing per call); the result holds exactly
    the face, zero elsewhere, and the next call does not change it."""
    from relight.kernels import relighter as rlm

    compact, _ = relighters
    env = load_environment("builtin:window")
    assert not env.flags.writeable and env.flags.owndata
    with pytest.raises(ValueError, match="read-only"):
        env *= 2.0
    hashed = []
    real = rlm.hashlib.blake2b
    monkeypatch.setattr(rlm.hashlib, "blake2b", lambda *a, **kw: hashed.append(1) or real(*a, **kw))
    out = np.zeros_like(compact.frame)
    got = [compact.relight(env, rotation=rotation_matrix(a, 0, 0)) for a in (3, 4, 5)]
    assert len(hashed) <= 1
    m = small_bundle.mask
    for a, img in zip((3, 4, 5), got, strict=True):
        want = compact.relight(env, rotation=rotation_matrix(a, 0, 0), out=out)
        assert np.array_equal(img[m], want[m]) and not img[~m].any()
    assert len(hashed) <= 1
