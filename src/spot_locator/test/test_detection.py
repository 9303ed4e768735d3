"""Detection: the cell-wise contour tracing finds what tracing the whole frame finds."""
import cv2
import numpy as np
import pytest

from spot_locator.core import detection as det


def _frame(rng, shape, n_blobs, dtype=np.uint8, scale=1):
    """Dark noisy frame with striped and solid blobs, some side by side in one band,
    some at the image edges.
    """
    h, w = shape
    img = rng.integers(0, 12, shape).astype(np.int64)
    for _ in range(n_blobs):
        y, x = int(rng.integers(-5, h)), int(rng.integers(-5, w))
        bh, bw = int(rng.integers(1, 40)), int(rng.integers(1, 40))
        level = int(rng.integers(20, 256))
        ys = np.arange(max(y, 0), min(y + bh, h))
        if rng.random() < 0.5:
            ys = ys[(ys // 3) % 2 == 0]            # stripes
        img[ys, max(x, 0):min(x + bw, w)] = level
    # two blobs side by side on the same rows, and single lit pixels
    img[h // 2:h // 2 + 6, 10:20] = 200
    img[h // 2 + 2:h // 2 + 9, 30:36] = 200
    img[rng.integers(0, h, 5), rng.integers(0, w, 5)] = 255
    return (img * scale).astype(dtype)


def _frame_contour_boxes(img, level):
    binary = (img > level).astype(np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    return [cv2.boundingRect(c) for c in contours]


@pytest.mark.parametrize('shape', [(720, 1280), (717, 640), (13, 50), (9, 33)])
@pytest.mark.parametrize('dtype,scale', [(np.uint8, 1), (np.uint16, 3)])
def test_cell_tracing_gives_the_whole_frames_boxes_in_its_order(shape, dtype, scale):
    rng = np.random.default_rng(7)
    for n_blobs in (0, 3, 30, 120):        # 120: more cells than the limit, traced whole
        img = _frame(rng, shape, n_blobs, dtype, scale)
        level = 20.5 * scale
        expected = _frame_contour_boxes(img, level)
        assert det._fragment_boxes(img, level) == expected
        assert det._frame_boxes(img, level) == expected


def test_background_histogram_median_and_mad_match_numpy():
    rng = np.random.default_rng(3)
    for _ in range(50):
        img = np.clip(rng.normal(rng.uniform(0, 255), rng.uniform(0, 30), (64, 80)),
                      0, 255).astype(np.uint8)
        sample = img[::8, ::8].ravel().astype(float)
        med, sigma = det.background_and_noise(img)
        # the lower median of the integer levels, as the histogram's cumulative count
        lower = float(np.sort(sample)[(sample.size - 1) // 2])
        assert med == lower
        dev = np.sort(np.abs(sample - med))
        assert sigma == pytest.approx(max(1.4826 * dev[(dev.size - 1) // 2], 0.29))
