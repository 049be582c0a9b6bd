"""The opt-in dark glossy object (``dark_visor``) and the dark-background placement rule."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from allo_mrad_ros.ephemeris import StationEphemeris
from allo_mrad_ros.geometry import pose_matrix
from allo_mrad_ros.render import (
    LABEL_ANOMALY,
    LABEL_SPACE,
    LABEL_STATION,
    ExtraObject,
    ReferenceRenderer,
)
from allo_mrad_ros.sequence import validate_sequence
from allo_mrad_ros.synth.config import SynthError, preset
from allo_mrad_ros.synth.frames import background_level
from allo_mrad_ros.synth.generator import generate
from allo_mrad_ros.synth.objects import (
    ANOMALY_TYPES,
    DARK_TYPES,
    KNOWN_TYPES,
    MATERIALS,
    OPT_IN_TYPES,
    build_anomaly,
)
from allo_mrad_ros.synth.planning import plan_frames

SEED = 5


def _pose(extra, prefix):
    return pose_matrix(
        [float(extra[f"{prefix}_{a}"]) for a in ("tx", "ty", "tz")],
        [float(extra[f"{prefix}_{a}"]) for a in ("qx", "qy", "qz", "qw")],
    )


def test_dark_visor_is_a_dark_glossy_closed_object():
    for seed in range(4):
        obj = build_anomaly("dark_visor", seed)
        assert all(p.mesh.is_watertight and p.mesh.volume > 0 for p in obj.parts)
        assert 0.25 <= obj.extents.max() <= 0.5  # a helmet, 30-40 cm
        np.testing.assert_allclose(obj.mesh.bounds.mean(axis=0), 0.0, atol=1e-9)
        colour, metallic, roughness = MATERIALS[obj.parts[0].material]
        # The visor: black, glossy dielectric.
        assert max(colour) <= 0.05 and metallic == 0.0 and roughness <= 0.1
        # The whole object is dark: area-weighted albedo under 10 %.
        areas = np.array([p.mesh.area for p in obj.parts])
        albedo = np.array([np.mean(MATERIALS[p.material][0]) for p in obj.parts])
        assert float(areas @ albedo / areas.sum()) < 0.1
    assert not np.array_equal(
        build_anomaly("dark_visor", 1).mesh.vertices, build_anomaly("dark_visor", 2).mesh.vertices
    )


def test_dark_visor_is_opt_in():
    assert "dark_visor" in OPT_IN_TYPES and "dark_visor" in KNOWN_TYPES
    assert "dark_visor" not in ANOMALY_TYPES and set(KNOWN_TYPES) >= DARK_TYPES
    # The default draw (every existing preset) never picks it ...
    assert all(p.anomaly != "dark_visor" for p in plan_frames(preset("bench"), 0))
    # ... and bench-dark draws nothing else.
    kinds = {p.anomaly for p in plan_frames(preset("bench-dark"), 0) if p.anomaly}
    assert kinds == {"dark_visor"}


@pytest.mark.parametrize(
    "change",
    [
        {"dark_background_types": ("spoon",)},
        {"dark_background_types": "dark_visor"},
        {"dark_background_level": -0.1},
        {"dark_background_level": 1.5},
        {"dark_background_level": math.nan},
    ],
)
def test_dark_background_settings_are_validated(change):
    with pytest.raises(SynthError):
        preset("smoke").with_overrides(**change)


def test_background_level_reads_the_ring_around_the_object():
    labels = np.full((60, 100), LABEL_STATION, np.uint8)
    labels[25:35, 45:55] = LABEL_ANOMALY
    rgb = np.full((60, 100, 3), 51, np.uint8)  # luma 51 = 0.2
    rgb[25:35, 45:55] = 250  # the object itself does not count
    assert background_level(rgb, labels) == pytest.approx(0.2, abs=1e-6)
    labels[:, 40:60] = LABEL_SPACE  # mostly space around it: not against the station
    labels[25:35, 45:55] = LABEL_ANOMALY
    assert background_level(rgb, labels) == math.inf
    assert background_level(rgb, np.full((60, 100), LABEL_STATION, np.uint8)) == math.inf


@pytest.fixture(scope="module")
def dark_sequence(tmp_path_factory):
    config = preset("smoke").with_overrides(
        anomaly_types=("dark_visor",),
        dark_background_types=("dark_visor",),
        colour_probability=0.0,
    )
    root = tmp_path_factory.mktemp("dark") / "seq"
    generate(config, root, SEED, progress=False)
    return validate_sequence(root, decode_images=True)


def test_generated_dark_visor_is_dark_with_an_exact_mask(dark_sequence):
    sequence = dark_sequence
    anomalous = [f for f in sequence.frames if f.is_anomalous]
    assert anomalous and {f.anomaly for f in anomalous} == {"dark_visor"}
    with ReferenceRenderer(sequence.meta.mesh, sequence.meta.camera, scale=1.0) as renderer:
        for frame in anomalous:
            e = frame.extra
            mask = cv2.imread(str(frame.mask), cv2.IMREAD_GRAYSCALE)
            image = cv2.cvtColor(cv2.imread(str(frame.image)), cv2.COLOR_BGR2RGB)
            # The mask is where adding the object changes the depth buffer.
            sky = StationEphemeris().sky_on_day(int(e["day"]))
            obj = build_anomaly(
                frame.anomaly, int(e["object_seed"]), e["colour"], float(e["scale"])
            )
            T = _pose(e, "true")
            extras = [ExtraObject(obj.scene, _pose(e, "obj"))]
            with_obj = renderer.render(T, sky.sun_direction, 1.0, (), extras, depth=True)
            without = renderer.render(T, sky.sun_direction, 1.0, (), depth=True)
            np.testing.assert_array_equal(mask == 2, with_obj.depth != without.depth)
            # Dark: most of the object's pixels are under a quarter of full scale.
            luma = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[mask == 2]
            assert np.median(luma) < 64, np.median(luma)
            if "background_level" in e and e["background_level"] not in ("", None):
                assert 0.0 <= float(e["background_level"]) <= 1.0
