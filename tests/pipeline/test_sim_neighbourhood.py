"""pipeline.neighbourhood returns what scipy.ndimage returns (the simulator uses it instead of scipy.ndimage)."""
import numpy as np
import pytest

ndimage = pytest.importorskip("scipy.ndimage")

from pipeline.neighbourhood import binary_dilation, maximum_filter3, minimum_filter3  # noqa: E402

CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], bool)


@pytest.mark.parametrize("shape", [(1, 1), (1, 5), (4, 1), (7, 9), (32, 17)])
def test_binary_dilation_matches_scipy(shape):
    rng = np.random.default_rng(shape[0] * 100 + shape[1])
    for density in (0.0, 0.05, 0.5, 1.0):
        mask = rng.random(shape) < density
        for structure in (CROSS, np.ones((3, 3), bool)):
            np.testing.assert_array_equal(binary_dilation(mask, structure), ndimage.binary_dilation(mask, structure))


@pytest.mark.parametrize("shape", [(1, 1), (2, 7), (7, 9), (32, 17)])
def test_min_max_filter_match_scipy(shape):
    rng = np.random.default_rng(shape[0] * 7 + shape[1])
    image = rng.normal(size=shape)
    image[rng.random(shape) < 0.3] = np.inf      # the window bound's 'no path' pixels
    image[rng.random(shape) < 0.3] = -np.inf
    np.testing.assert_array_equal(maximum_filter3(image), ndimage.maximum_filter(image, size=3))
    np.testing.assert_array_equal(minimum_filter3(image), ndimage.minimum_filter(image, size=3))
    single = np.zeros(shape)
    single[shape[0] // 2, shape[1] // 2] = 1.0
    np.testing.assert_array_equal(maximum_filter3(single), ndimage.maximum_filter(single, size=3))
