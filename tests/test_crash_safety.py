"""Writers killed with SIGKILL at random moments (``relight bench crash`` runs more kills): the
previous file is intact or the new one whole, never a damaged one; what a killed writer left
is removed by the next run."""

from __future__ import annotations

import os

import pytest

from relight.bench import crash


@pytest.mark.slow
def test_killed_writers_leave_no_damaged_file(shared_data, tmp_path):
    doc = crash.run(tmp_path, kills=crash.QUICK_KILLS, seed=1, progress=False)
    rows = {r["writer"]: r for r in doc["writers"]}
    assert set(rows) == {"capture", "filter", "environment upload"}
    for r in doc["writers"]:
        assert r["damaged_total"] == 0, r
    for name in ("capture", "filter"):
        assert rows[name]["temporaries_after_next_run"] == 0, rows[name]
        assert rows[name]["previous"] + rows[name]["new"] == crash.QUICK_KILLS
    assert rows["environment upload"]["restarts_clean_and_serving"] == crash.QUICK_KILLS


def test_stale_temporaries_of_dead_writers_removed(tmp_path):
    """A killed writer's temporary (its pid gone) is removed by the next write of the same
    target; a live writer's, and other files, are left."""
    import subprocess
    import sys

    from relight.imageio import atomic_path, clean_stale_temps

    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True).stdout.strip()
    stale = tmp_path / f".face.{dead}.abc123.tmp.bundle"
    stale.write_bytes(b"half a bundle")
    stale_dir = tmp_path / f".relit.{dead}.xyz.tmp"
    stale_dir.mkdir()
    live = tmp_path / f".face.{os.getppid()}.def456.tmp.bundle"
    live.write_bytes(b"being written")
    other = tmp_path / ".face.notes"
    other.write_bytes(b"mine")
    with atomic_path(tmp_path / "face.bundle") as tmp:
        tmp.write_bytes(b"whole")
    assert not stale.exists() and live.exists() and other.exists()
    assert (tmp_path / "face.bundle").read_bytes() == b"whole"
    assert clean_stale_temps(tmp_path, "relit") == [stale_dir] and not stale_dir.exists()
