"""The capture variants the benchmarks compare: the paper's method with each of our additions
switched off, and the classical fits (as ``relight capture`` flags in words)."""

from __future__ import annotations

#: Capture options of each variant (``relight capture`` flags in words).
VARIANTS: dict[str, dict] = {
    "full": {},
    "full -visibility": {"visibility": False},
    "full -adaptation": {"adaptation": False},
    "full -both": {"visibility": False, "adaptation": False},
    "full -extrapolation": {"extrapolation": False},
    "full -spline": {"spline": False},
    "full, paper adaptation": {"paper_adaptation": True},
    "barycentric": {"method": "barycentric"},
    "ptm": {"method": "ptm"},
    "hsh": {"method": "hsh"},
    "hsh2": {"method": "hsh2"},
    "rbf": {"method": "rbf"},
}
BASELINES = ("barycentric", "ptm", "hsh", "hsh2", "rbf")
