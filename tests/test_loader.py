"""The Mitsuba XML loader: every supported element, transforms against hand-computed
matrices, and every kind of bad input ending in a SceneError that names the problem."""
import math

import numpy as np
import pytest

from photonmc import SceneError, load_scene
from photonmc.scene.scene import CONDUCTOR, DIELECTRIC, DIFFUSE

from .conftest import camera_xml

LIGHT = """<shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1,2,3"/></emitter></shape>"""
TETRA_OBJ = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
QUAD_PLY = """ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
property float nx
property float ny
property float nz
element face 1
property list uchar int vertex_indices
end_header
0 0 0 0 0 1
1 0 0 0 0 1
1 1 0 0 0 1
0 1 0 0 0 1
4 0 1 2 3
"""


def scene_with(body, write_scene, files=None, cam=None):
    return write_scene((cam or camera_xml()) + LIGHT + body, files)


# -- supported elements ----------------------------------------------------------------------

def test_every_supported_shape_and_material(write_scene):
    body = """
    <bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.2, 0.4, 0.6"/></bsdf>
    <bsdf type="twosided" id="two"><bsdf type="diffuse"><float name="reflectance" value="0.3"/></bsdf></bsdf>
    <bsdf type="twosided" id="front-back">
        <ref id="white"/><bsdf type="conductor"><spectrum name="specular_reflectance" value="0.9"/></bsdf>
    </bsdf>
    <shape type="cube"><ref id="two"/></shape>
    <shape type="obj"><string name="filename" value="tetra.obj"/><ref name="bsdf" id="front-back"/></shape>
    <shape type="ply"><string name="filename" value="quad.ply"/><bsdf type="conductor"/></shape>
    <shape type="sphere">
        <point name="center" x="1" y="2" z="3"/><float name="radius" value="0.5"/>
        <transform name="to_world"><scale value="2"/><translate x="1"/></transform>
        <bsdf type="dielectric"><string name="int_ior" value="bk7"/><string name="ext_ior" value="air"/></bsdf>
    </shape>
    <shape type="sphere"><boolean name="flip_normals" value="true"/></shape>
    """
    s = load_scene(scene_with(body, write_scene, {"tetra.obj": TETRA_OBJ, "quad.ply": QUAD_PLY}))
    # rectangle (light) 2 + cube 12 + tetra 4 + quad 2 (split by trimesh)
    assert len(s.tri_vertices) == 2 + 12 + 4 + 2
    np.testing.assert_allclose(s.sphere_center[0], [3, 4, 6])          # scaled then translated
    assert s.sphere_radius[0] == pytest.approx(1.0)
    assert list(s.sphere_flip) == [False, True]
    kinds = [b.kind for b in s.bsdfs]
    assert kinds.count(DIFFUSE) >= 2 and CONDUCTOR in kinds and DIELECTRIC in kinds
    glass = next(b for b in s.bsdfs if b.kind == DIELECTRIC)
    assert glass.eta == pytest.approx(1.5046 / 1.00028)
    white = s.bsdfs[s.materials[s.tri_material[2 + 12]][0]]            # the tetra's front
    np.testing.assert_allclose(white.color, [0.2, 0.4, 0.6])
    back = s.bsdfs[s.materials[s.tri_material[2 + 12]][1]]
    assert back.kind == CONDUCTOR and back.color[0] == pytest.approx(0.9)
    two = s.materials[s.tri_material[2]]
    assert two[0] == two[1] and s.bsdfs[two[0]].color[0] == pytest.approx(0.3)
    one_sided = s.materials[s.sphere_material[1]]                          # default diffuse 0.5
    assert one_sided[1] == -1 and s.bsdfs[one_sided[0]].color[0] == pytest.approx(0.5)
    np.testing.assert_allclose(s.emitter_radiance, [[1, 2, 3]])
    assert s.tri_emitter[:2].tolist() == [0, 0] and (s.tri_emitter[2:] == -1).all()


def test_ply_normals_are_kept_and_obj_normals_recomputed(write_scene):
    s = load_scene(scene_with(
        '<shape type="ply"><string name="filename" value="quad.ply"/></shape>'
        '<shape type="obj"><string name="filename" value="tetra.obj"/></shape>'
        '<shape type="obj"><string name="filename" value="tetra.obj"/><boolean name="face_normals" value="true"/></shape>',
        write_scene, {"tetra.obj": TETRA_OBJ, "quad.ply": QUAD_PLY}))
    quad_n = s.tri_normals[2:4]
    np.testing.assert_allclose(quad_n.reshape(-1, 3), np.tile([0, 0, 1.0], (6, 1)))
    smooth = s.tri_normals[4:8]
    # The origin corner of the tetrahedron is shared by three faces at right angles with
    # equal corner angles: its angle-weighted normal is -(1,1,1)/sqrt(3).
    corner = smooth[0][0]
    np.testing.assert_allclose(corner, -np.ones(3) / math.sqrt(3), atol=1e-9)
    flat = s.tri_normals[8:12]
    assert np.allclose(flat[:, 0], flat[:, 1]) and np.allclose(flat[:, 1], flat[:, 2])


