"""Benchmark of :class:`allo_mrad_ros.render.ReferenceRenderer` on the committed station model.

Times colour renders at the default reference scale (0.125: 240x135) and at 1920x1080, each
with directional shadows on and off (at the reference scale also with a Sun that moves every
frame, so the shadow map cannot be reused), plus the generator's mode (colour, depth and labels),
over a fixed set of viewpoints with the Sun, Earth and Moon in the scene. Prints median and
p95 per configuration and writes them to a JSON report. The default reference is also timed
against pyrender's own drawing (a renderer built in ``plain_pyrender()``, without the CPU
patches of ``render/uniforms.py`` and ``render/shader_patches.py``): the two renderers take
turns frame by frame in one process, so machine load weighs on both alike, and every pair of
images is compared.

Usage: ``python -m benchmarks.render --out reports/bench_render.json``
"""

from __future__ import annotations

import argparse
import inspect
import time
from pathlib import Path

import numpy as np

from allo_mrad_ros.camera import ALLO_INTRINSICS
from allo_mrad_ros.geometry import euler_zyx_to_matrix
from allo_mrad_ros.render import DEFAULT_SCALE, ReferenceRenderer
from allo_mrad_ros.render.gl_patches import plain_pyrender
from allo_mrad_ros.resources import share_path
from benchmarks import finish, machine_facts
from harness.scene import BODIES, SUN_CENTRE, viewpoints

# Reference render at the default scale must stay at or under this median.
TARGET_REF_MS = 40.0


def _summary(samples: list[float]) -> dict[str, float]:
    ms = np.asarray(samples) * 1000.0
    return {
        "ms_median": float(np.median(ms)),
        "ms_p95": float(np.percentile(ms, 95)),
        "frames": len(samples),
    }


def time_config(
    scale: float,
    shadows: bool,
    frames: int,
    warmup: int,
    backend: str | None,
    depth: bool = False,
    labels: bool = False,
    moving_sun: bool = False,
) -> dict:
    """Build one renderer and time ``frames`` renders cycling over :func:`viewpoints`.

    The Sun stays fixed, as within a stream (it moves about a degree a day), so the shadow
    map is drawn once and reused; ``moving_sun`` turns it by half a degree every frame, which
    forces a new shadow map each time (the cost for frames of unrelated days).
    """
    poses = viewpoints()
    start = time.perf_counter()
    with ReferenceRenderer(
        None, ALLO_INTRINSICS, scale=scale, shadows=shadows, backend=backend
    ) as renderer:
        init_s = time.perf_counter() - start
        for i in range(warmup):
            renderer.render(poses[i % len(poses)], SUN_CENTRE, bodies=BODIES)
        samples = []
        for i in range(frames):
            sun = SUN_CENTRE
            if moving_sun:
                sun = euler_zyx_to_matrix(0.0, 0.0, np.radians(0.5 * (i + 1))) @ SUN_CENTRE
            t0 = time.perf_counter()
            renderer.render(poses[i % len(poses)], sun, bodies=BODIES, depth=depth, labels=labels)
            samples.append(time.perf_counter() - t0)
        k = renderer.output_intrinsics
        info = {
            "size": [k.width, k.height],
            "shadows": shadows,
            "depth": depth,
            "labels": labels,
            "moving_sun": moving_sun,
            "init_ms": init_s * 1000.0,
            "triangles": renderer.triangle_count,
            "backend": renderer.backend,
        }
    return {**info, **_summary(samples)}


def time_patched_against_plain(scale: float, frames: int, warmup: int, backend: str | None) -> dict:
    """Time the default reference with and without the CPU patches, alternating per frame.

    Each frame is rendered by both renderers (which goes first alternates), timing wall
    clock and the process's CPU time (OpenGL's rasteriser threads included); the images of
    each pair are compared (the shadow filter of ``render/shader_patches.py`` may move a rare
    pixel by one grey level). The Sun turns by 10 degrees halfway through.
    """
    poses = viewpoints()
    turned_sun = euler_zyx_to_matrix(0.0, 0.0, np.radians(10.0)) @ SUN_CENTRE
    with plain_pyrender():
        plain = ReferenceRenderer(None, ALLO_INTRINSICS, scale=scale, backend=backend)
    patched = ReferenceRenderer(None, ALLO_INTRINSICS, scale=scale, backend=backend)
    renderers = {"plain": plain, "patched": patched}
    wall: dict[str, list[float]] = {name: [] for name in renderers}
    cpu: dict[str, list[float]] = {name: [] for name in renderers}
    unequal = unequal_pixels = max_diff = 0
    with plain, patched:
        for i in range(-warmup, frames):
            sun = SUN_CENTRE if i < frames // 2 else turned_sun
            images = {}
            order = ("plain", "patched") if i % 2 == 0 else ("patched", "plain")
            for name in order:
                t0, c0 = time.perf_counter(), time.process_time()
                images[name] = renderers[name].render(poses[i % len(poses)], sun, bodies=BODIES)
                if i >= 0:
                    wall[name].append(time.perf_counter() - t0)
                    cpu[name].append(time.process_time() - c0)
            if i >= 0:
                diff = np.abs(images["plain"].rgb.astype(np.int16) - images["patched"].rgb)
                unequal += bool(diff.any())
                unequal_pixels += int(np.count_nonzero(diff.max(axis=-1)))
                max_diff = max(max_diff, int(diff.max()))
    result = {
        name: {
            **_summary(wall[name]),
            "cpu_s_per_render": float(np.mean(cpu[name])),
            "cpu_s_median": float(np.median(cpu[name])),
        }
        for name in renderers
    }
    k = patched.output_intrinsics
    return {
        **result,
        "size": [k.width, k.height],
        "frames": frames,
        "frames_with_unequal_images": int(unequal),
        "unequal_pixels": unequal_pixels,
        "max_abs_difference": max_diff,
        "wall_ratio_median": result["patched"]["ms_median"] / result["plain"]["ms_median"],
        "cpu_ratio": result["patched"]["cpu_s_per_render"] / result["plain"]["cpu_s_per_render"],
    }


