"""Stage 6: the bundle file - round trip, memory mapping, hostile and broken files."""

import json
import struct

import numpy as np
import pytest

from relight import load_bundle
from relight.errors import InputError
from relight.pipeline.bundle_write import VERSION, write_bundle


def _arrays(p=50, t=20, k=6):
    rng = np.random.default_rng(0)
    h, w = 10, 12
    mask = np.zeros((h, w), dtype=bool)
    mask.flat[:p] = True
    return {
        "pixels": np.flatnonzero(mask).astype(np.int32), "mask_crop": mask,
        "ambient": rng.uniform(0, 1, (h, w, 3)).astype(np.float32),
        "background": rng.integers(0, 255, (30, 40, 3), dtype=np.uint8),
        "normal": rng.normal(size=(p, 3)).astype(np.float32), "albedo": rng.uniform(0, 1, (p, 3)).astype(np.float32),
        "depth": rng.uniform(0, 5, (h, w)).astype(np.float32), "light_dirs": rng.normal(size=(k, 3)).astype(np.float32),
        "maps": rng.uniform(0, 2, (p, 3, 32)).astype(np.float16), "map_texels": np.arange(t, dtype=np.int32) * 7,
        "maps_rows": rng.uniform(0, 2, (t, 3, p)).astype(np.float16),
        "samples": rng.uniform(0, 1, (k, p, 3)).astype(np.float16),
    }


META = {"frame_size": [40, 30], "crop_origin": [5, 6], "map_size": [64, 32], "note": "ünïcode ok"}


def test_round_trip_and_memory_mapping(tmp_path):
    arrays = _arrays()
    path = write_bundle(tmp_path / "f.bundle", META, arrays)
    b = load_bundle(path)
    assert b.meta == META
    for name, a in arrays.items():
        np.testing.assert_array_equal(np.asarray(getattr(b, name)), a)
        assert getattr(b, name).dtype == a.dtype
    assert isinstance(b.maps, np.memmap) and not b.maps.flags.writeable
    assert b.mask.shape == (30, 40) and b.mask.sum() == 50 and b.mask[6, 5]
    assert b.full_map(3).shape == (32, 64, 3)
    assert b.solid_angle.shape == (20,) and (b.solid_angle > 0).all()


def test_truncated_file_names_the_field(tmp_path):
    path = write_bundle(tmp_path / "f.bundle", META, _arrays())
    data = path.read_bytes()
    (tmp_path / "cut.bundle").write_bytes(data[:-100])
    with pytest.raises(InputError, match="'samples'.*truncated|truncated"):
        load_bundle(tmp_path / "cut.bundle")
    (tmp_path / "tiny.bundle").write_bytes(data[:10])
    with pytest.raises(InputError, match="truncated"):
        load_bundle(tmp_path / "tiny.bundle")


def test_corruption_is_caught_by_the_checksum(tmp_path):
    path = write_bundle(tmp_path / "f.bundle", META, _arrays())
    header_len = struct.unpack_from("<Q", path.read_bytes(), 16)[0]
    doc = json.loads(path.read_bytes()[24:24 + header_len])
    off = doc["arrays"]["maps"]["offset"] + 10
    data = bytearray(path.read_bytes())
    data[off] ^= 0xFF
    (tmp_path / "bad.bundle").write_bytes(bytes(data))
    with pytest.raises(InputError, match="'maps'.*checksum"):
        load_bundle(tmp_path / "bad.bundle")
    data = bytearray(path.read_bytes())
    data[30] ^= 0x01  # inside the header
    (tmp_path / "badh.bundle").write_bytes(bytes(data))
    with pytest.raises(InputError, match="header"):
        load_bundle(tmp_path / "badh.bundle")


