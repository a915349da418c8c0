"""A short soak of a real relight-serve with good and misbehaving clients (``relight bench soak``
runs 10 minutes): the good clients see no error, the server is ready at the end, and every
kind of misbehaving client was run against it."""

from __future__ import annotations

import pytest

from relight.bench import soak


@pytest.mark.slow
def test_soak_with_misbehaving_clients(small_bundle, tmp_path):
    doc = soak.run(tmp_path, minutes=0.5, bundle=small_bundle.path, progress=False)
    assert doc["ready_after"], doc
    assert doc["good"]["errors"] == 0, doc["good"]["error_texts"]
    assert doc["good"]["returned"] > 0
    bad = doc["bad"]
    assert all(n >= 1 for n in bad["sessions"].values()), bad
    assert not bad["failures"], bad["failures"]
    assert bad["garbage_error_replies"] >= 4 * bad["sessions"]["garbage"]  # each kind answered, not dropped
    assert set(bad["http_codes"]) <= {400, 403, 413, 415, 422, 503}, bad["http_codes"]
