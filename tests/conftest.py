"""Shared fixtures. Taichi is initialised once per test session: a second ti.init()
would discard every compiled kernel."""
import textwrap
from pathlib import Path

import numpy as np
import pytest

from photonmc import load_scene, runtime

REPO = Path(__file__).resolve().parent.parent
SCENES = REPO / "scenes"
REFS = Path(__file__).resolve().parent / "refs"

# Every bundled scene but the gap-lit room (its own tests) with its Mitsuba reference in refs/
# and the scene parameters that give the reference's resolution.
SCENE_REFERENCES = [
    ("cornell-box", "cornell-box-64.exr", {"res": 64}),
    ("mitsuba-style", "mitsuba-style-80x60.exr", {"resx": 80, "resy": 60}),
    ("mesh-room", "mesh-room-64.exr", {"res": 64}),
    ("caustic", "caustic-64.exr", {"res": 64}),
]


def half_resolution(params: dict) -> dict:
    """The same scene at half the reference's resolution: a box-filtered image's mean does not
    depend on the resolution, and a quarter of the pixels is a quarter of the work."""
    return {k: v // 2 for k, v in params.items()}


@pytest.fixture(scope="session", autouse=True)
def taichi_cpu():
    runtime.init("cpu")


def camera_xml(res=16, fov=60.0, origin="0,0,0", target="0,0,-1", up="0,1,0", extra=""):
    return f"""
    <sensor type="perspective">
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="{origin}" target="{target}" up="{up}"/></transform>
        <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/>
            <rfilter type="box"/></film>
        {extra}
    </sensor>"""


@pytest.fixture
def write_scene(tmp_path):
    """Write an XML scene (body inside <scene>) plus optional extra files; returns its path."""
    def write(body: str, files: dict | None = None, name="scene.xml"):
        for fname, content in (files or {}).items():
            p = tmp_path / fname
            p.write_bytes(content if isinstance(content, bytes) else content.encode())
        path = tmp_path / name
        path.write_text(f'<scene version="3.0.0">\n{textwrap.dedent(body)}\n</scene>\n')
        return path
    return write


def scaled_box_scene(write_scene, scale=1.0, radiance_scale=1.0):
    """A small closed box with a glass sphere (a caustic) and a ceiling light."""
    s = scale
    return load_scene(write_scene(camera_xml(res=12, fov=70, origin=f"0,0,{2.5 * s}", target="0,0,0") + f"""
        <shape type="cube"><boolean name="flip_normals" value="true"/>
            <transform name="to_world"><scale x="{s}" y="{s}" z="{3 * s}"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.6,0.5,0.4"/></bsdf></shape>
        <shape type="sphere"><float name="radius" value="{0.4 * s}"/><point name="center" x="0" y="{-0.5 * s}" z="0"/>
            <bsdf type="dielectric"/></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="{0.3 * s}"/><rotate x="1" angle="90"/>
            <translate y="{0.99 * s}"/></transform>
            <emitter type="area"><rgb name="radiance" value="{5 * radiance_scale}"/></emitter></shape>"""))


def assert_image_follows_the_units(render_image, write_scene):
    """The box of scaled_box_scene scaled by 1e-3 and 1e3 gives the same image (radii,
    offsets and grids scale with the scene), and its emitter's radiance x1e-6 and x1e6 scales
    the image linearly (fixed-point films and the chains' first-pass constants are relative
    to the brightest emitter): a model in millimetres or kilometres, in watts or kilowatts,
    renders alike. render_image(scene) -> image, with a fixed seed."""
    from photonmc.metrics import downsample, luminance
    base = render_image(scaled_box_scene(write_scene))
    assert base.mean() > 0
    for scale in (1e-3, 1e3):
        img = render_image(scaled_box_scene(write_scene, scale=scale))
        assert abs(img.mean() / base.mean() - 1) < 0.03, scale
        assert np.abs(downsample(luminance(img), 4) - downsample(luminance(base), 4)).max() \
            < 0.25 * luminance(base).mean(), scale
    for k in (1e-6, 1e6):
        img = render_image(scaled_box_scene(write_scene, radiance_scale=k))
        np.testing.assert_allclose(img / k, base, rtol=1e-3, atol=1e-6 * base.max(), err_msg=f"radiance x{k}")


def slit_band(ref_luminance, margin=4):
    """Image columns around the slit: the columns brighter than 1.5x the image mean (the lit
    gap), widened by `margin` pixels on each side to cover its grazing-lit faces."""
    column = ref_luminance.mean(axis=0)
    bright = np.flatnonzero(column > 1.5 * column.mean())
    band = np.zeros(column.shape, bool)
    band[max(bright.min() - margin, 0):bright.max() + margin + 1] = True
    return band
