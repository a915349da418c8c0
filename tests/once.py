"""Test data made once per test run and shared by pytest-xdist's worker processes."""

from __future__ import annotations

import dataclasses
import fcntl
import json
import os
from collections.abc import Callable
from pathlib import Path

#: A folder for the shared test data that outlives one pytest run (else each run makes its own).
SHARED_ENV = "RELIGHT_TEST_SHARED"


def made_once(tmp_path_factory, name: str, make: Callable[[Path], None]) -> Path:
    """A folder ``name`` that ``make(folder)`` fills, made once per test run: under pytest-xdist
    the workers share it (the first one makes it while holding a lock, the others wait and
    reuse it); a make that raised leaves no "done" mark, so the next asker tries again."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the run's folder, above each worker's own
    if os.environ.get(SHARED_ENV):  # kept across runs (make test-cpus: made natively, used emulated)
        base = Path(os.environ[SHARED_ENV])
        base.mkdir(parents=True, exist_ok=True)
    folder = base / f"shared-{name}"
    with open(base / f"shared-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (folder / ".done").exists():
            folder.mkdir(exist_ok=True)
            make(folder)
            (folder / ".done").touch()
    return folder


def synthesized(tmp_path_factory, name: str, cfg):
    """The SynthResult of ``synthesize(cfg)``, made once per run (see :func:`made_once`)."""
    from relight.pipeline.synth.config import SynthResult
    from relight.pipeline.synth.studio import synthesize

    def make(folder: Path):
        res = synthesize(folder / "synth", cfg, progress=False)
        fields = {k: str(v) if isinstance(v, Path) else v for k, v in dataclasses.asdict(res).items()}
        (folder / "result.json").write_text(json.dumps(fields))

    fields = json.loads((made_once(tmp_path_factory, name, make) / "result.json").read_text())
    return SynthResult(**{k: Path(fields[k]) if k in ("out", "video", "truth") else fields[k] for k in fields})
