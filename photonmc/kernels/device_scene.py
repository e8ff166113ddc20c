"""The scene on the device: Taichi fields plus the @ti.func queries every method uses.

Built once per scene from the numpy Scene. Queries: closest hit and any hit along a ray
(BVH with an explicit stack, then analytic spheres), the surface record at a hit, emitter
sampling proportional to power, and camera rays. What the scene lacks is compiled out
with ti.static (no sphere loop without spheres, no glass code without glass).
"""

import math

import numpy as np
import taichi as ti

from ..errors import SceneError
from ..scene.bvh import build_bvh
from ..scene.scene import DIELECTRIC, Scene
from . import bsdf as bsdf_mod
from .fields import FieldGroup
from .sampling import INV_PI, cosine_hemisphere, onb, to_world, uniform_sphere, uniform_triangle, vec3
from ..taichi_frontend import data_oriented

Hit = ti.types.struct(t=ti.f32, kind=ti.i32, prim=ti.i32, b1=ti.f32, b2=ti.f32)
Surface = ti.types.struct(p=vec3, ng=vec3, ns=vec3, material=ti.i32, emitter=ti.i32, light_pdf_a=ti.f32,
                          tri=ti.i32)     # tri: the triangle hit (-1 for a sphere)
LightSample = ti.types.struct(p=vec3, n=vec3, radiance=vec3, pdf_a=ti.f32)
# Emitters for both directions (pdfs include the choice of the light; docs/vcm.md):
# an emitted ray for a light subpath, a point chosen toward a shading point (next-event
# estimation), and the pdfs of an emitter point that a camera path hit.
Emission = ti.types.struct(p=vec3, n=vec3, d=vec3, radiance=vec3, emission_pdf_w=ti.f32, direct_pdf_a=ti.f32,
                           cos_light=ti.f32)
Illumination = ti.types.struct(p=vec3, n=vec3, wi=vec3, dist=ti.f32, radiance=vec3, direct_pdf_w=ti.f32,
                               emission_pdf_w=ti.f32, cos_light=ti.f32)
EmitterHit = ti.types.struct(radiance=vec3, direct_pdf_a=ti.f32, emission_pdf_w=ti.f32)

MISS, TRIANGLE, SPHERE = -1, 0, 1
STACK_SIZE = 32     # the SAH build has depth ~18 at 80k triangles; deeper trees are refused
UNBOUNDED_DEPTH = 1 << 30


