"""Where the real data sets are: ``../shared/data`` beside the project (the Yale faces, the RTI
dome, the light probes, the head scans), looked up once for every benchmark and command."""
from __future__ import annotations

from pathlib import Path

#: The project's folder (this file is bench/real_data.py in it).
PROJECT = Path(__file__).resolve().parents[1]


def shared_data(name: str | None = None, probe: str | None = None) -> Path | None:
    """``../shared/data`` (or its set ``name``, holding files that match the glob ``probe``) beside
    the working folder or beside the project, whichever has it first; None when neither does."""
    for base in (Path.cwd(), PROJECT):
        cand = base.parent / "shared" / "data"
        if name is not None:
            cand = cand / name
        if cand.is_dir() and (probe is None or any(cand.glob(probe))):
            return cand
    return None
