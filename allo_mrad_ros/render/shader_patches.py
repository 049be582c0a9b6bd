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

The material patch (:func:`install_material_shader`) is of another kind: it changes what is
drawn, to what glTF's metallic-roughness material says, and is installed on every renderer.
pyrender 1.0.1's ``mesh.frag`` reads every texture, but

* scales neither the normal map (``normalTexture.scale``) nor builds its frame from the
  vertex tangents it is given (it tests a define no one sets, ``HAS_TANGENTS``);
* multiplies all light, direct and ambient, by the occlusion map, with no ``strength``
  (glTF's occlusion darkens only the light that does not come from the scene's lights);
* adds the emissive texture times the emissive factor squared;
* ignores ``alphaMode`` MASK (no cut-outs: a texel below ``alphaCutoff`` is drawn).

A material without those textures, and not MASK, computes the same pixels as before (only
the emissive factor is no longer squared).
"""

from __future__ import annotations

import logging
import re
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

from allo_mrad_ros.render.meshes import NORMAL_SCALE, OCCLUSION_STRENGTH
from allo_mrad_ros.render.uniforms import patch_each_program

_LOG = logging.getLogger(__name__)

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


def _wrap_loader(program: Any, marker: str, wrap: Callable[[Callable], Callable]) -> None:
    """Replace ``program._load`` by ``wrap(load)`` once per ``marker`` (patches compose)."""
    if program.__dict__.get(marker):
        return
    program._load = wrap(program._load)
    setattr(program, marker, True)


def install_shadow_filter(offscreen: object) -> None:
    """Load every ``mesh.frag`` this renderer compiles with :func:`shared_read_pcf`."""

    def wrap(load: Callable[[str], str]) -> Callable[[str], str]:
        def load_patched(filename: str) -> str:
            text = load(filename)
            return shared_read_pcf(text) if filename.endswith("mesh.frag") else text

        return load_patched

    patch_each_program(offscreen, lambda program: _wrap_loader(program, "_allo_pcf", wrap))


# (pyrender 1.0.1's text, the glTF text), applied to mesh.frag before pyrender's own
# preprocessing (which turns ``#ifdef`` into ``#if 1``/``#if 0`` and defines into values).
_MATERIAL_EDITS: tuple[tuple[str, str], ...] = (
    (
        "struct Material {\n    vec3 emissive_factor;\n",
        "struct Material {\n    vec3 emissive_factor;\n"
        "    float normal_scale;\n    float occlusion_strength;\n    float alpha_cutoff;\n",
    ),
    # The frame from the vertex tangents when the primitive has them (TANGENT_LOC).
    ("#ifndef HAS_TANGENTS\n", "#ifndef TANGENT_LOC\n"),
    (
        "n = normalize(tbn_n * ((2.0 * n - 1.0) * vec3(1.0, 1.0, 1.0)));",
        "n = normalize(tbn_n * ((2.0 * n - 1.0) * "
        "vec3(material.normal_scale, material.normal_scale, 1.0)));",
    ),
    (
        "    float ao = texture(material.occlusion_texture, uv_0).r;\n    color.xyz *= ao;\n",
        "    float ao = texture(material.occlusion_texture, uv_0).r;\n"
        "    color.xyz -= base_color.xyz * ambient_light\n"
        "        * (1.0 - mix(1.0, ao, material.occlusion_strength));\n",
    ),
    ("    color.xyz += emissive * material.emissive_factor;\n", "    color.xyz += emissive;\n"),
    (
        "    frag_color = clamp(vec4(pow(color.xyz, vec3(1.0/2.2)), color.a * base_color.a), "
        "0.0, 1.0);\n",
        "#ifdef ALPHA_MASK\n"
        "    if (color.a * base_color.a < material.alpha_cutoff) {\n"
        "        discard;\n"
        "    }\n"
        "    frag_color = clamp(vec4(pow(color.xyz, vec3(1.0/2.2)), 1.0), 0.0, 1.0);\n"
        "#else\n"
        "    frag_color = clamp(vec4(pow(color.xyz, vec3(1.0/2.2)), color.a * base_color.a), "
        "0.0, 1.0);\n"
        "#endif\n",
    ),
)
_WARNED_SHADER: list[str] = []


def gltf_material_shader(source: str) -> str | None:
    """``mesh.frag``'s text with glTF's material (see the module's notes), or None if the
    text is not pyrender 1.0.1's."""
    for old, _ in _MATERIAL_EDITS:
        if source.count(old) != 1:
            return None
    for old, new in _MATERIAL_EDITS:
        source = source.replace(old, new)
    return source


def _preprocess(text: str, defines: dict) -> str:
    """pyrender 1.0.1's ``ShaderProgram._load`` after reading the file: ``#ifdef``/``#ifndef``
    of the defines, then each define's name replaced by its value."""

    def ifdef(match: re.Match) -> str:
        return "#if 1" if match.group(1) in defines else "#if 0"

    def ifndef(match: re.Match) -> str:
        return "#if 0" if match.group(1) in defines else "#if 1"

    text = re.sub(r"#ifdef\s+([a-zA-Z_][a-zA-Z_0-9]*)\s*$", ifdef, text, flags=re.MULTILINE)
    text = re.sub(r"#ifndef\s+([a-zA-Z_][a-zA-Z_0-9]*)\s*$", ifndef, text, flags=re.MULTILINE)
    for name, value in defines.items():
        text = text.replace(name, str(value))
    return text


def install_material_shader(pr: ModuleType, offscreen: object) -> None:
    """Draw glTF's metallic-roughness material: the shader edits of :data:`_MATERIAL_EDITS`,
    the uniforms they read (from :mod:`.meshes`' material attributes), and a program of
    its own (define ``ALPHA_MASK``) for MASK materials, so that no other pays for the
    ``discard`` (which turns off a rasteriser's early depth test)."""
    renderer = getattr(offscreen, "_renderer", None)
    if renderer is None or not hasattr(renderer, "_bind_and_draw_primitive"):
        return

    def wrap(program: Any, load: Callable[[str], str]) -> Callable[[str], str]:
        def load_patched(filename: str) -> str:
            if not filename.endswith("mesh.frag"):
                return load(filename)
            patched = gltf_material_shader(Path(filename).read_text(encoding="utf-8"))
            if patched is None:
                if filename not in _WARNED_SHADER:
                    _WARNED_SHADER.append(filename)
                    _LOG.warning(
                        "%s is not pyrender 1.0.1's: glTF normal scale, occlusion strength "
                        "and alpha cut-outs are not drawn",
                        filename,
                    )
                return load(filename)
            return _preprocess(patched, program.defines or {})

        return load_patched

    patch_each_program(
        offscreen,
        lambda program: _wrap_loader(program, "_allo_material", lambda load: wrap(program, load)),
    )

    drawing: list[Any] = [None]  # the primitive whose program is being chosen
    choose_program = renderer._get_primitive_program
    cache = renderer._program_cache
    get_program = cache.get_program

    def get_primitive_program(primitive: Any, *args: Any, **kwargs: Any) -> Any:
        drawing[0] = primitive
        try:
            return choose_program(primitive, *args, **kwargs)
        finally:
            drawing[0] = None

    def get_program_with_mask(*args: Any, defines: dict | None = None, **kwargs: Any) -> Any:
        material = getattr(drawing[0], "material", None)
        if (
            defines is not None
            and "USE_METALLIC_MATERIAL" in defines
            and getattr(material, "alphaMode", None) == "MASK"
        ):
            defines = {**defines, "ALPHA_MASK": 1}
        return get_program(*args, defines=defines, **kwargs)

    renderer._get_primitive_program = get_primitive_program
    cache.get_program = get_program_with_mask

    bind_and_draw = renderer._bind_and_draw_primitive
    skip = pr.RenderFlags.DEPTH_ONLY | pr.RenderFlags.SEG

    def bind_and_draw_material(primitive: Any, pose: Any, program: Any, flags: int) -> None:
        material = primitive.material
        if not flags & skip and isinstance(material, pr.MetallicRoughnessMaterial):
            if material.normalTexture is not None:
                program.set_uniform("material.normal_scale", getattr(material, NORMAL_SCALE, 1.0))
            if material.occlusionTexture is not None:
                strength = getattr(material, OCCLUSION_STRENGTH, 1.0)
                program.set_uniform("material.occlusion_strength", strength)
            if material.alphaMode == "MASK":
                program.set_uniform("material.alpha_cutoff", float(material.alphaCutoff))
        bind_and_draw(primitive, pose, program, flags)

    renderer._bind_and_draw_primitive = bind_and_draw_material


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
