"""Next-event estimation against numerical integration, down to grazing light angles.

Found by comparing with Mitsuba: shadow rays from an offset origin aimed along the
unoffset direction met a tilted light early (eps/cos) and counted it as its own occluder,
darkening the floor up to 100 % where the light was seen at a grazing angle."""
import numpy as np
import taichi as ti

from photonmc import load_scene
from photonmc.kernels import rng
from photonmc.kernels.device_scene import DeviceScene
from photonmc.kernels.direct import next_event
from photonmc.kernels.sampling import onb, to_local, vec3

from .conftest import camera_xml

N = 40000


@ti.kernel
def nee_at(ds: ti.template(), px: ti.f32, out: ti.types.ndarray(dtype=vec3, ndim=1)):
    for i in range(out.shape[0]):
        state = rng.seed(ti.u32(1), ti.u32(i), ti.u32(0))
        p = vec3(px, 0.0, 0.0)
        n = vec3(0.0, 1.0, 0.0)
        t1, t2 = onb(n)
        out[i] = next_event(ds, p, n, 0, to_local(vec3(0.0, 0.6, 0.8), t1, t2, n), n, t1, t2, state, False)


def irradiance_integral(tris, p, n, nl, samples=200_000):
    total = 0.0
    u = np.random.default_rng(0).random((samples, 2))
    su = np.sqrt(u[:, 0])
    b1, b2 = 1 - su, u[:, 1] * su
    for t in tris:
        q = t[0] + b1[:, None] * (t[1] - t[0]) + b2[:, None] * (t[2] - t[0])
        area = 0.5 * np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0]))
        d = q - p
        dist = np.linalg.norm(d, axis=1)
        w = d / dist[:, None]
        total += np.mean(np.maximum(-(w @ nl), 0) * np.maximum(w @ n, 0) / dist ** 2) * area
    return total


def test_direct_light_from_a_tilted_light_down_to_grazing_angles(write_scene):
    """Floor points from under the light to where the light's plane is seen at about 5 deg."""
    scene = load_scene(write_scene(camera_xml() + """
        <shape type="rectangle"><transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/></transform>
            <bsdf type="diffuse"><float name="reflectance" value="0.5"/></bsdf></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="90"/>
            <rotate z="1" angle="-40"/><translate x="-2" y="3"/></transform>
            <emitter type="area"><rgb name="radiance" value="10"/></emitter></shape>"""))
    ds = DeviceScene(scene)
    light = scene.tri_vertices[scene.tri_emitter >= 0]
    nl = np.cross(light[0][1] - light[0][0], light[0][2] - light[0][0])
    nl /= np.linalg.norm(nl)
    out = np.zeros((N, 3), np.float32)
    for x in (-1.0, 0.0, 0.5, 1.0, 1.4):
        nee_at(ds, x, out)
        expected = 0.5 / np.pi * 10 * irradiance_integral(light, np.array([x, 0, 0.0]), np.array([0, 1.0, 0]), nl)
        estimate = out[:, 0].mean()
        se = out[:, 0].std() / np.sqrt(N)
        assert abs(estimate - expected) < 5 * se + 2e-3 * expected, (x, estimate, expected)
    ds.release()
