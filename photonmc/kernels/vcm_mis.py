"""Path vertices and the MIS bookkeeping of vertex connection and merging.

Georgiev, Krivanek, Davidovic, Slusallek 2012, "Light transport simulation with vertex
connection and merging", in the recursive form of Georgiev's technical report
"Implementing vertex connection and merging" (2012) and SmallVCM: each subpath carries three
partial sums (dvcm, dvc, dvm) from which the balance-heuristic weight of every technique that
could have made a full path is computed locally at the vertex that makes it. docs/vcm.md
writes the recursion out, with the sample counts and the measure of every pdf.

Conventions: every pdf includes the choice of the light and the Russian-roulette
continuation of the vertex it is sampled at (a property of the material alone,
`bsdf.continuation`); directional pdfs are per solid angle (`_w`), positional ones per area
(`_a`); cosines are with the shading normal. `MisConstants` are fixed for one iteration and
count every technique's samples relative to the connections' (one light subpath per camera
subpath in VCM): vm_weight = eta = pi r^2 N_L (0 without merging), vc_weight = 1/eta (0
without connections), n_light = N_L light subpaths (light tracing), camera_only = kappa, the
relative count of the two techniques that need no light subpath (emitter hits and next-event
estimation): 1 in VCM. mbe sets kappa = b_V, the chains' visible fraction: its light subpaths
have density 1/b_V on their support, which is the same as dividing every light-dependent
pdf by b_V (the "modified weights" of Sik et al. 2016, docs/mbe.md). kappa enters at the
light subpath's start (the terms there end in the camera-only techniques) and in the
camera-only techniques' own weights.
"""
import taichi as ti

from .sampling import vec3

SubpathMis = ti.types.struct(dvcm=ti.f32, dvc=ti.f32, dvm=ti.f32)
MisConstants = ti.types.struct(vm_weight=ti.f32, vc_weight=ti.f32, n_light=ti.f32, camera_only=ti.f32)
# A vertex of a light or camera subpath: where it is, how it is lit or seen, what it carries.
PathVertex = ti.types.struct(p=vec3, ng=vec3, n=vec3, wo=vec3, beta=vec3, length=ti.i32, bsdf=ti.i32,
                             dvcm=ti.f32, dvc=ti.f32, dvm=ti.f32)
COS_MIN = 1e-6            # grazing cosines would overflow the partial sums (1/cos)


@ti.func
def pdf_w_to_a(pdf_w: ti.f32, dist2: ti.f32, cos_there: ti.f32) -> ti.f32:
    """A solid-angle pdf at one vertex as an area pdf at the vertex it points to."""
    return pdf_w * ti.abs(cos_there) / dist2


@ti.func
def _safe_weight(w_light: ti.f32, w_camera: ti.f32) -> ti.f32:
    """1 / (w_light + 1 + w_camera), 0 where another technique's pdf overflowed."""
    total = w_light + 1.0 + w_camera
    w = 0.0
    if total < ti.math.inf:         # false for inf and NaN
        w = 1.0 / total
    return w


@ti.func
def light_start(direct_pdf_a: ti.f32, emission_pdf_w: ti.f32, cos_light: ti.f32, c):
    """Partial sums at the start of a light subpath (tech. report eqs. 31-33), the camera-only
    techniques they lead to counted kappa times."""
    m = SubpathMis(dvcm=c.camera_only * direct_pdf_a / emission_pdf_w, dvc=c.camera_only * cos_light / emission_pdf_w,
                   dvm=0.0)
    m.dvm = m.dvc * c.vc_weight
    return m


@ti.func
def camera_start(camera_pdf_w: ti.f32, c):
    """Partial sums at the camera: light tracing samples the first segment N_L times."""
    return SubpathMis(dvcm=c.n_light / camera_pdf_w, dvc=0.0, dvm=0.0)


@ti.func
def after_hit(m: ti.template(), dist2: ti.f32, cos_here: ti.f32):
    """Account for the segment just traced: its length and the cosine at the new vertex
    convert the previous vertex's solid-angle pdf to area (eqs. 34-36)."""
    cos = ti.max(ti.abs(cos_here), COS_MIN)
    m.dvcm *= dist2 / cos
    m.dvc /= cos
    m.dvm /= cos


