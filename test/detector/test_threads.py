"""The block split of per-cell loops: every cell once, errors surface."""

import cv2
import pytest

from allo_mrad_ros.detector.threads import for_each_block, worker_count


@pytest.fixture
def opencv_threads():
    previous = cv2.getNumThreads()
    yield cv2.setNumThreads
    cv2.setNumThreads(previous)


@pytest.mark.parametrize("threads", [1, 2, 4])
@pytest.mark.parametrize("cells", [1, 7, 64, 100])
def test_blocks_cover_every_cell_once(opencv_threads, threads, cells):
    opencv_threads(threads)
    seen = []
    for_each_block(lambda block: seen.extend(block), cells)
    assert sorted(seen) == list(range(cells))
    assert 1 <= worker_count(cells) <= max(1, threads)


def test_an_error_in_a_worker_block_is_raised_to_the_caller(opencv_threads):
    opencv_threads(2)

    def work(block):
        if 63 in block:
            raise ValueError("bad cell 63")

    with pytest.raises(ValueError, match="bad cell 63"):
        for_each_block(work, 64)


def test_small_images_stay_in_one_block(opencv_threads):
    from allo_mrad_ros.detector.threads import MIN_PIXELS_PER_BLOCK

    opencv_threads(4)
    assert worker_count(64, pixels=480 * 270) == 1
    assert worker_count(64, pixels=4 * MIN_PIXELS_PER_BLOCK) == 4
    assert worker_count(64, pixels=2 * MIN_PIXELS_PER_BLOCK) == 2
    assert worker_count(64) == 4
