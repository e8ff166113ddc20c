"""BSDFs in the local shading frame (+z = shading normal), with Mitsuba 3's conventions.

`wo` points away from the surface toward where the path came from; `wi` is the sampled or
evaluated other direction. The bidirectional contract (docs/vcm.md):
- sample() returns weight = f*|cos wi|/pdf_fwd_w, the forward pdf (of wi given wo) and the
  reverse pdf (of wo given wi), both in solid angle, and whether the lobe is delta (a delta
  lobe's pdfs are the probability of choosing it, equal both ways);
- evaluate() returns f without the cosine (photon gathering needs exactly that) and both pdfs;
- continuation() is the Russian-roulette survival probability at a vertex: it depends on the
  material alone, never on the path, so a reverse pdf can include it.
Only `diffuse` has a non-delta lobe; conductor (mirror) and dielectric (smooth glass) are
pure delta lobes.

`kinds` is a static tuple of the BSDF kinds present in the scene, so a kernel for a scene
without glass carries no glass code.
"""
import taichi as ti

from ..scene.scene import CONDUCTOR, DIELECTRIC, DIFFUSE
from .sampling import INV_PI, cosine_hemisphere, vec3

BsdfSample = ti.types.struct(wi=vec3, weight=vec3, pdf_fwd_w=ti.f32, pdf_rev_w=ti.f32, delta=ti.i32, eta=ti.f32,
                             ok=ti.i32)
BsdfEval = ti.types.struct(f=vec3, pdf_fwd_w=ti.f32, pdf_rev_w=ti.f32)


@ti.func
def fresnel_dielectric(cos_i: ti.f32, eta: ti.f32):
    """Unpolarised Fresnel reflectance for relative IOR eta = n_inside/n_outside.

    Returns (R, cos_t, eta_it, eta_ti): cos_t carries the sign of the transmitted side."""
    outside = cos_i >= 0.0
    eta_it = eta if outside else 1.0 / eta
    eta_ti = 1.0 / eta_it
    cos_t_sqr = 1.0 - eta_ti * eta_ti * (1.0 - cos_i * cos_i)
    ci = ti.abs(cos_i)
    ct = ti.sqrt(ti.max(0.0, cos_t_sqr))
    r = 1.0
    if eta == 1.0:
        r = 0.0
    elif ci > 0.0 and cos_t_sqr > 0.0:
        a_s = (eta_it * ct - ci) / (eta_it * ct + ci)
        a_p = (eta_it * ci - ct) / (eta_it * ci + ct)
        r = 0.5 * (a_s * a_s + a_p * a_p)
    cos_t = -ct if cos_i >= 0.0 else ct
    return r, cos_t, eta_it, eta_ti


@ti.func
def sample(kinds: ti.template(), kind: ti.i32, color, transmittance, eta: ti.f32, wo,
           u1: ti.f32, u2: ti.f32, u3: ti.f32, radiance_mode: ti.template()):
    s = BsdfSample(wi=vec3(0.0), weight=vec3(0.0), pdf_fwd_w=0.0, pdf_rev_w=0.0, delta=0, eta=1.0, ok=0)
    if ti.static(DIFFUSE in kinds):
        if kind == DIFFUSE and wo.z > 0.0:
            s.wi = cosine_hemisphere(u1, u2)
            s.pdf_fwd_w = s.wi.z * INV_PI
            s.pdf_rev_w = wo.z * INV_PI
            if s.pdf_fwd_w > 0.0:
                s.weight = color
                s.ok = 1
    if ti.static(CONDUCTOR in kinds):
        if kind == CONDUCTOR and wo.z > 0.0:
            s.wi = vec3(-wo.x, -wo.y, wo.z)
            s.weight = color
            s.pdf_fwd_w = 1.0
            s.delta = 1
            s.ok = 1
    if ti.static(DIELECTRIC in kinds):
        if kind == DIELECTRIC and wo.z != 0.0:
            r, cos_t, eta_it, eta_ti = fresnel_dielectric(wo.z, eta)
            s.delta = 1
            s.ok = 1
            if u3 < r:
                s.wi = vec3(-wo.x, -wo.y, wo.z)
                s.pdf_fwd_w = r
                s.weight = color
            else:
                s.wi = vec3(-eta_ti * wo.x, -eta_ti * wo.y, cos_t)
                s.pdf_fwd_w = 1.0 - r
                s.eta = eta_it
                s.weight = transmittance
                if ti.static(radiance_mode):
                    # Radiance is compressed into the denser medium (Veach 1997, 5.2).
                    s.weight *= eta_ti * eta_ti
    if s.delta:
        s.pdf_rev_w = s.pdf_fwd_w        # the lobe's choice probability, the same both ways
    return s


@ti.func
def evaluate(kinds: ti.template(), kind: ti.i32, color, wo, wi):
    """f(wo, wi) of the non-delta lobes (no cosine), pdf of wi given wo and of wo given wi."""
    e = BsdfEval(f=vec3(0.0), pdf_fwd_w=0.0, pdf_rev_w=0.0)
    if ti.static(DIFFUSE in kinds):
        if kind == DIFFUSE and wo.z > 0.0 and wi.z > 0.0:
            e.f = color * INV_PI
            e.pdf_fwd_w = wi.z * INV_PI
            e.pdf_rev_w = wo.z * INV_PI
    return e


@ti.func
def continuation(kinds: ti.template(), kind: ti.i32, color, transmittance) -> ti.f32:
    """Russian-roulette survival probability at a vertex of this material (path-independent,
    as bidirectional MIS needs): the largest albedo component, at most 1 (SmallVCM's rule)."""
    q = ti.min(1.0, color.max())
    if ti.static(DIELECTRIC in kinds):
        if kind == DIELECTRIC:
            q = ti.min(1.0, ti.max(color.max(), transmittance.max()))
    return ti.max(q, 0.0)


@ti.func
def is_delta(kind: ti.i32) -> ti.i32:
    return kind != DIFFUSE
