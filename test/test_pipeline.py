"""Render-then-detect on real renders of the station model, with an object the model lacks."""

import cv2
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
    ProcessedFrame,
    ProcessingError,
    RenderSettings,
)
from allo_mrad_ros.render import ExtraObject, ReferenceRenderer, RendererError
from allo_mrad_ros.render.settings import RenderSettingsError
from allo_mrad_ros.sky import with_sun
from allo_mrad_ros.view import View

INTRINSICS = CameraIntrinsics(640, 360, 444.4, 444.4, 320.0, 180.0)
SUN = (0.3, -0.5, 0.8)


@pytest.fixture(scope="module")
def renderers():
    camera = ReferenceRenderer(None, INTRINSICS, scale=1.0, shadows=False)
    config = PipelineConfig(RenderSettings(0.5, shadows=False))
    with camera, Pipeline.open(INTRINSICS, config=config) as pipeline:
        yield camera, pipeline


@pytest.fixture(scope="module")
def pose():
    return look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])


def test_object_absent_from_the_model_is_detected(renderers, pose):
    camera, pipeline = renderers
    # A 1.2 m gold-coloured box floating 8 m in front of the camera, seen against the sky.
    box = trimesh.creation.box((1.2, 1.2, 1.2))
    box.visual.face_colors = (230, 180, 40, 255)
    object_pose = pose.copy()
    object_pose[:3, 3] = pose[:3, 3] + 8.0 * pose[:3, 2] + 0.8 * pose[:3, 0] - 2.5 * pose[:3, 1]
    frame = camera.render(pose, SUN, extra_objects=[ExtraObject(box, object_pose)], labels=True)
    clean = camera.render(pose, SUN)
    processor = pipeline.with_config(pipeline.config.replace(methods=("MRAD", "PAD", "RXD")))
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
    camera, pipeline = renderers
    image = camera.render(pose, SUN).rgb
    given = pipeline.render(View(pose, SUN))
    out = pipeline.process(image, View(pose, SUN), reference=given)
    assert out.timings_ms["render"] == 0.0 and out.reference is given


def test_wrong_image_size_and_unknown_method_are_named(renderers, pose):
    _, pipeline = renderers
    with pytest.raises(ProcessingError, match="differs from the camera's 640x360"):
        pipeline.process(np.zeros((10, 10, 3), np.uint8), View(pose, SUN))
    with pytest.raises(ProcessingError, match="unknown detection method"):
        PipelineConfig(methods=("MRAD", "YOLO"))
    with pytest.raises(ProcessingError, match="render settings"):
        Pipeline(pipeline.provider, PipelineConfig())
    with pytest.raises(RenderSettingsError, match="reference_scale"):
        RenderSettings(reference_scale=0.0)


def test_sun_disc_is_added_to_the_reference_only_when_in_view(renderers):
    _, pipeline = renderers
    reference_renderer = pipeline.provider.renderer
    sun = np.array([0.2, -0.3, 0.93])
    sun /= np.linalg.norm(sun)
    eye = 100.0 * sun  # outside the station, on its sunny side
    towards_sun = look_at(eye, 200.0 * sun, up=(1.0, 0.0, 0.0))
    reference = pipeline.render(View(towards_sun, sun))
    assert reference[87:93, 157:163].max() > 200  # the disc (about 1 px radius here), ahead
    rendered = reference_renderer.render(towards_sun, sun, bodies=with_sun([], sun))
    assert rendered.bodies_in_view == ("sun",)
    away = look_at(eye, [0.0, 0.0, 0.0], up=(1.0, 0.0, 0.0))
    assert reference_renderer.render(away, sun, bodies=with_sun([], sun)).bodies_in_view == ()
    assert [b.name for b in with_sun([], sun)] == ["sun"]
    given = [("sun", (1.0, 0.0, 0.0), 5.0)]
    assert [(b.name, b.centre, b.radius) for b in with_sun(given, sun)] == given


def test_a_new_config_swaps_the_pipeline_and_leaves_the_old_one_as_it_was(renderers, pose):
    camera, first = renderers
    image = camera.render(pose, SUN).rgb
    coarse = first.config.replace(params=first.config.params.replace(grid=2))
    second = first.with_config(coarse)
    assert second.provider is first.provider and first.config.params.grid == MradParams().grid
    reference = first.render(View(pose, SUN))
    one = first.process(image, View(pose, SUN), reference=reference).primary
    two = second.process(image, View(pose, SUN), reference=reference).primary
    again = first.process(image, View(pose, SUN), reference=reference).primary
    np.testing.assert_array_equal(one.score, again.score)
    assert second.config.params.grid == 2 and two.score.shape == one.score.shape


def test_a_frame_names_the_camera_its_reference_was_rendered_for(renderers, pose):
    camera, pipeline = renderers
    image = camera.render(pose, SUN).rgb
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
    mapped = processor.detect(pair.query, reference).results["MRAD"]
    unmapped = processor.detect(pair.query, reference, score_map=False).results["MRAD"]
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
    mapped = processor.detect(pair.query, pair.reference).results["MRAD"]
    unmapped = processor.detect(pair.query, pair.reference, score_map=False).results["MRAD"]
    assert unmapped.image_score == mapped.image_score


