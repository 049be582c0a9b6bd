"""``make demo``: run the detectors on the built-in example and print what they found.

Until the ROS node and the sequence generator land, the demo uses the built-in synthetic
station view (:mod:`allo_mrad_ros.example_scene`): a reference, the same view with a loose
blanket pasted in, sensor noise and a 2-pixel shift, and the same query without the
blanket. It writes an overlay PNG per method to ``reports/demo/``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from allo_mrad_ros.detector import METHODS, MradParams, profile
from allo_mrad_ros.example_scene import example_pair


def overlay(image: np.ndarray, mask: np.ndarray, colour: tuple[int, int, int]) -> np.ndarray:
    """The RGB image with the mask's outline drawn on it."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    out = image.copy()
    cv2.drawContours(out, contours, -1, colour, thickness=max(2, image.shape[1] // 480))
    return out


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / union if union else 0.0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--profile", default="default", help="detector parameter profile")
    parser.add_argument("--ref-scale", type=float, default=0.25, help="reference resolution")
    parser.add_argument("--out", type=Path, default=Path("reports/demo"))
    args = parser.parse_args(argv)
    params: MradParams = profile(args.profile)
    pair = example_pair()
    height, width = pair.query.shape[:2]
    ref_size = (round(width * args.ref_scale), round(height * args.ref_scale))
    reference = cv2.resize(pair.reference, ref_size, interpolation=cv2.INTER_AREA)
    truth = pair.object_mask > 0
    args.out.mkdir(parents=True, exist_ok=True)
    print(
        f"built-in example: {width}x{height} query, {ref_size[0]}x{ref_size[1]} reference, "
        f"object of {np.count_nonzero(truth)} px; profile {args.profile!r}"
    )
    header = f"{'method':<8}{'frame':<8}{'anomalous':>10}{'area px':>10}{'IoU':>7}{'ms':>8}"
    print(header)
    for name, method in METHODS.items():
        for label, query in (("object", pair.query), ("clean", pair.clean_query)):
            result = method(query, reference, params)
            iou = _iou(result.mask > 0, truth) if label == "object" else float("nan")
            print(
                f"{name:<8}{label:<8}{result.anomalous!s:>10}{result.area:>10}"
                f"{iou:>7.2f}{result.timings_ms['total']:>8.1f}"
            )
            if label == "object":
                path = args.out / f"{name.lower()}_overlay.png"
                image = overlay(
                    overlay(query, pair.object_mask, (0, 255, 0)), result.mask, (255, 0, 0)
                )
                cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    print(f"overlays (green: ground truth, red: detected) in {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
