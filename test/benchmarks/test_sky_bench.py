"""The sky benchmark: which frames it measures and what it counts, on a tiny sequence whose
camera looks at the Sun (its glare drawn into the query) or away from it, or at the Moon."""

from __future__ import annotations

import cv2
import numpy as np

from allo_mrad_ros.camera import ALLO_INTRINSICS
from allo_mrad_ros.detector import MradParams
from allo_mrad_ros.geometry import look_at, pose_components
from allo_mrad_ros.resources import share_path
from allo_mrad_ros.sequence import SequenceMeta, SequenceWriter
from allo_mrad_ros.sequence.model import MASK_ANOMALY
from allo_mrad_ros.sky import earth_and_moon
from allo_mrad_ros.view import View
from benchmarks.sky import measure, table

CAMERA = ALLO_INTRINSICS.scaled(1.0 / 12.0)
SUN = np.array([0.2, -0.3, 0.93]) / np.linalg.norm([0.2, -0.3, 0.93])


def write_sun_sequence(root):
    """Test frames: the Sun's glare alone (normal); the glare and a green glint elsewhere
    (anomalous); the camera turned away from the Sun, a glint alone (anomalous)."""
    meta = SequenceMeta(
        name="sun", camera=CAMERA, rate_hz=10.0, mesh=share_path("meshes", "station.glb")
    )
    eye = 400.0 * SUN  # far out on the sunny side: space all round
    towards = look_at(eye, 500.0 * SUN, up=(1.0, 0.0, 0.0))
    away = look_at(eye, 300.0 * SUN, up=(1.0, 0.0, 0.0))
    sun = tuple(round(v) for v in View(towards, SUN).sun_pixel(CAMERA))
    with SequenceWriter(root, meta, start_ns=1_000_000_000) as writer:
        for index, (pose, glare, glint) in enumerate(
            ((towards, True, False), (towards, True, True), (away, False, True))
        ):
            image = np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8)
            mask = np.zeros(image.shape[:2], np.uint8)
            if glare:
                cv2.circle(image, sun, 20, (140, 140, 140), -1)
                cv2.circle(image, sun, 8, (255, 255, 255), -1)
            if glint:
                cv2.rectangle(image, (20, 10), (30, 20), (40, 220, 40), -1)
                mask[10:21, 20:31] = MASK_ANOMALY
            position, quaternion = pose_components(pose)
            writer.add_frame(
                split="test",
                camera=index,
                image=image,
                mask=mask,
                anomaly="glint" if glint else "",
                position=position,
                quaternion=quaternion,
                sun_direction=SUN,
                sun_strength=1.0,
            )
    return root


def test_only_frames_with_the_sun_are_measured_and_the_glare_is_no_longer_flagged(tmp_path):
    root = write_sun_sequence(tmp_path / "sun")
    report = measure("sun_glare", str(root), "test", [0.0, 8.0], MradParams(grid=4))
    assert report["frames"] == 2  # the frame turned away is left out
    off, on = report["per_value"]["0.0"], report["per_value"]["8.0"]
    assert (off["normal"], off["anomalous"]) == (1, 1)
    assert off["normal_flagged"] == 1 and on["normal_flagged"] == 0
    # The glint is found, on the object, whatever the factor.
    assert off["found_on_object"] == on["found_on_object"] == 1
    assert on["anomaly_pixels_masked"] > 0 and on["anomaly_pixels"] == 121
    rows = table("sun_glare", "sun:test", report).splitlines()
    assert rows[0] == "sun:test: 2 frames with the Sun in view"
    # Flagged off the object: the normal frame flagged, at 0 only.
    assert "| 1/2 |" in rows[3] and "| 0/2 |" in rows[4]


LARGE = ALLO_INTRINSICS.scaled(1.0 / 4.0)


def write_moon_sequence(root):
    """Test frames: the Moon in view, its limb 30 % wider in the query than the sphere the
    reference draws (normal); the camera turned away from it (normal)."""
    meta = SequenceMeta(
        name="moon", camera=LARGE, rate_hz=10.0, mesh=share_path("meshes", "station.glb")
    )
    eye = np.array([0.0, 0.0, 400.0])  # far above the station: space all round
    ahead = np.array([1.0, 0.0, 0.0])
    towards = look_at(eye, eye + ahead, up=(0.0, 0.0, 1.0))
    away = look_at(eye, eye - ahead, up=(0.0, 0.0, 1.0))
    moon = [float(eye[0] + 3000.0), float(eye[1]), float(eye[2]), 60.0]
    ((x, y, radius),) = View(towards, SUN, bodies=earth_and_moon(None, moon)).body_discs(LARGE)
    with SequenceWriter(root, meta, start_ns=1_000_000_000) as writer:
        for index, pose in enumerate((towards, away)):
            image = np.zeros((LARGE.height, LARGE.width, 3), np.uint8)
            if index == 0:
                centre = (round(x - 0.5), round(y - 0.5))
                cv2.circle(image, centre, round(1.3 * radius), (110, 108, 104), -1)
            position, quaternion = pose_components(pose)
            writer.add_frame(
                split="test",
                camera=index,
                image=image,
                mask=np.zeros(image.shape[:2], np.uint8),
                anomaly="",
                position=position,
                quaternion=quaternion,
                sun_direction=SUN,
                sun_strength=1.0,
                moon=moon,
            )
    return root, radius


def test_a_moon_limb_the_reference_places_coarsely_is_no_longer_flagged(tmp_path):
    root, radius = write_moon_sequence(tmp_path / "moon")
    # 0.3 of the radius is within one reference pixel (8 camera pixels at the 1/8 scale).
    assert 0.3 * radius < 8.0
    report = measure("body_margin", str(root), "test", [0.0, 1.0], MradParams())
    assert report["frames"] == 1  # the frame turned away is left out
    off, on = report["per_value"]["0.0"], report["per_value"]["1.0"]
    assert (off["normal"], off["normal_flagged"]) == (1, 1)
    assert (on["normal"], on["normal_flagged"]) == (1, 0)
    assert table("body_margin", "moon", report).startswith("moon: 1 frames with a body in view")
