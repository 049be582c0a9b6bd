"""Draw ``detection.png`` for the README: one frame of the demo sequence, MRAD with the
default parameters, ground truth outlined in green and the detection in red.

Run after ``make demo`` (which generates ``data/demo/sequence``)::

    .venv/bin/python docs/images/make_detection_image.py
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from allo_mrad_ros.evaluation.sources import open_sequence
from allo_mrad_ros.pipeline import Pipeline
from allo_mrad_ros.visualise import outline


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sequence", type=Path, default=Path("data/demo/sequence"))
    parser.add_argument("--frame", default="000017_wrench", help="frame name")
    parser.add_argument("--width", type=int, default=800, help="width of the picture")
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("detection.png"))
    args = parser.parse_args()

    source = open_sequence(args.sequence)
    index = next(i for i, f in enumerate(source.sequence.frames) if f.name == args.frame)
    frame = next(source.frames([index]))
    with Pipeline.open(source.camera, mesh=source.mesh) as pipeline:
        mrad = pipeline.process(frame.image, frame.view).primary

    height = round(frame.image.shape[0] * args.width / frame.image.shape[1])
    size = (args.width, height)
    image = cv2.resize(frame.image, size, interpolation=cv2.INTER_AREA)
    truth = cv2.resize((frame.mask == 2).astype(np.uint8) * 255, size, cv2.INTER_NEAREST)
    found = cv2.resize(np.ascontiguousarray(mrad.mask), size, interpolation=cv2.INTER_NEAREST)
    # The picture is the image in 62 colours plus the two outlines' own, so the file is small.
    picture = Image.fromarray(image).quantize(62, dither=Image.Dither.NONE)
    indices = np.array(picture)
    blank = np.zeros_like(image)
    indices[outline(blank, truth, (1, 1, 1))[..., 0] > 0] = 62
    indices[outline(blank, found, (1, 1, 1))[..., 0] > 0] = 63
    palette = [*picture.getpalette()[: 62 * 3], 0, 255, 0, 255, 40, 40]
    picture = Image.fromarray(indices)
    picture.putpalette(palette)
    picture.save(args.out, optimize=True)
    print(f"{args.out}: frame {frame.name} ({frame.anomaly}), anomalous={mrad.anomalous}")


if __name__ == "__main__":
    main()