@pytest.mark.parametrize("backend", ARRAY_BACKENDS)
def test_every_array_backend_finds_the_same_object_as_numpy(renderers, pose, backend):
    skip_unless_runnable(backend)
    camera, pipeline = renderers
    box = trimesh.creation.box((1.2, 1.2, 1.2))
    box.visual.face_colors = (230, 180, 40, 255)
    object_pose = pose.copy()
    object_pose[:3, 3] = pose[:3, 3] + 8.0 * pose[:3, 2] + 0.8 * pose[:3, 0] - 2.5 * pose[:3, 1]
    frame = camera.render(pose, SUN, extra_objects=[ExtraObject(box, object_pose)])
    methods = ("MRAD", "PAD", "RXD")
    base = pipeline.config.replace(methods=methods)
    reference = pipeline.render(View(pose, SUN))
    view = View(pose, SUN)
    expected = pipeline.with_config(base).process(frame.rgb, view, reference=reference)
    config = base.replace(array_backend=backend)
    found = pipeline.with_config(config).process(frame.rgb, view, reference=reference)
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


def test_open_renders_as_the_config_says_and_closing_releases_the_renderer(pose):
    config = PipelineConfig(RenderSettings(0.25, shadows=False), profile("paper"))
    with Pipeline.open(INTRINSICS, config=config) as pipeline:
        assert pipeline.config is config and pipeline.provider.settings == config.render
        reference = pipeline.render(View(pose, SUN))
        assert reference.shape == (90, 160, 3)
        renderer = pipeline.provider.renderer
    with pytest.raises(RendererError, match="closed"):
        renderer.render(pose, SUN)
    pipeline.close()  # a second close is harmless


def test_open_takes_the_package_model_and_the_default_config():
    with Pipeline.open(INTRINSICS) as pipeline:
        assert pipeline.config == PipelineConfig()
        assert pipeline.provider.renderer.triangle_count > 0


def test_detect_returns_a_processed_frame_as_process_does(renderers, pose):
    camera, pipeline = renderers
    image = camera.render(pose, SUN).rgb
    reference = pipeline.render(View(pose, SUN))
    detected = pipeline.detect(image, reference)
    processed = pipeline.process(image, View(pose, SUN), reference=reference)
    assert isinstance(detected, ProcessedFrame) and detected.reference is reference
    assert detected.reference_camera is None and detected.timings_ms["render"] == 0.0
    assert list(detected.results) == list(processed.results) == ["MRAD"]
    np.testing.assert_array_equal(detected.primary.mask, processed.primary.mask)
    np.testing.assert_array_equal(detected.primary.score, processed.primary.score)
    assert detected.timings_ms["total"] >= detected.timings_ms["MRAD"] > 0
    # A reference rendered apart (the node's render thread) takes its time and camera.
    rendered = detected.with_render(5.0, INTRINSICS.scaled(0.5))
    assert rendered.timings_ms["render"] == 5.0 and rendered.reference_camera.width == 320
    assert rendered.timings_ms["total"] == 5.0 + detected.timings_ms["MRAD"]


def test_process_tells_the_detector_where_the_sun_is(renderers):
    _, pipeline = renderers
    sun = np.array([0.2, -0.3, 0.93])
    sun /= np.linalg.norm(sun)
    eye = 100.0 * sun  # outside the station, on its sunny side, looking at the Sun
    view = View(look_at(eye, 200.0 * sun, up=(1.0, 0.0, 0.0)), sun)
    reference = pipeline.render(view)
    # The camera clips the Sun and blooms it far beyond the disc the reference draws.
    image = np.zeros((INTRINSICS.height, INTRINSICS.width, 3), np.uint8)
    centre = tuple(round(v) for v in view.sun_pixel(INTRINSICS))
    assert centre == (320, 180)
    cv2.circle(image, centre, 40, (150, 150, 150), -1)
    cv2.circle(image, centre, 12, (255, 255, 255), -1)
    params = pipeline.config.params
    assert params.sun_glare > 0  # the default
    glare = pipeline.with_config(pipeline.config.replace(params=params.replace(sun_glare=4.0)))
    blind = pipeline.with_config(pipeline.config.replace(params=params.replace(sun_glare=0.0)))
    assert blind.process(image, view, reference=reference).primary.anomalous
    assert not glare.process(image, view, reference=reference).primary.anomalous
    assert not pipeline.process(image, view, reference=reference).primary.anomalous
    # Without the view, detect() cannot place the Sun: the glare is an anomaly.
    assert glare.detect(image, reference).primary.anomalous
    assert not glare.detect(image, reference, view=view).primary.anomalous


def test_options_are_keyword_only(renderers, pose):
    camera, pipeline = renderers
    image = camera.render(pose, SUN).rgb
    reference = pipeline.render(View(pose, SUN))
    with pytest.raises(TypeError):
        pipeline.process(image, View(pose, SUN), reference)
    with pytest.raises(TypeError):
        pipeline.detect(image, reference, False)
    with pytest.raises(TypeError):
        pipeline.render(View(pose, SUN), 0.0)
    with pytest.raises(TypeError):
        Pipeline.open(INTRINSICS, None)