@data_oriented
class DeviceScene:
    def __init__(self, scene: Scene):
        self.scene = scene
        self.kinds = tuple(sorted(scene.bsdf_kinds()))
        self.has_triangles = len(scene.tri_vertices) > 0
        self.has_spheres = len(scene.sphere_radius) > 0
        self.n_spheres = len(scene.sphere_radius)
        self.max_depth = UNBOUNDED_DEPTH if scene.max_depth < 0 else int(scene.max_depth)
        lo, hi = scene.bounds
        # Ray offsets scale with the scene and with how far it sits from the origin,
        # since float32 round-off grows with coordinate magnitude.
        self.ray_eps = float(2e-5 * max(np.linalg.norm(hi - lo), np.abs(np.stack([lo, hi])).max()))
        self.extent = float(np.linalg.norm(hi - lo))
        # A kernels/raycast.RayLog here before the first kernel compiles records every ray
        # traced (tools/pt_stages.py); None compiles the recording out.
        self.ray_log = None
        self.fields = FieldGroup("scene")
        self._upload_geometry(scene)
        self._upload_materials(scene)
        self._upload_lights(scene)
        self._upload_camera(scene)
        self.fields.finalize()

    def release(self):
        """Free the device memory (and the SNode tree); the object is unusable afterwards."""
        self.fields.release()

    # -- upload ----------------------------------------------------------------------
    def _upload_geometry(self, scene: Scene):
        bvh = build_bvh(scene.tri_vertices)
        self.bvh = bvh
        order = bvh.prim_order
        v = scene.tri_vertices[order]
        n_tri = len(order)
        self.n_tri = n_tri
        # What the intersection test reads, stored per triangle (one cache line).
        self.tri_v0, self.tri_e1, self.tri_e2 = self.fields.interleaved(
            n_tri, [(3, ti.f32, v[:, 0]), (3, ti.f32, v[:, 1] - v[:, 0]), (3, ti.f32, v[:, 2] - v[:, 0])])
        nrm = scene.tri_normals[order]
        self.tri_n0 = self.fields.vector(3, ti.f32, n_tri, nrm[:, 0])
        self.tri_n1 = self.fields.vector(3, ti.f32, n_tri, nrm[:, 1])
        self.tri_n2 = self.fields.vector(3, ti.f32, n_tri, nrm[:, 2])
        self.tri_material = self.fields.scalar(ti.i32, n_tri, scene.tri_material[order])
        self.tri_emitter = self.fields.scalar(ti.i32, n_tri, scene.tri_emitter[order])
        self.tri_slot_of = np.empty(n_tri, np.int64)      # original triangle -> BVH slot
        self.tri_slot_of[order] = np.arange(n_tri)
        n_nodes = bvh.node_count
        self.node_min, self.node_max, self.node_right_or_first, self.node_count = self.fields.interleaved(
            n_nodes, [(3, ti.f32, bvh.bmin), (3, ti.f32, bvh.bmax), (None, ti.i32, bvh.right_or_first),
                      (None, ti.i32, bvh.count)])
        if bvh.depth > STACK_SIZE - 2:
            raise SceneError(f"{scene.path}: the BVH over {n_tri} triangles is {bvh.depth} levels deep, more than "
                             f"the traversal stack of {STACK_SIZE} holds (highly clustered geometry?)")
        ns = self.n_spheres
        self.sph_center = self.fields.vector(3, ti.f32, ns, scene.sphere_center)
        self.sph_radius = self.fields.scalar(ti.f32, ns, scene.sphere_radius)
        self.sph_flip = self.fields.scalar(ti.i32, ns, scene.sphere_flip.astype(np.int32))
        self.sph_material = self.fields.scalar(ti.i32, ns, scene.sphere_material)
        self.sph_emitter = self.fields.scalar(ti.i32, ns, scene.sphere_emitter)

    def _upload_materials(self, scene: Scene):
        nb = len(scene.bsdfs)
        self.bsdf_kind = self.fields.scalar(ti.i32, nb, [b.kind for b in scene.bsdfs])
        self.bsdf_color = self.fields.vector(3, ti.f32, nb, np.array([b.color for b in scene.bsdfs]))
        self.bsdf_trans = self.fields.vector(3, ti.f32, nb, np.array([b.transmittance for b in scene.bsdfs]))
        self.bsdf_eta = self.fields.scalar(ti.f32, nb, [b.eta for b in scene.bsdfs])
        self.mat_sides = self.fields.vector(2, ti.i32, len(scene.materials), scene.materials)

    def _upload_lights(self, scene: Scene):
        """Emitting primitives with a CDF proportional to power (luminance x area x pi)."""
        rad = scene.emitter_radiance
        kinds, prims, areas, lums = [], [], [], []
        tri_em = scene.tri_emitter
        if len(tri_em):
            idx = np.nonzero(tri_em >= 0)[0]
            kinds += [0] * len(idx)
            prims += list(self.tri_slot_of[idx])
            areas += list(scene.triangle_areas()[idx])
            lums += list(_lum(rad[tri_em[idx]]))
        for i, e in enumerate(scene.sphere_emitter):
            if e >= 0:
                kinds.append(1)
                prims.append(i)
                areas.append(4 * math.pi * scene.sphere_radius[i] ** 2)
                lums.append(_lum(rad[e][None])[0])
        areas = np.array(areas)
        power = np.array(lums) * areas * math.pi
        self.total_power = float(power.sum())
        pick = power / power.sum()
        cdf = np.cumsum(pick)
        cdf[-1] = 1.0
        n = len(kinds)
        self.n_lights = n
        self.light_kind = self.fields.scalar(ti.i32, n, kinds)
        self.light_prim = self.fields.scalar(ti.i32, n, prims)
        self.light_cdf = self.fields.scalar(ti.f32, n, cdf)
        self.light_area = self.fields.scalar(ti.f32, n, areas)
        self.light_pick = self.fields.scalar(ti.f32, n, pick)
        self.emitter_radiance = self.fields.vector(3, ti.f32, len(rad), rad)
        # pdf_a of each emitting primitive under light sampling, for MIS at emitter hits.
        tri_pdf = np.zeros(max(self.n_tri, 1))
        sph_pdf = np.zeros(max(self.n_spheres, 1))
        for k, p, a, w in zip(kinds, prims, areas, pick):
            (tri_pdf if k == 0 else sph_pdf)[p] = w / a
        self.tri_light_pdf = self.fields.scalar(ti.f32, self.n_tri, tri_pdf[: self.n_tri])
        self.sph_light_pdf = self.fields.scalar(ti.f32, self.n_spheres, sph_pdf[: self.n_spheres])

    def _upload_camera(self, scene: Scene):
        cam = scene.camera
        self.width, self.height = cam.width, cam.height
        self.cam_origin = ti.Vector(list(cam.origin.astype(float)))
        m = cam.to_world[:3, :3]
        self.cam_x = ti.Vector(list(m[:, 0]))
        self.cam_y = ti.Vector(list(m[:, 1]))
        self.cam_z = ti.Vector(list(m[:, 2]))
        self.tan_x, self.tan_y = cam.tan_half
        # For light tracing: world -> camera-local rows (to_world need not be orthonormal).
        # camera_ray samples uniformly the parallelogram {lx*x + ly*y + z}: a plane with unit
        # normal cam_forward at distance cam_plane_dist, cam_pixel_area per pixel.
        inv = np.linalg.inv(m)
        self.cam_inv0, self.cam_inv1, self.cam_inv2 = (ti.Vector(list(inv[k])) for k in range(3))
        cross = np.cross(m[:, 0], m[:, 1])
        normal = cross / np.linalg.norm(cross)
        if normal @ m[:, 2] < 0:
            normal = -normal
        self.cam_forward = ti.Vector(list(normal))
        self.cam_plane_dist = float(normal @ m[:, 2])
        self.cam_pixel_area = float(np.linalg.norm(cross) * (2.0 * self.tan_x / self.width)
                                    * (2.0 * self.tan_y / self.height))

    # -- ray queries -------------------------------------------------------------------
    @ti.func
    def _box_entry(self, node: ti.i32, o, inv_d, tmax: ti.f32) -> ti.f32:
        """Entry distance into a node's box, or +inf if the ray misses it before tmax."""
        t0 = (self.node_min[node] - o) * inv_d
        t1 = (self.node_max[node] - o) * inv_d
        tn = ti.min(t0, t1)
        tf = ti.max(t0, t1)
        t_enter = ti.max(ti.max(tn.x, tn.y), ti.max(tn.z, 0.0))
        t_exit = ti.min(ti.min(tf.x, tf.y), ti.min(tf.z, tmax))
        result = ti.math.inf
        if t_enter <= t_exit:
            result = t_enter
        return result

    @ti.func
    def _triangle(self, i: ti.i32, o, d, hit: ti.template()):
        """Moeller-Trumbore; updates `hit` if triangle i is closer."""
        e1 = self.tri_e1[i]
        e2 = self.tri_e2[i]
        pv = d.cross(e2)
        det = e1.dot(pv)
        if det != 0.0:
            inv_det = 1.0 / det
            tv = o - self.tri_v0[i]
            b1 = tv.dot(pv) * inv_det
            if b1 >= 0.0 and b1 <= 1.0:
                qv = tv.cross(e1)
                b2 = d.dot(qv) * inv_det
                if b2 >= 0.0 and b1 + b2 <= 1.0:
                    t = e2.dot(qv) * inv_det
                    if t > 0.0 and t < hit.t:
                        hit.t = t
                        hit.kind = TRIANGLE
                        hit.prim = i
                        hit.b1 = b1
                        hit.b2 = b2

    @ti.func
    def _leaf(self, first: ti.i32, count: ti.i32, o, d, hit: ti.template()):
        """A leaf's triangles first .. first + count - 1 (tools/bvh_wide_study.py overrides it
        to test them four at a time)."""
        for j in range(first, first + count):
            self._triangle(j, o, d, hit)

    @ti.func
    def _sphere(self, i: ti.i32, o, d, hit: ti.template()):
        """Ray-sphere with the numerically robust discriminant (Haines et al., RT Gems ch. 7)."""
        c = self.sph_center[i]
        r = self.sph_radius[i]
        f = o - c
        b = -f.dot(d)
        perp = f + b * d
        disc = r * r - perp.dot(perp)
        if disc >= 0.0:
            sq = ti.sqrt(disc)
            q = b + (sq if b >= 0.0 else -sq)
            t0 = f.dot(f) - r * r
            ta = q
            tb = 0.0
            if q != 0.0:
                tb = t0 / q
            tnear = ti.min(ta, tb)
            tfar = ti.max(ta, tb)
            t = tnear
            if t <= 0.0:
                t = tfar
            if t > 0.0 and t < hit.t:
                hit.t = t
                hit.kind = SPHERE
                hit.prim = i
                hit.b1 = 0.0
                hit.b2 = 0.0

    def _logs_rays(self) -> bool:
        return self.ray_log is not None

    @ti.func
    def trace(self, o, d, tmax: ti.f32, any_hit: ti.template()):
        """Closest hit (or, with any_hit, the first hit found) in (0, tmax)."""
        if ti.static(self._logs_rays()):
            self.ray_log.record(o, d, tmax, any_hit)
        hit = Hit(t=tmax, kind=MISS, prim=-1, b1=0.0, b2=0.0)
        if ti.static(self.has_triangles):
            dd = d
            for k in ti.static(range(3)):   # no zero components: keeps slab tests NaN-free
                if ti.abs(dd[k]) < 1e-30:
                    dd[k] = 1e-30
            inv_d = 1.0 / dd
            stack = ti.Vector([0] * STACK_SIZE, ti.i32)
            stack_t = ti.Vector([0.0] * STACK_SIZE, ti.f32)   # entry distance of each pushed node
            sp = 0
            node = 0
            if self._box_entry(0, o, inv_d, hit.t) == ti.math.inf:
                node = -1
            while node >= 0:
                count = self.node_count[node]
                if count > 0:
                    self._leaf(self.node_right_or_first[node], count, o, d, hit)
                    node = -1
                    if ti.static(any_hit):
                        if hit.kind != MISS:
                            sp = 0
                else:
                    left = node + 1
                    right = self.node_right_or_first[node]
                    tl = self._box_entry(left, o, inv_d, hit.t)
                    tr = self._box_entry(right, o, inv_d, hit.t)
                    node = -1
                    if tl == ti.math.inf and tr == ti.math.inf:
                        pass
                    elif tr == ti.math.inf:
                        node = left
                    elif tl == ti.math.inf:
                        node = right
                    elif tl <= tr:
                        stack[sp] = right
                        stack_t[sp] = tr
                        sp += 1
                        node = left
                    else:
                        stack[sp] = left
                        stack_t[sp] = tl
                        sp += 1
                        node = right
                # Next: pop the nearest pending node that may still hold a closer hit.
                while node < 0 and sp > 0:
                    sp -= 1
                    if stack_t[sp] < hit.t:
                        node = stack[sp]
        if ti.static(self.has_spheres):
            for i in range(self.n_spheres):
                self._sphere(i, o, d, hit)
        return hit

    @ti.func
    def occluded(self, o, d, dist: ti.f32) -> ti.i32:
        return self.trace(o, d, dist, True).kind != MISS

    @ti.func
    def visible(self, p, n_p, q, n_q) -> ti.i32:
        """Whether surface points p and q (normals n_p, n_q) see each other. Both ends are
        pushed off their surfaces toward the other and the ray is aimed between the pushed
        ends; aiming from a pushed origin along the unpushed direction would cross a surface
        seen at a grazing angle early by eps/cos and report it as its own occluder."""
        a = self.spawn(p, n_p, q - p)
        b = self.spawn(q, n_q, p - q)
        d = b - a
        dist = d.norm()
        result = 1
        if dist > 0.0:
            result = not self.occluded(a, d / dist, dist * (1.0 - 1e-4))
        return result

    @ti.func
    def _tri_shading_normal(self, i: ti.i32, b1: ti.f32, b2: ti.f32, fallback):
        """Interpolated vertex normal of triangle i at barycentrics (b1, b2)."""
        ns = (1.0 - b1 - b2) * self.tri_n0[i] + b1 * self.tri_n1[i] + b2 * self.tri_n2[i]
        length = ns.norm()
        result = fallback
        if length > 0.0:
            result = ns / length
        return result

    @ti.func
    def surface(self, o, d, hit):
        """Position, normals, material and emitter at a hit. The geometric normal is turned
        to the shading normal's side; sidedness (front/back) follows the shading normal."""
        s = Surface(p=vec3(0.0), ng=vec3(0.0, 0.0, 1.0), ns=vec3(0.0, 0.0, 1.0), material=0, emitter=-1,
                    light_pdf_a=0.0, tri=-1)
        if hit.kind == TRIANGLE:
            i = hit.prim
            e1 = self.tri_e1[i]
            e2 = self.tri_e2[i]
            s.p = self.tri_v0[i] + hit.b1 * e1 + hit.b2 * e2
            ng = e1.cross(e2).normalized()
            ns = self._tri_shading_normal(i, hit.b1, hit.b2, ng)
            if ng.dot(ns) < 0.0:
                ng = -ng
            s.ng = ng
            s.ns = ns
            s.material = self.tri_material[i]
            s.emitter = self.tri_emitter[i]
            s.light_pdf_a = self.tri_light_pdf[i]
            s.tri = i
        elif ti.static(self.has_spheres):
            if hit.kind == SPHERE:
                i = hit.prim
                c = self.sph_center[i]
                n = (o + hit.t * d - c).normalized()
                s.p = c + self.sph_radius[i] * n          # re-project onto the surface
                if self.sph_flip[i]:
                    n = -n
                s.ng = n
                s.ns = n
                s.material = self.sph_material[i]
                s.emitter = self.sph_emitter[i]
                s.light_pdf_a = self.sph_light_pdf[i]
        return s

    @ti.func
    def spawn(self, p, ng, d):
        """Origin for a ray leaving p in direction d, pushed off the surface on d's side."""
        off = self.ray_eps * ng
        if d.dot(ng) < 0.0:
            off = -off
        return p + off

    # -- materials ---------------------------------------------------------------------
    @ti.func
    def side_bsdf(self, material: ti.i32, ns, wo):
        """BSDF index seen from direction wo (-1: black) and the frame normal to use.
        Non-dielectric back sides are evaluated in the flipped frame, as Mitsuba's twosided."""
        sides = self.mat_sides[material]
        front = wo.dot(ns) > 0.0
        b = sides[0] if front else sides[1]
        n = ns
        if not front:
            if ti.static(DIELECTRIC in self.kinds):
                if b < 0 or self.bsdf_kind[b] != DIELECTRIC:
                    n = -ns
            else:
                n = -ns
        return b, n

    @ti.func
    def bsdf_sample(self, b: ti.i32, wo_local, u1, u2, u3, radiance_mode: ti.template()):
        return bsdf_mod.sample(self.kinds, self.bsdf_kind[b], self.bsdf_color[b], self.bsdf_trans[b],
                               self.bsdf_eta[b], wo_local, u1, u2, u3, radiance_mode)

    @ti.func
    def bsdf_is_delta(self, b: ti.i32) -> ti.i32:
        return bsdf_mod.is_delta(self.bsdf_kind[b])

    @ti.func
    def bsdf_evaluate(self, b: ti.i32, wo_local, wi_local):
        """f (no cosine) with the pdfs of wi given wo (forward) and wo given wi (reverse)."""
        return bsdf_mod.evaluate(self.kinds, self.bsdf_kind[b], self.bsdf_color[b], wo_local, wi_local)

    @ti.func
    def bsdf_continuation(self, b: ti.i32) -> ti.f32:
        return bsdf_mod.continuation(self.kinds, self.bsdf_kind[b], self.bsdf_color[b], self.bsdf_trans[b])

    # -- emitters ----------------------------------------------------------------------
    @ti.func
    def emitted(self, emitter: ti.i32, ns, wo):
        """Radiance leaving an area emitter toward wo (one-sided, along the normal)."""
        le = vec3(0.0)
        if emitter >= 0 and wo.dot(ns) > 0.0:
            le = self.emitter_radiance[emitter]
        return le

    @ti.func
    def sample_light(self, u0: ti.f32, u1: ti.f32, u2: ti.f32):
        """A point on an emitter, chosen by power then uniformly by area; pdf in area measure."""
        lo = 0
        hi = self.n_lights - 1
        while lo < hi:                    # first entry with cdf > u0
            mid = (lo + hi) // 2
            if self.light_cdf[mid] > u0:
                hi = mid
            else:
                lo = mid + 1
        ls = LightSample(p=vec3(0.0), n=vec3(0.0, 0.0, 1.0), radiance=vec3(0.0), pdf_a=0.0)
        prim = self.light_prim[lo]
        emitter = -1
        if self.light_kind[lo] == 0:
            b1, b2 = uniform_triangle(u1, u2)
            ls.p = self.tri_v0[prim] + b1 * self.tri_e1[prim] + b2 * self.tri_e2[prim]
            ls.n = self._tri_shading_normal(prim, b1, b2, self.tri_e1[prim].cross(self.tri_e2[prim]).normalized())
            emitter = self.tri_emitter[prim]
        elif ti.static(self.has_spheres):
            n = uniform_sphere(u1, u2)
            ls.p = self.sph_center[prim] + self.sph_radius[prim] * n
            if self.sph_flip[prim]:
                n = -n
            ls.n = n
            emitter = self.sph_emitter[prim]
        ls.radiance = self.emitter_radiance[emitter]
        ls.pdf_a = self.light_pick[lo] / self.light_area[lo]
        return ls

    @ti.func
    def emit(self, u0: ti.f32, u1: ti.f32, u2: ti.f32, u3: ti.f32, u4: ti.f32):
        """A ray leaving an emitter: point by power then area (u0..u2), direction cosine-
        weighted about the emitter's normal (u3, u4). emission_pdf_w = pdf_a * cos/pi."""
        ls = self.sample_light(u0, u1, u2)
        t1, t2 = onb(ls.n)
        local = cosine_hemisphere(u3, u4)
        e = Emission(p=ls.p, n=ls.n, d=to_world(local, t1, t2, ls.n), radiance=ls.radiance,
                     emission_pdf_w=ls.pdf_a * local.z * INV_PI, direct_pdf_a=ls.pdf_a, cos_light=local.z)
        return e

    @ti.func
    def illuminate(self, p, u0: ti.f32, u1: ti.f32, u2: ti.f32):
        """A point on an emitter for next-event estimation at p: direction, distance, the
        pdf of the point in solid angle at p, and the emission pdf of the reverse ray.
        radiance is zero where the emitter faces away from p."""
        ls = self.sample_light(u0, u1, u2)
        il = Illumination(p=ls.p, n=ls.n, wi=vec3(0.0, 0.0, 1.0), dist=0.0, radiance=vec3(0.0), direct_pdf_w=0.0,
                          emission_pdf_w=0.0, cos_light=0.0)
        to_l = ls.p - p
        dist2 = to_l.dot(to_l)
        if dist2 > 0.0:
            il.dist = ti.sqrt(dist2)
            il.wi = to_l / il.dist
            il.cos_light = -il.wi.dot(ls.n)
            if il.cos_light > 0.0:
                il.radiance = ls.radiance
                il.direct_pdf_w = ls.pdf_a * dist2 / il.cos_light
                il.emission_pdf_w = ls.pdf_a * il.cos_light * INV_PI
        return il

    @ti.func
    def emitter_hit(self, s, wo):
        """Radiance toward wo at a surface a camera path hit, with the pdfs other techniques
        would have sampled this emitter point with (area for NEE, emitted ray for light paths)."""
        eh = EmitterHit(radiance=self.emitted(s.emitter, s.ns, wo), direct_pdf_a=s.light_pdf_a, emission_pdf_w=0.0)
        eh.emission_pdf_w = s.light_pdf_a * ti.abs(s.ns.dot(wo)) * INV_PI
        return eh

    # -- camera ------------------------------------------------------------------------
    @ti.func
    def camera_ray(self, px: ti.i32, py: ti.i32, u1: ti.f32, u2: ti.f32):
        """Ray through film position (px+u1, py+u2); Mitsuba's orientation (+x local is left)."""
        sx = (px + u1) / self.width
        sy = (py + u2) / self.height
        local = vec3((1.0 - 2.0 * sx) * self.tan_x, (1.0 - 2.0 * sy) * self.tan_y, 1.0)
        d = (local.x * self.cam_x + local.y * self.cam_y + local.z * self.cam_z).normalized()
        return self.cam_origin, d

    @ti.func
    def camera_pdf_w(self, d) -> ti.f32:
        """Solid-angle density at the camera of direction d for one sample per pixel (the
        image-plane-to-solid-angle factor): 1 / (pixel area at unit distance * cos^3)."""
        cos = d.dot(self.cam_forward)
        pdf = 0.0
        if cos > 0.0:
            pdf = self.cam_plane_dist * self.cam_plane_dist / (self.cam_pixel_area * cos * cos * cos)
        return pdf

    @ti.func
    def camera_raster(self, p):
        """(ok, x, y): film position in pixels of the world point p seen by the camera,
        the inverse of camera_ray; ok is 0 behind the camera or outside the film."""
        v = p - self.cam_origin
        local = vec3(v.dot(self.cam_inv0), v.dot(self.cam_inv1), v.dot(self.cam_inv2))
        ok = 0
        x = 0.0
        y = 0.0
        if local.z > 0.0:
            x = 0.5 * (1.0 - local.x / (local.z * self.tan_x)) * self.width
            y = 0.5 * (1.0 - local.y / (local.z * self.tan_y)) * self.height
            if 0.0 <= x < self.width and 0.0 <= y < self.height:
                ok = 1
        return ok, x, y


def _lum(rgb):
    rgb = np.asarray(rgb, float)
    return np.maximum(rgb @ np.array([0.2126, 0.7152, 0.0722]), 1e-12)
