"""The demo's live row is computed as the offline one: the node's score map and its image
score (``~/result``), never the mask's area (no ROS needed)."""

import types

import numpy as np

from allo_mrad_ros.demo import LiveTally
from allo_mrad_ros.metrics import MetricsAccumulator


class FakeSequence:
    """Four 4x4 frames: two normal, two with an anomaly (class 2) in the top-left pixel."""

    def __init__(self):
        self.frames = [
            types.SimpleNamespace(stamp_ns=stamp, name=f"f{stamp}", is_anomalous=stamp >= 2)
            for stamp in range(4)
        ]

    def load_mask(self, frame):
        mask = np.ones((4, 4), np.uint8)
        if frame.is_anomalous:
            mask[0, 0] = 2
        return mask

    def load_image(self, frame):
        return np.zeros((4, 4, 3), np.uint8)


def _recorded(stamp, image_score, mask_pixels):
    score = np.full((4, 4), 10.0, np.float32)
    score[0, 0] = 200.0 if stamp >= 2 else 20.0
    mask = np.zeros((4, 4), np.uint8)
    mask.flat[:mask_pixels] = 255
    return types.SimpleNamespace(
        stamp_ns=stamp, score=score, mask=mask, image_score=image_score, latency_ms=5.0
    )


# The image scores rank the anomalous frames first; the mask areas rank them last.
FRAMES = [_recorded(0, 1.0, 9), _recorded(1, 2.0, 8), _recorded(2, 3.0, 1), _recorded(3, 4.0, 0)]


def test_live_i_auroc_ranks_the_node_image_score_not_the_mask_area(tmp_path):
    tally = LiveTally(FakeSequence(), tmp_path, max_overlays=0)
    for recorded in FRAMES:
        tally.add(recorded)
    assert tally.frames == 4 and tally.missing() == []
    assert tally.metrics()["i_auroc"] == 1.0  # by mask area it would be 0.0


def test_live_row_equals_the_offline_computation_on_the_same_outputs(tmp_path):
    sequence = FakeSequence()
    tally = LiveTally(sequence, tmp_path, max_overlays=0)
    offline = MetricsAccumulator()
    for recorded, frame in zip(FRAMES, sequence.frames, strict=True):
        tally.add(recorded)
        offline.update(recorded.score, recorded.image_score, sequence.load_mask(frame))
    assert tally.metrics() == offline.compute().as_dict()


def test_outputs_of_frames_outside_the_sequence_are_ignored(tmp_path):
    tally = LiveTally(FakeSequence(), tmp_path)
    tally.add(_recorded(99, 1.0, 0))
    assert tally.frames == 0 and tally.overlays == []
    assert tally.missing() == ["f0", "f1", "f2", "f3"]
