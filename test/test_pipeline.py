"""Render-then-detect on real renders of the station model, with an object the model lacks."""

import numpy as np
import pytest
import trimesh
from array_backends import ARRAY_BACKENDS, skip_unless_runnable

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector import MradParams, profile
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.pipeline import (
    Pipeline,
    PipelineConfig,
    ProcessingError,
    ReferenceProvider,
    RenderSettings,
)
from allo_mrad_ros.render import ExtraObject, ReferenceRenderer
from allo_mrad_ros.render.settings import RenderSettingsError
from allo_mrad_ros.sky import with_sun
from allo_mrad_ros.view import View

INTRINSICS = CameraIntrinsics(640, 360, 444.4, 444.4, 320.0, 180.0)
SUN = (0.3, -0.5, 0.8)


@pytest.fixture(scope="module")
def renderers():
    camera = ReferenceRenderer(None, INTRINSICS, scale=1.0, shadows=False)
    reference = ReferenceProvider(None, INTRINSICS, RenderSettings(0.5, shadows=False))
    yield camera, reference
    camera.close()
    reference.close()


@pytest.fixture(scope="module")
def pose():
    return look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])


def test_object_absent_from_the_model_is_detected(renderers, pose):
    camera, reference_renderer = renderers
    # A 1.2 m gold-coloured box floating 8 m in front of the camera, seen against the sky.
    box = trimesh.creation.box((1.2, 1.2, 1.2))
    box.visual.face_colors = (230, 180, 40, 255)
    object_pose = pose.copy()
    object_pose[:3, 3] = pose[:3, 3] + 8.0 * pose[:3, 2] + 0.8 * pose[:3, 0] - 2.5 * pose[:3, 1]
    frame = camera.render(pose, SUN, extra_objects=[ExtraObject(box, object_pose)], labels=True)
    clean = camera.render(pose, SUN)
    config = PipelineConfig(reference_renderer.settings, methods=("MRAD", "PAD", "RXD"))
    processor = Pipeline(reference_renderer, config)
    found = processor.process(frame.rgb, View(pose, SUN))
    assert set(found.results) == {"MRAD", "PAD", "RXD"}
    assert found.reference.shape == (180, 320, 3)
    mrad = found.primary
    truth = frame.labels == 2
    assert mrad.anomalous
    hits = np.count_nonzero((mrad.mask > 0) & truth)
    # Hysteresis growth keeps the blur's rim around the object.
    assert hits >= 0.5 * np.count_nonzero(truth) and hits >= 0.7 * mrad.area
    assert not processor.process(clean.rgb, View(pose, SUN)).primary.anomalous
    assert found.timings_ms["render"] > 0 and found.timings_ms["total"] >= found.timings_ms["MRAD"]


def test_supplied_reference_skips_rendering(renderers, pose):
    camera, reference_renderer = renderers
    image = camera.render(pose, SUN).rgb
    processor = Pipeline(reference_renderer)
    given = reference_renderer.render(View(pose, SUN))
    out = processor.process(image, View(pose, SUN), reference=given)
    assert out.timings_ms["render"] == 0.0 and out.reference is given


def test_wrong_image_size_and_unknown_method_are_named(renderers, pose):
    _, reference_renderer = renderers
    with pytest.raises(ProcessingError, match="differs from the camera's 640x360"):
        Pipeline(reference_renderer).process(np.zeros((10, 10, 3), np.uint8), View(pose, SUN))
    with pytest.raises(ProcessingError, match="unknown detection method"):
        PipelineConfig(methods=("MRAD", "YOLO"))
    with pytest.raises(ProcessingError, match="render settings"):
        Pipeline(reference_renderer, PipelineConfig())
    with pytest.raises(RenderSettingsError, match="reference_scale"):
        RenderSettings(reference_scale=0.0)


def test_sun_disc_is_added_to_the_reference_only_when_in_view(renderers):
    _, provider = renderers
    reference_renderer = provider.renderer
    sun = np.array([0.2, -0.3, 0.93])
    sun /= np.linalg.norm(sun)
    eye = 100.0 * sun  # outside the station, on its sunny side
    towards_sun = look_at(eye, 200.0 * sun, up=(1.0, 0.0, 0.0))
    reference = provider.render(View(towards_sun, sun))
    assert reference[87:93, 157:163].max() > 200  # the disc (about 1 px radius here), ahead
    rendered = reference_renderer.render(towards_sun, sun, bodies=with_sun([], sun))
    assert rendered.bodies_in_view == ("sun",)
    away = look_at(eye, [0.0, 0.0, 0.0], up=(1.0, 0.0, 0.0))
    assert reference_renderer.render(away, sun, bodies=with_sun([], sun)).bodies_in_view == ()
    assert [b.name for b in with_sun([], sun)] == ["sun"]
    given = [("sun", (1.0, 0.0, 0.0), 5.0)]
    assert [(b.name, b.centre, b.radius) for b in with_sun(given, sun)] == given


