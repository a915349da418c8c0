"""relight.sampling.bilinear: the one bilinear read of an image with replicated edges."""

import numpy as np

from relight.sampling import bilinear


def test_interior_points_are_the_weighted_corners_and_outside_reads_the_edge():
    img = np.arange(4 * 5 * 2, dtype=np.float64).reshape(4, 5, 2) ** 1.5
    x = np.array([0.0, 1.25, 3.5, 4.0, -3.0, 9.0, 2.0])
    y = np.array([0.0, 2.75, 0.5, 3.0, 1.0, -2.0, 7.5])
    got = bilinear(img, x, y)
    for k in range(3):  # the interior: the four corners' weighted sum
        x0, y0 = int(np.floor(x[k])), int(np.floor(y[k]))
        ax, ay = x[k] - x0, y[k] - y0
        x1, y1 = min(x0 + 1, 4), min(y0 + 1, 3)
        want = ((1 - ax) * (1 - ay) * img[y0, x0] + ax * (1 - ay) * img[y0, x1]
                + (1 - ax) * ay * img[y1, x0] + ax * ay * img[y1, x1])
        np.testing.assert_allclose(got[k], want, rtol=1e-12)
    np.testing.assert_allclose(got[3], img[3, 4], rtol=1e-12)  # the last pixel exactly
    np.testing.assert_allclose(got[4], img[1, 0], rtol=1e-12)  # left of the image: its left edge
    np.testing.assert_allclose(got[5], img[0, 4], rtol=1e-12)  # above and right: the corner
    np.testing.assert_allclose(got[6], img[3, 2], rtol=1e-12)  # below: the bottom row


def test_a_one_pixel_wide_image_is_read_without_leaving_it():
    img = np.array([[[1.0]], [[3.0]]])  # (2, 1, 1)
    got = bilinear(img, np.array([0.0, 0.7, -1.0]), np.array([0.5, 0.5, 2.0]))
    np.testing.assert_allclose(got[:, 0], [2.0, 2.0, 3.0])