def test_flip_normals_reverses_winding_and_normals(write_scene):
    s = load_scene(scene_with('<shape type="rectangle"><boolean name="flip_normals" value="true"/></shape>',
                              write_scene))
    v = s.tri_vertices[2]
    n = np.cross(v[1] - v[0], v[2] - v[0])
    assert n[2] < 0 and np.allclose(s.tri_normals[2], [0, 0, -1])


@pytest.mark.parametrize("axis,width,height,tx,ty", [
    ("x", 200, 100, math.tan(math.radians(30)), math.tan(math.radians(30)) / 2),
    ("y", 200, 100, 2 * math.tan(math.radians(30)), math.tan(math.radians(30))),
    ("smaller", 200, 100, 2 * math.tan(math.radians(30)), math.tan(math.radians(30))),
    ("larger", 200, 100, math.tan(math.radians(30)), math.tan(math.radians(30)) / 2),
    ("diagonal", 300, 400, math.tan(math.radians(30)) * 3 / 5, math.tan(math.radians(30)) * 4 / 5),
])
def test_fov_axis(write_scene, axis, width, height, tx, ty):
    cam = f"""<sensor type="perspective"><float name="fov" value="60"/><string name="fov_axis" value="{axis}"/>
        <film type="hdrfilm"><integer name="width" value="{width}"/><integer name="height" value="{height}"/></film>
        </sensor>"""
    s = load_scene(scene_with("", write_scene, cam=cam))
    assert s.camera.tan_half == pytest.approx((tx, ty))
    assert (s.camera.width, s.camera.height) == (width, height)


def _camera_matrix(write_scene, steps):
    cam = f"""<sensor type="perspective"><float name="fov" value="45"/>
        <transform name="to_world">{steps}</transform></sensor>"""
    return load_scene(scene_with("", write_scene, cam=cam)).camera.to_world


def test_transforms_against_hand_computed_matrices(write_scene):
    m = _camera_matrix(write_scene, '<translate x="1" y="2" z="3"/>')
    np.testing.assert_allclose(m[:3, 3], [1, 2, 3])
    # +90 degrees about +y takes +x to -z (counter-clockwise looking down the axis).
    m = _camera_matrix(write_scene, '<rotate y="1" angle="90"/>')
    np.testing.assert_allclose(m[:3, :3] @ [1, 0, 0], [0, 0, -1], atol=1e-12)
    # Document order: scale first, then translate.
    m = _camera_matrix(write_scene, '<scale value="2"/><translate x="1"/>')
    np.testing.assert_allclose(m @ [1, 0, 0, 1], [3, 0, 0, 1])
    m = _camera_matrix(write_scene, '<translate x="1"/><scale value="2"/>')
    np.testing.assert_allclose(m @ [1, 0, 0, 1], [4, 0, 0, 1])
    m = _camera_matrix(write_scene, '<scale x="2" z="3"/>')
    np.testing.assert_allclose(np.diag(m), [2, 1, 3, 1])
    m = _camera_matrix(write_scene, '<matrix value="1 0 0 5  0 1 0 6  0 0 1 7  0 0 0 1"/>')
    np.testing.assert_allclose(m[:3, 3], [5, 6, 7])
    # Mitsuba 3 gives this camera-to-world matrix for the same lookat (checked with mitsuba 3.9).
    m = _camera_matrix(write_scene, '<lookat origin="0,0,5" target="0,0,0" up="0,1,0"/>')
    np.testing.assert_allclose(m, [[-1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 5], [0, 0, 0, 1]], atol=1e-12)


def test_defaults_and_parameter_overrides(write_scene):
    path = write_scene("""<default name="res" value="24"/><default name="depth" value="3"/>
        <integrator type="path"><integer name="max_depth" value="$depth"/></integrator>
        <sensor type="perspective"><float name="fov" value="45"/>
        <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/></film>
        </sensor>""" + LIGHT)
    s = load_scene(path)
    assert (s.camera.width, s.max_depth) == (24, 3)
    s = load_scene(path, {"res": 8})
    assert s.camera.width == 8


# -- bad input ------------------------------------------------------------------------------

