"""The byte-level mutations of ``relight bench fuzz``: a Hypothesis strategy of edits (bit flips,
interesting bytes and integers, inserts, deletes, truncation, repeats, splices of another seed,
numbers in text replaced) and their application to a seed file."""

from __future__ import annotations

import re

import numpy as np

#: Interesting replacement values (header fields, counts, sizes, numbers in text).
INTERESTING_INTS = (0, 1, -1, 2, 3, 7, 16, 64, 255, 256, 4096, 65535, 65536, 2 ** 31 - 1, 2 ** 31, 2 ** 32,
                    2 ** 63 - 1, 10 ** 12)
INTERESTING_TEXT = ("0", "-1", "1e308", "-1e308", "nan", "inf", "-0", "4294967296", "99999999999999999999",
                    "1e-320", "", " ", "\x00", "NaN", "1.5", "0x10")


def mutations(st):
    """A Hypothesis strategy of byte-level edits: (op, where, value) triples applied in order."""
    ops = st.sampled_from(("flip", "byte", "int32", "insert", "delete", "truncate", "repeat", "splice",
                           "number"))
    return st.lists(st.tuples(ops, st.floats(0.0, 1.0), st.integers(0, 2 ** 32 - 1), st.booleans()),
                    min_size=0, max_size=6)


def apply_mutations(data: bytes, edits, seeds: list[bytes]) -> bytes:
    """``data`` with ``edits`` applied; positions are fractions, biased to the first 512 bytes
    (where the headers a parser trusts live) when the edit's flag is set."""
    buf = bytearray(data)
    for op, frac, value, head in edits:
        n = len(buf)
        span = min(n, 512) if head else n
        pos = min(int(frac * span), max(n - 1, 0))
        if op == "flip" and n:
            buf[pos] ^= 1 << (value % 8)
        elif op == "byte" and n:
            buf[pos] = (0x00, 0xFF, 0x7F, 0x80, 0x01, 0x20, 0x0A)[value % 7] if value & 8 else value & 0xFF
        elif op == "int32" and n >= 4:
            v = INTERESTING_INTS[value % len(INTERESTING_INTS)] & 0xFFFFFFFF
            pos = min(pos, n - 4)
            buf[pos:pos + 4] = v.to_bytes(4, "little" if value & 32 else "big")
        elif op == "insert":
            rng = np.random.default_rng(value)
            buf[pos:pos] = rng.integers(0, 256, 1 + value % 64, dtype=np.uint8).tobytes()
        elif op == "delete" and n:
            del buf[pos:pos + 1 + value % 256]
        elif op == "truncate":
            del buf[pos:]
        elif op == "repeat" and n:
            chunk = bytes(buf[pos:pos + 1 + value % 128])
            buf[pos:pos] = chunk * (1 + value % 4)
        elif op == "splice" and seeds:
            other = seeds[value % len(seeds)]
            cut = int(frac * len(other))
            buf[pos:] = other[cut:]
        elif op == "number":
            nums = list(re.finditer(rb"-?\d+(\.\d+)?([eE][-+]?\d+)?", bytes(buf[:1 << 16])))
            if nums:
                m = nums[value % len(nums)]
                buf[m.start():m.end()] = INTERESTING_TEXT[(value >> 8) % len(INTERESTING_TEXT)].encode()
    return bytes(buf)
