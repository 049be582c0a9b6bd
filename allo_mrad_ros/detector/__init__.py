"""The MRAD detector core: pure NumPy/OpenCV, no ROS.

Pipeline stages, each in one place:

1. cell statistics -- :mod:`.statistics`; cross score -- :mod:`.score`
2. scaling and threshold -- :mod:`.postprocess` (``scale_scores``, ``threshold_scores``)
3. noise removal and blur -- :mod:`.postprocess` (``remove_noise``, ``blur_scores``)
4. seeds -- :mod:`.regions` (``find_seeds``)
5. region growing and the regions as records -- :mod:`.regions` (``grow_hysteresis``,
   ``grow_regions``, ``extract_regions``: :class:`Region`)
6. decision, anomaly score and image score -- :mod:`.decision` (``frame_decision``,
   ``image_score``)

:mod:`.pipeline` composes them in :func:`detect`; stage 0, the colour transfer, is
:mod:`.colour_transfer`.
"""

from allo_mrad_ros.detector.decision import decide
from allo_mrad_ros.detector.params import PROFILES, MradParams, profile
from allo_mrad_ros.detector.pipeline import (
    METHODS,
    DetectionResult,
    Detector,
    detect,
    detect_pad,
    detect_rxd,
)
from allo_mrad_ros.detector.regions import Region

__all__ = [
    "METHODS",
    "PROFILES",
    "DetectionResult",
    "Detector",
    "MradParams",
    "Region",
    "decide",
    "detect",
    "detect_pad",
    "detect_rxd",
    "profile",
]