def test_foreign_and_wrong_version_files(tmp_path):
    path = write_bundle(tmp_path / "f.bundle", META, _arrays())
    data = bytearray(path.read_bytes())
    struct.pack_into("<I", data, 8, VERSION + 1)
    (tmp_path / "v.bundle").write_bytes(bytes(data))
    with pytest.raises(InputError, match=f"version {VERSION + 1}.*reads versions 1, 2"):
        load_bundle(tmp_path / "v.bundle")
    struct.pack_into("<I", data, 8, 1)  # the first format: a superset of the fields, still read
    (tmp_path / "v1.bundle").write_bytes(bytes(data))
    assert load_bundle(tmp_path / "v1.bundle").n_pixels == 50
    (tmp_path / "x.bundle").write_bytes(b"PK\x03\x04" + b"\0" * 100)
    with pytest.raises(InputError, match="not a relight bundle"):
        load_bundle(tmp_path / "x.bundle")
    with pytest.raises(InputError, match="no such"):
        load_bundle(tmp_path / "missing.bundle")


def test_pixel_major_maps_come_from_the_rows_when_not_stored(tmp_path):
    """A default bundle holds the maps once (texel-major); the pixel-major maps a --keep-maps
    bundle stores are the same values, gathered on demand."""
    arrays = _arrays()
    t = arrays["map_texels"].size
    arrays["maps"][:] = 0
    arrays["maps"][:, :, :t] = arrays["maps_rows"].transpose(2, 1, 0)
    kept = load_bundle(write_bundle(tmp_path / "k.bundle", META, arrays))
    lean = load_bundle(write_bundle(tmp_path / "l.bundle", META,
                                    {k: v for k, v in arrays.items() if k not in ("maps", "samples")}))
    assert "maps" not in lean.arrays
    np.testing.assert_array_equal(lean.pixel_maps(), kept.pixel_maps())
    idx = np.array([3, 4, 5, 17, 40])
    np.testing.assert_array_equal(lean.pixel_maps(idx), kept.pixel_maps(idx))
    np.testing.assert_array_equal(lean.pixel_maps(slice(10, 30), padded=False), arrays["maps"][10:30, :, :t])
    np.testing.assert_array_equal(lean.full_map(7), kept.full_map(7))
    assert (tmp_path / "l.bundle").stat().st_size < (tmp_path / "k.bundle").stat().st_size


def test_writes_are_atomic_and_checked(tmp_path):
    target = write_bundle(tmp_path / "f.bundle", META, _arrays())
    before = target.read_bytes()
    broken = _arrays()
    broken["maps"] = broken["maps"].astype(np.float32)
    broken["maps"][0, 0, 0] = np.nan
    with pytest.raises(ArithmeticError, match="maps"):
        write_bundle(target, META, broken)
    missing = _arrays()
    del missing["normal"]
    with pytest.raises(ValueError, match="normal"):
        write_bundle(target, META, missing)
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["f.bundle"]


def test_the_meta_schema_is_checked_on_write_and_on_load(tmp_path):
    """The bundle module owns the meta keys its readers rely on: a writer missing one, or a file
    whose header (checksum made to match) says something else, gets an error naming the key."""
    import zlib

    for bad in ({**META, "frame_size": [40]}, {k: v for k, v in META.items() if k != "map_size"},
                {**META, "crop_origin": [-1, 0]}, {**META, "sample_scale": float("nan")},
                {**META, "transport_direct": "x"}, {**META, "transport_direct": 10 ** 9}):
        with pytest.raises(InputError, match="meta '(frame_size|map_size|crop_origin|sample_scale|transport_direct)'"):
            write_bundle(tmp_path / "bad.bundle", bad, _arrays())
    assert not (tmp_path / "bad.bundle").exists()
    path = write_bundle(tmp_path / "ok.bundle", META, _arrays())
    data = path.read_bytes()
    hlen = struct.unpack_from("<Q", data, 16)[0]
    header = json.loads(data[24:24 + hlen])
    header["meta"]["frame_size"] = ["40", 30]
    new = json.dumps(header).encode().ljust(hlen)  # same length: the arrays' offsets hold
    assert len(new) == hlen
    forged = bytearray(data)
    forged[24:24 + hlen] = new
    struct.pack_into("<I", forged, 12, zlib.crc32(new))
    (tmp_path / "forged.bundle").write_bytes(bytes(forged))
    with pytest.raises(InputError, match="meta 'frame_size'"):
        load_bundle(tmp_path / "forged.bundle")