BAD_CASES = {
    "malformed": ("<shape type='cube'>", {}, "malformed XML"),
    "unknown shape": ('<shape type="disk"/>', {}, "unsupported shape type 'disk'"),
    "unknown bsdf": ('<shape type="cube"><bsdf type="plastic"/></shape>', {}, "unsupported bsdf type 'plastic'"),
    "unknown element": ('<medium type="homogeneous"/>', {}, "unsupported element <medium"),
    "unknown parameter": ('<shape type="cube"><float name="radius" value="1"/></shape>', {},
                          "unsupported parameter 'radius'"),
    "texture": ('<shape type="cube"><bsdf type="diffuse"><texture type="bitmap" name="reflectance"/></bsdf></shape>',
                {}, "textures are not supported"),
    "missing mesh": ('<shape type="obj"><string name="filename" value="nope.obj"/></shape>', {},
                     "mesh file"),
    "nan vertex": ('<shape type="obj"><string name="filename" value="nan.obj"/></shape>',
                   {"nan.obj": "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n"}, "NaN"),
    "all degenerate": ('<shape type="obj"><string name="filename" value="flat.obj"/></shape>',
                       {"flat.obj": "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"}, "degenerate"),
    "zero radiance": ('<shape type="cube"><emitter type="area"><rgb name="radiance" value="0"/></emitter></shape>',
                      {}, "zero radiance"),
    "zero area light": ('<shape type="rectangle"><transform name="to_world"><scale x="0"/></transform>'
                        '<emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>', {}, "singular"),
    "wavelength spectrum": ('<shape type="cube"><bsdf type="diffuse"><spectrum name="reflectance" '
                            'value="400:0.1, 700:0.5"/></bsdf></shape>', {}, "wavelength"),
    "unset parameter": ('<shape type="sphere"><float name="radius" value="$r"/></shape>', {}, "'$r' has no value"),
    "unknown ref": ('<shape type="cube"><ref id="missing"/></shape>', {}, "unknown id 'missing'"),
    "negative radius": ('<shape type="sphere"><float name="radius" value="-1"/></shape>', {}, "radius"),
    "nonuniform sphere": ('<shape type="sphere"><transform name="to_world"><scale x="2"/></transform></shape>', {},
                          "non-uniformly"),
    "named conductor": ('<shape type="cube"><bsdf type="conductor"><string name="material" value="Au"/></bsdf></shape>',
                        {}, "conductor material 'Au'"),
    "env emitter": ('<emitter type="constant"/>', {}, "unsupported emitter type 'constant'"),
    "bad number": ('<shape type="sphere"><float name="radius" value="abc"/></shape>', {}, "not a list of numbers"),
    "mesh garbage": ('<shape type="ply"><string name="filename" value="g.ply"/></shape>', {"g.ply": "garbage"},
                     "cannot read mesh"),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_is_a_scene_error_naming_the_problem(write_scene, case):
    body, files, message = BAD_CASES[case]
    path = scene_with(body, write_scene, files)
    with pytest.raises(SceneError) as info:
        load_scene(path)
    text = str(info.value)
    assert message in text
    assert "\n" not in text
    assert str(path) in text or "mesh" in text


def test_scene_without_emitters_or_sensor(write_scene):
    with pytest.raises(SceneError, match="no emitters"):
        load_scene(write_scene(camera_xml() + '<shape type="cube"/>'))
    with pytest.raises(SceneError, match="no <sensor>"):
        load_scene(write_scene(LIGHT))
    with pytest.raises(SceneError, match="cannot read scene file"):
        load_scene("/nonexistent/scene.xml")


def test_bad_input_names_the_line(write_scene):
    path = write_scene(camera_xml() + LIGHT + '\n\n<shape type="disk"/>')
    with pytest.raises(SceneError) as info:
        load_scene(path)
    line = path.read_text().splitlines().index('<shape type="disk"/>') + 1
    assert f"{path}:{line}:" in str(info.value)


def test_some_degenerate_triangles_are_dropped_with_a_warning(write_scene):
    obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n"
    s = load_scene(scene_with('<shape type="obj"><string name="filename" value="m.obj"/></shape>',
                              write_scene, {"m.obj": obj}))
    assert len(s.tri_vertices) == 2 + 1
    assert any("dropped 1 degenerate" in w for w in s.warnings)


def test_emitter_without_bsdf_is_black_other_shapes_default_to_half(write_scene):
    """Mitsuba 3 gives emitting shapes a black diffuse and other shapes diffuse 0.5."""
    s = load_scene(scene_with('<shape type="cube"/>', write_scene))
    light = s.bsdfs[s.materials[s.tri_material[0]][0]]
    cube = s.bsdfs[s.materials[s.tri_material[2]][0]]
    assert light.color.max() == 0.0 and cube.color[0] == pytest.approx(0.5)


def test_rotate_axis_is_used_as_given(write_scene):
    """A non-unit axis scales and shears the points (Rodrigues with the raw axis), while
    normals are turned by the same matrix as for a pure rotation (both checked against
    mitsuba 3.9, which renders such files that way)."""
    s = load_scene(scene_with('<shape type="rectangle"><transform name="to_world">'
                              '<rotate x="1" y="1" angle="30"/></transform></shape>', write_scene))
    a, t = np.array([1.0, 1.0, 0.0]), math.radians(30)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    r = math.cos(t) * np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * np.outer(a, a)
    np.testing.assert_allclose(s.tri_vertices[2][0], r @ [-1, -1, 0], atol=1e-12)
    expected_n = r @ [0, 0, 1]
    np.testing.assert_allclose(s.tri_normals[2][0], expected_n / np.linalg.norm(expected_n), atol=1e-12)
    assert any("not unit length" in w for w in s.warnings)