def test_a_new_config_swaps_the_pipeline_and_leaves_the_old_one_as_it_was(renderers, pose):
    camera, provider = renderers
    image = camera.render(pose, SUN).rgb
    first = Pipeline(provider)
    coarse = first.config.replace(params=first.config.params.replace(grid=2))
    second = first.with_config(coarse)
    assert second.provider is first.provider and first.config.params.grid == MradParams().grid
    reference = provider.render(View(pose, SUN))
    one = first.process(image, View(pose, SUN), reference=reference).primary
    two = second.process(image, View(pose, SUN), reference=reference).primary
    again = first.process(image, View(pose, SUN), reference=reference).primary
    np.testing.assert_array_equal(one.score, again.score)
    assert second.config.params.grid == 2 and two.score.shape == one.score.shape


def test_a_frame_names_the_camera_its_reference_was_rendered_for(renderers, pose):
    camera, provider = renderers
    image = camera.render(pose, SUN).rgb
    pipeline = Pipeline(provider)
    rendered = pipeline.process(image, View(pose, SUN))
    assert rendered.reference_camera == INTRINSICS.scaled(0.5)
    assert rendered.reference.shape[:2] == (180, 320)
    supplied = pipeline.process(image, View(pose, SUN), reference=rendered.reference)
    assert supplied.reference_camera is None  # a supplied reference's camera is not known


def test_config_replace_reaches_the_render_settings():
    config = PipelineConfig().replace(reference_scale=0.25, methods=("PAD",))
    assert config.render.reference_scale == 0.25 and config.methods == ("PAD",)


def test_with_no_reader_of_the_score_map_the_mask_stays_and_the_ranking_map_is_skipped(
    monkeypatch,
):
    from types import SimpleNamespace

    from allo_mrad_ros.detector import pipeline as detector_pipeline
    from allo_mrad_ros.example_scene import example_pair

    pair = example_pair(360, 640)
    reference = pair.reference[::2, ::2]
    config = PipelineConfig(
        RenderSettings(0.5, shadows=False), profile("default", image_score="area")
    )
    assert config.params.pixel_score == "continuous"  # the default makes a ranking map
    processor = Pipeline(SimpleNamespace(settings=config.render), config)
    models = []
    cross_scores = detector_pipeline.cross_scores
    monkeypatch.setattr(
        detector_pipeline,
        "cross_scores",
        lambda *a: models.append(len(a[5])) or cross_scores(*a),
    )
    mapped = processor.detect(pair.query, reference)[0]["MRAD"]
    unmapped = processor.detect(pair.query, reference, score_map=False)[0]["MRAD"]
    assert models == [2, 1]  # the map's own photometric model is skipped
    assert mapped.anomalous and unmapped.anomalous and mapped.area == unmapped.area
    np.testing.assert_array_equal(mapped.mask, unmapped.mask)
    blurred = detector_pipeline.detect(
        pair.query, reference, config.params.replace(pixel_score="blurred")
    )
    np.testing.assert_array_equal(unmapped.score, blurred.score)
    assert not np.array_equal(mapped.score, unmapped.score)


def test_the_map_top_image_score_keeps_the_map_even_without_a_reader():
    from types import SimpleNamespace

    from allo_mrad_ros.example_scene import example_pair

    pair = example_pair(180, 320)
    config = PipelineConfig(RenderSettings(0.5, shadows=False))
    assert config.params.image_score == "map_top"
    processor = Pipeline(SimpleNamespace(settings=config.render), config)
    mapped = processor.detect(pair.query, pair.reference)[0]["MRAD"]
    unmapped = processor.detect(pair.query, pair.reference, score_map=False)[0]["MRAD"]
    assert unmapped.image_score == mapped.image_score


@pytest.mark.parametrize("backend", ARRAY_BACKENDS)
def test_every_array_backend_finds_the_same_object_as_numpy(renderers, pose, backend):
    skip_unless_runnable(backend)
    camera, reference_renderer = renderers
    box = trimesh.creation.box((1.2, 1.2, 1.2))
    box.visual.face_colors = (230, 180, 40, 255)
    object_pose = pose.copy()
    object_pose[:3, 3] = pose[:3, 3] + 8.0 * pose[:3, 2] + 0.8 * pose[:3, 0] - 2.5 * pose[:3, 1]
    frame = camera.render(pose, SUN, extra_objects=[ExtraObject(box, object_pose)])
    methods = ("MRAD", "PAD", "RXD")
    base = PipelineConfig(reference_renderer.settings, methods=methods)
    reference = reference_renderer.render(View(pose, SUN))
    expected = Pipeline(reference_renderer, base).process(frame.rgb, View(pose, SUN), reference)
    config = base.replace(array_backend=backend)
    found = Pipeline(reference_renderer, config).process(frame.rgb, View(pose, SUN), reference)
    for method in methods:
        ours, theirs = found.results[method], expected.results[method]
        # float32 sums in another order: equal up to rounding of the largest raw score.
        tolerance = 1e-5 * float(np.abs(theirs.raw_score).max()) + 1e-3
        np.testing.assert_allclose(ours.raw_score, theirs.raw_score, rtol=0, atol=tolerance)
        assert np.count_nonzero(ours.mask != theirs.mask) <= 1e-3 * ours.mask.size
        assert ours.anomalous == theirs.anomalous
    assert expected.primary.anomalous


def test_an_unknown_or_unrunnable_array_backend_is_named():
    with pytest.raises(ProcessingError, match="array_backend must be one of"):
        PipelineConfig(array_backend="cupy")
