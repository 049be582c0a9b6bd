"""Make pyrender's lit shader cheaper on a CPU rasteriser while computing the same pixels.

Under OSMesa (llvmpipe) the fragment shader is most of a reference render's cost, and two
things in pyrender's ``mesh.frag`` make it dearer than the scene needs:

* Light arrays are sized for the most lights pyrender allows: 26 shadowed Suns on llvmpipe
  (its texture units less six), 4 spots, 4 points, looped over with a uniform count, so every
  shadow-map read indexes a sampler array at run time. Sizing each array to the lights of
  that type in the scene (at least one; never above pyrender's limit) binds the same lights
  and runs the same arithmetic; only unused array slots go.
* The directional shadow's percentage-closer filter sums nine bilinear taps, one shadow-map
  texel apart, each comparing four texels: 36 reads of the 2048x2048 map for 16 distinct
  texels. The replacement reads each of the 16 once and forms the same nine bilinear mixes
  in the same order. With a power-of-two map every texel coordinate is exact in float, so it
  picks the same texels; the fractional weights are those of the centre tap, which for the
  others can differ from pyrender's only in float rounding. Measured against pyrender on the
  committed station (12 poses): 2 pixels off by one grey level in 432 frames at 240x135
  (36 Sun directions) and 2 in 24 frames at 1920x1080; the light limits change no pixel.

Both are installed per renderer; a shader text other than pyrender 1.0.1's is left as it is.
"""

from __future__ import annotations

import re

from allo_mrad_ros.render.uniforms import patch_each_program

_PCF_PYRENDER = re.compile(
    r"float PCF\(sampler2D depths, vec2 size, vec2 uv, float compare\)\{\n"
    r"    float result = 0\.0;\n"
    r"    for\(int x=-1; x<=1; x\+\+\)\{\n"
    r"        for\(int y=-1; y<=1; y\+\+\)\{\n"
    r"            vec2 off = vec2\(x,y\)/size;\n"
    r"            result \+= texture2DShadowLerp\(depths, size, uv\+off, compare\);\n"
    r"        \}\n"
    r"    \}\n"
    r"    return result/9\.0;\n"
    r"\}"
)
# Texels (i, j) of the 4x4 block around the centre tap's lower-left texel, i and j in -1..2.
_PCF_SHARED_READS = """float PCF(sampler2D depths, vec2 size, vec2 uv, float compare){
    vec2 texel = vec2(1.0)/size;
    vec2 centre = uv*size+0.5;
    vec2 f = fract(centre);
    vec2 lower_left = floor(centre)/size;
    float lit[16];
    for(int j=0; j<4; j++){
        for(int i=0; i<4; i++){
            lit[j*4+i] = texture2DCompare(depths, lower_left+texel*vec2(i-1, j-1), compare);
        }
    }
    float result = 0.0;
    for(int x=0; x<3; x++){
        for(int y=0; y<3; y++){
            float a = mix(lit[y*4+x], lit[(y+1)*4+x], f.y);
            float b = mix(lit[y*4+x+1], lit[(y+1)*4+x+1], f.y);
            result += mix(a, b, f.x);
        }
    }
    return result/9.0;
}"""


def shared_read_pcf(source: str) -> str:
    """Return fragment-shader text with pyrender's PCF replaced (unchanged if not found)."""
    return _PCF_PYRENDER.sub(lambda _: _PCF_SHARED_READS, source, count=1)


def install_shadow_filter(offscreen: object) -> None:
    """Load every ``mesh.frag`` this renderer compiles with :func:`shared_read_pcf`."""

    def patch_loader(program: object) -> None:
        if "_load" in program.__dict__:
            return
        load = program._load

        def load_patched(filename: str) -> str:
            text = load(filename)
            return shared_read_pcf(text) if filename.endswith("mesh.frag") else text

        program._load = load_patched

    patch_each_program(offscreen, patch_loader)


def install_light_limits(offscreen: object) -> None:
    """Size the shader's light arrays to the lights of the scene being rendered.

    pyrender binds ``min(lights of a type, limit)`` lights and compiles arrays of ``limit``;
    with ``limit`` lowered to ``max(1, lights of that type)`` (never raised) it binds the same
    lights. The texture-unit query behind pyrender's limits runs once per flags value.
    """
    renderer = getattr(offscreen, "_renderer", None)
    if renderer is None or not hasattr(renderer, "_compute_max_n_lights"):
        return
    compute = renderer._compute_max_n_lights
    render = renderer.render
    pyrender_limits: dict[int, list[int]] = {}
    scene_lights = [1, 1, 1]  # directional, spot, point: those of the scene now rendering

    def render_counting_lights(scene: object, flags: int, seg_node_map: object = None) -> object:
        scene_lights[:] = [
            len(scene.directional_light_nodes),
            len(scene.spot_light_nodes),
            len(scene.point_light_nodes),
        ]
        return render(scene, flags, seg_node_map)

    def max_n_lights(flags: int) -> list[int]:
        key = int(flags)
        if key not in pyrender_limits:
            pyrender_limits[key] = list(compute(flags))
        limits = pyrender_limits[key]
        return [min(limit, max(1, n)) for limit, n in zip(limits, scene_lights, strict=True)]

    renderer.render = render_counting_lights
    renderer._compute_max_n_lights = max_n_lights