def test_the_fields_are_the_formats_table():
    """Field names every array the format's table documents, and nothing else."""
    import re

    from relight.kernels import bundle_format
    from relight.kernels.bundle_format import Field

    table = bundle_format.__doc__.split("======================  ===========================")[2]
    documented = set(re.findall(r"^([a-z][a-z0-9_]*)", table, re.M))
    assert documented == {f.value for f in Field}
    assert repr(Field.MAPS_ROWS) == "'maps_rows'" and f"{Field.MAPS_ROWS}" == "maps_rows"


def _string_keys_on_arrays(tree):
    """(line, key) of every string literal used as a key of something called ``arrays``
    (``arrays["x"]``, ``arrays.get("x")``, ``"x" in arrays``, ``arrays = {"x": ...}``,
    ``arrays.update({"x": ...})``), ``arrays`` a name or an attribute, or a name given one
    (``a = bundle.arrays``)."""
    import ast

    aliases = {t.id for node in ast.walk(tree) if isinstance(node, ast.Assign)
               and isinstance(node.value, ast.Attribute) and node.value.attr == "arrays"
               for t in node.targets if isinstance(t, ast.Name)}

    def is_arrays(node):
        return (isinstance(node, ast.Name) and node.id in aliases | {"arrays"}) or (
            isinstance(node, ast.Attribute) and node.attr == "arrays")

    def literal_keys(d):
        return [k.value for k in getattr(d, "keys", []) if isinstance(k, ast.Constant) and isinstance(k.value, str)]

    for node in ast.walk(tree):
        keys = []
        if isinstance(node, ast.Subscript) and is_arrays(node.value):
            keys = [node.slice.value] if isinstance(node.slice, ast.Constant) else []
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and is_arrays(node.func.value):
            arg = node.args[0] if node.args else None
            if node.func.attr in ("get", "pop") and isinstance(arg, ast.Constant):
                keys = [arg.value]
            elif node.func.attr == "update" and isinstance(arg, ast.Dict):
                keys = literal_keys(arg)
        elif isinstance(node, ast.Compare) and isinstance(node.left, ast.Constant) and any(
                isinstance(op, ast.In | ast.NotIn) for op in node.ops) and any(map(is_arrays, node.comparators)):
            keys = [node.left.value]
        elif isinstance(node, ast.Assign) and any(map(is_arrays, node.targets)) and isinstance(node.value, ast.Dict):
            keys = literal_keys(node.value)
        yield from ((node.lineno, k) for k in keys if isinstance(k, str))


def test_only_the_format_spells_the_field_names():
    """One owner for the bundle's field names: outside bundle_format.py the package keys a
    bundle's arrays with :class:`Field` members, never a string literal (a typo there is a
    KeyError at run time; with Field it fails at import)."""
    import ast

    from tests.architecture import modules

    found = [f"{path.name}:{line} {key!r}" for name, path in modules().items()
             if not name.endswith(".bundle_format")
             for line, key in _string_keys_on_arrays(ast.parse(path.read_text()))]
    assert not found, found
    # the scan sees what it looks for
    probe = ('arrays["pixels"]; b.arrays.get("maps"); "x" in arrays; arrays = {"a": 1}; arrays.update({"b": 2}); '
             'q = b.arrays; q["y"]')
    assert sorted(k for _, k in _string_keys_on_arrays(ast.parse(probe))) == ["a", "b", "maps", "pixels", "x", "y"]