@ti.func
def after_scatter(m: ti.template(), delta: ti.i32, cos_out: ti.f32, pdf_fwd_w: ti.f32, pdf_rev_w: ti.f32, c):
    """Account for the direction sampled at a vertex (pdfs including continuation).
    A delta lobe cannot be connected or merged at: only the cosine enters (eqs. 37-39)."""
    cos = ti.abs(cos_out)
    if delta:
        m.dvcm = 0.0
        m.dvc *= cos
        m.dvm *= cos
    else:
        dvc = cos / pdf_fwd_w * (m.dvc * pdf_rev_w + m.dvcm + c.vm_weight)
        dvm = cos / pdf_fwd_w * (m.dvm * pdf_rev_w + m.dvcm * c.vc_weight + 1.0)
        m.dvc = dvc
        m.dvm = dvm
        m.dvcm = 1.0 / pdf_fwd_w


@ti.func
def emitter_hit_weight(m, direct_pdf_a: ti.f32, emission_pdf_w: ti.f32, with_light_paths: ti.template(),
                       c) -> ti.f32:
    """A camera subpath that hit an emitter, against next-event estimation (direct_pdf_a) and
    the light-subpath techniques (emission_pdf_w), when those exist."""
    w_camera = direct_pdf_a * m.dvcm
    if ti.static(with_light_paths):
        w_camera += emission_pdf_w * m.dvc / c.camera_only
    return _safe_weight(0.0, w_camera)


@ti.func
def next_event_weight(m, direct_pdf_w: ti.f32, emission_pdf_w: ti.f32, cos_light: ti.f32, cos_to_light: ti.f32,
                      bsdf_fwd_w: ti.f32, bsdf_rev_w: ti.f32, c, with_light_paths: ti.template()) -> ti.f32:
    """Next-event estimation at a camera vertex against hitting the emitter by BSDF sampling
    (w_light) and against the techniques with more light vertices (w_camera)."""
    w_light = bsdf_fwd_w / direct_pdf_w
    w_camera = 0.0
    if ti.static(with_light_paths):
        w_camera = (emission_pdf_w * ti.abs(cos_to_light) / (direct_pdf_w * cos_light)) * \
            (c.vm_weight + m.dvcm + m.dvc * bsdf_rev_w) / c.camera_only
    return _safe_weight(w_light, w_camera)


@ti.func
def connection_weight(light, camera, camera_fwd_a: ti.f32, camera_rev_w: ti.f32, light_fwd_a: ti.f32,
                      light_rev_w: ti.f32, c) -> ti.f32:
    """Connecting a light vertex and a camera vertex. camera_fwd_a: the camera vertex's pdf of
    sampling the light vertex (area); camera_rev_w: its pdf toward its own predecessor given
    the connection; light_* likewise from the light vertex (eqs. 40-41)."""
    w_light = camera_fwd_a * (c.vm_weight + light.dvcm + light.dvc * light_rev_w)
    w_camera = light_fwd_a * (c.vm_weight + camera.dvcm + camera.dvc * camera_rev_w)
    return _safe_weight(w_light, w_camera)


@ti.func
def light_trace_weight(light, camera_pdf_a: ti.f32, light_rev_w: ti.f32, c) -> ti.f32:
    """A light vertex connected to the camera, against the camera-side techniques."""
    w_light = (camera_pdf_a / c.n_light) * (c.vm_weight + light.dvcm + light.dvc * light_rev_w)
    return _safe_weight(w_light, 0.0)


@ti.func
def merge_weight(light, camera, camera_fwd_w: ti.f32, camera_rev_w: ti.f32, c) -> ti.f32:
    """Merging a light vertex at a camera vertex: camera_fwd_w is the camera vertex's pdf of
    the light vertex's incoming direction, camera_rev_w the reverse (eqs. 38-39)."""
    w_light = light.dvcm * c.vc_weight + light.dvm * camera_fwd_w
    w_camera = camera.dvcm * c.vc_weight + camera.dvm * camera_rev_w
    return _safe_weight(w_light, w_camera)