def run(
    frames: int, full_frames: int, warmup: int, reference_scale: float, backend: str | None
) -> dict:
    """Time every configuration and return the report."""
    paired = time_patched_against_plain(reference_scale, frames, warmup, backend)
    configs = {
        "ref_shadows": time_config(reference_scale, True, frames, warmup, backend),
        "ref_shadows_moving_sun": time_config(
            reference_scale, True, frames, warmup, backend, moving_sun=True
        ),
        "ref_no_shadows": time_config(reference_scale, False, frames, warmup, backend),
        "ref_shadows_depth_labels": time_config(
            reference_scale, True, frames, warmup, backend, depth=True, labels=True
        ),
        "full_shadows": time_config(1.0, True, full_frames, warmup, backend),
        "full_no_shadows": time_config(1.0, False, full_frames, warmup, backend),
    }
    model = share_path("meshes", "station.glb")
    # The headline figures are those of the renderer's default shadow setting.
    default_shadows = inspect.signature(ReferenceRenderer).parameters["shadows"].default
    default = "shadows" if default_shadows else "no_shadows"
    ref, full = configs[f"ref_{default}"], configs[f"full_{default}"]
    return {
        "reference_scale": reference_scale,
        "ref_size": ref["size"],
        "full_size": full["size"],
        "default_shadows": default_shadows,
        "ref_ms_median": ref["ms_median"],
        "ref_ms_p95": ref["ms_p95"],
        "full_ms_median": full["ms_median"],
        "full_ms_p95": full["ms_p95"],
        "target_ref_ms_median": TARGET_REF_MS,
        "ref_meets_target": ref["ms_median"] <= TARGET_REF_MS,
        "ref_patched_vs_plain_pyrender": paired,
        "configs": configs,
        "model": "meshes/station.glb",
        "model_bytes": model.stat().st_size,
        "triangles": ref["triangles"],
        "backend": ref["backend"],
        **machine_facts(),
    }


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark, print a table and write the JSON report."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("reports/bench_render.json"))
    parser.add_argument("--frames", type=int, default=60, help="timed frames per reference config")
    parser.add_argument("--full-frames", type=int, default=24, help="timed frames at 1920x1080")
    parser.add_argument("--warmup", type=int, default=3)
    parser.add_argument("--reference-scale", type=float, default=DEFAULT_SCALE)
    parser.add_argument("--backend", choices=("osmesa", "egl"), default=None)
    args = parser.parse_args(argv)
    if min(args.frames, args.full_frames) < 1 or args.warmup < 0:
        parser.error("--frames and --full-frames must be >= 1, --warmup >= 0")
    report = run(args.frames, args.full_frames, args.warmup, args.reference_scale, args.backend)
    print(
        f"station model: {report['triangles']} triangles, {report['model_bytes']} bytes; "
        f"backend {report['backend']}, {report['cpu_count']} CPUs"
    )
    print(f"{'configuration':<28}{'size':>11}{'median ms':>11}{'p95 ms':>9}{'init ms':>9}")
    for name, c in report["configs"].items():
        size = f"{c['size'][0]}x{c['size'][1]}"
        print(f"{name:<28}{size:>11}{c['ms_median']:>11.1f}{c['ms_p95']:>9.1f}{c['init_ms']:>9.0f}")
    paired = report["ref_patched_vs_plain_pyrender"]
    print(f"default reference, frames alternating between renderers ({paired['frames']} each):")
    for name in ("plain", "patched"):
        p = paired[name]
        print(
            f"  {name + ' pyrender' if name == 'plain' else 'patched':<16} median "
            f"{p['ms_median']:6.1f} ms  p95 {p['ms_p95']:6.1f} ms  "
            f"CPU {p['cpu_s_per_render']:.4f} s per render"
        )
    print(
        f"  patched/plain: median {paired['wall_ratio_median']:.2f}, "
        f"CPU {paired['cpu_ratio']:.2f}; "
        f"frames with unequal images: {paired['frames_with_unequal_images']} "
        f"({paired['unequal_pixels']} pixels, at most {paired['max_abs_difference']} grey levels)"
    )
    verdict = "meets" if report["ref_meets_target"] else "MISSES"
    shadows = "shadows" if report["default_shadows"] else "no shadows"
    print(
        f"reference render (scale {report['reference_scale']}, {shadows}): median "
        f"{report['ref_ms_median']:.1f} ms, {verdict} the {TARGET_REF_MS:.0f} ms target"
    )
    return finish(args.out, report)


if __name__ == "__main__":
    raise SystemExit(main())
