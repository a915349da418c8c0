"""relight bench video's first-frame figures (bench.first_frame): what counts as found, the
summary's counts over the goal's poses, and the plot a person looks at."""

import numpy as np

from relight.bench.first_frame import GOAL_PITCH, GOAL_YAW, _on_head, plot, summary, table
from relight.imageio import read_image


def test_a_box_counts_when_its_centre_is_on_the_head():
    cov = np.zeros((90, 160), np.float32)
    cov[20:60, 50:90] = 1.0
    assert _on_head((55, 25, 85, 55), cov)  # centre (70, 40)
    assert not _on_head((0, 0, 20, 20), cov)
    assert _on_head((41, 11, 55, 25), cov)  # centre (48, 18): within 2 px of the head's corner (50, 20)
    assert not _on_head((40, 10, 54, 24), cov)  # centre (47, 17): 3 px off
    assert not _on_head((150, 80, 170, 100), cov)  # (past the frame's edge: no error)


def _doc():
    yaws, pitches = [-60, 0, 60], [-30, 0]
    rows = []
    for size in ([640, 360], [1280, 720]):
        for p in pitches:
            for y in yaws:
                goal = abs(y) <= GOAL_YAW and abs(p) <= GOAL_PITCH
                rows.append({"size": size, "yaw": y, "pitch": p, "haar": y == 0 and p == 0, "detector": goal,
                             "search_ms": 10.0 + abs(y) / 10, "path": goal, "pose_error_deg": 1.5 if goal else None,
                             "in_goal": goal})
    return {"rows": rows, "yaws": yaws, "pitches": pitches, "sizes": [[640, 360], [1280, 720]],
            "summary": summary(rows)}


def test_the_summary_counts_the_goals_poses_and_all(tmp_path):
    doc = _doc()
    s = doc["summary"]
    assert [x["size"] for x in s] == [[640, 360], [1280, 720]]
    assert s[0]["goal_poses"] == 1 and s[0]["poses"] == 6  # (0, 0) alone is within 45 / 25 deg
    assert (s[0]["haar_goal"], s[0]["detector_goal"], s[0]["path_goal"]) == (1, 1, 1)
    assert s[0]["search_ms"] == 16.0 and s[0]["pose_error_median_deg"] == 1.5
    assert "| 640x360 | 1 / 1 / 1 of 1 | 1 / 1 / 1 of 6 | 16.0 | 1.5 deg |" in table(doc)


def test_the_plot_is_a_png_with_a_panel_per_size_and_way(tmp_path):
    path = plot(_doc(), tmp_path / "first_frame.png")
    img = read_image(path)
    assert img.ndim == 3 and img.shape[1] > img.shape[0]  # two sizes across, three ways down: wider than tall
    assert img.shape[0] > 200 and img.std() > 0.05  # drawn, not blank (0-1 values)
