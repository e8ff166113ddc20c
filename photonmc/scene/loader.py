"""Interpreting the Mitsuba 3 plugin tree into a Scene.

What photonmc supports is listed here and nowhere else. Anything else - an unknown plugin,
an unknown parameter, a texture - is an error naming the element and its line, as Mitsuba
itself rejects unreferenced properties. Geometry and lights are validated so that a scene
that would render wrongly (NaN vertices, a light of zero area or zero power) is refused.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import SceneError
from . import shapes
from . import transform as tf
from .scene import CONDUCTOR, DIELECTRIC, DIFFUSE, Bsdf, Camera, Scene
from .xml import Plugin, Property, Ref, SceneXmlReader

# Mitsuba's table of named indices of refraction (used by `dielectric`).
NAMED_IOR = {
    "vacuum": 1.0, "helium": 1.00004, "hydrogen": 1.00013, "air": 1.00028,
    "carbon dioxide": 1.00045, "water": 1.3330, "acetone": 1.36, "ethanol": 1.361,
    "carbon tetrachloride": 1.461, "glycerol": 1.4729, "benzene": 1.501,
    "silicone oil": 1.52045, "bromine": 1.661, "water ice": 1.31, "fused quartz": 1.458,
    "pyrex": 1.470, "acrylic glass": 1.49, "polypropylene": 1.49, "bk7": 1.5046,
    "sodium chloride": 1.544, "amber": 1.55, "pet": 1.5750, "diamond": 2.419,
}
SUPPORTED = {
    "shape": ("obj", "ply", "rectangle", "cube", "sphere"),
    "bsdf": ("diffuse", "conductor", "dielectric", "twosided"),
    "emitter": ("area",),
    "sensor": ("perspective",),
    "film": ("hdrfilm",),
}
_REQUIRED = object()


class _Params:
    """Typed access to one plugin's properties; finish() rejects the ones nobody read."""

    def __init__(self, plugin: Plugin, file: str):
        self.plugin, self.file, self.used = plugin, file, set()

    def err(self, line, msg):
        return SceneError(f"{self.file}:{line}: {msg}")

    def _get(self, name, kinds, default):
        prop: Property | None = self.plugin.props.get(name)
        self.used.add(name)
        if prop is None:
            if default is _REQUIRED:
                raise self.err(self.plugin.line, f"<{self.plugin.tag} type=\"{self.plugin.type}\"> "
                                                 f"needs parameter '{name}'")
            return default
        if prop.kind not in kinds:
            raise self.err(prop.line, f"parameter '{name}' of <{self.plugin.tag} type=\"{self.plugin.type}\"> "
                                      f"must be {' or '.join(kinds)}, not <{prop.kind}>")
        return prop

    def value(self, name, kinds, default=_REQUIRED):
        p = self._get(name, kinds, default)
        return p.value if isinstance(p, Property) else p

    def number(self, name, default=_REQUIRED):
        v = self.value(name, ("float", "integer"), default)
        return None if v is None else float(v)

    def color(self, name, default=_REQUIRED):
        p = self._get(name, ("rgb", "spectrum", "float"), default)
        if not isinstance(p, Property):
            return np.full(3, float(p)) if np.isscalar(p) else np.asarray(p, float)
        v = np.full(3, p.value) if p.kind == "float" else np.asarray(p.value, float)
        if np.any(v < 0):
            raise self.err(p.line, f"parameter '{name}' is negative")
        return v

    def line_of(self, name):
        return self.plugin.props[name].line if name in self.plugin.props else self.plugin.line

    def finish(self, ignored=()):
        for name, prop in self.plugin.props.items():
            if name not in self.used and name not in ignored:
                raise self.err(prop.line, f"unsupported parameter '{name}' of "
                                          f"<{self.plugin.tag} type=\"{self.plugin.type}\">")


class _Builder:
    def __init__(self, reader: SceneXmlReader, root: Plugin):
        self.reader, self.root, self.file = reader, root, str(reader.path)
        self.base_dir = reader.path.parent
        self.bsdfs: list[Bsdf] = []
        self.materials: list[tuple] = []
        self._bsdf_cache: dict[int, tuple] = {}      # id(node) -> (node, sides)
        self.emitters: list[np.ndarray] = []
        self.tris = {"v": [], "n": [], "mat": [], "em": []}
        self.spheres = {"c": [], "r": [], "flip": [], "mat": [], "em": []}
        self.camera = None
        self.max_depth = -1
        self.warnings: list[str] = reader.warnings

    def err(self, line, msg):
        return SceneError(f"{self.file}:{line}: {msg}")

    def _check_type(self, node: Plugin):
        allowed = SUPPORTED.get(node.tag)
        if allowed is None:
            raise self.err(node.line, f"unsupported element <{node.tag} type=\"{node.type}\">")
        if node.type not in allowed:
            raise self.err(node.line, f"unsupported {node.tag} type '{node.type}' "
                                      f"(supported: {', '.join(allowed)})")

    def _resolve(self, child) -> Plugin:
        if isinstance(child, Ref):
            if child.id not in self.reader.ids:
                raise self.err(child.line, f"reference to unknown id '{child.id}'")
            return self.reader.ids[child.id]
        return child

    # -- top level --------------------------------------------------------------------
    def build(self) -> Scene:
        sensors = []
        for child in self.root.children:
            if isinstance(child, Ref):
                raise self.err(child.line, "a <ref> at scene level has no effect")
            if child.tag == "shape":
                self._shape(child)
            elif child.tag == "bsdf":
                self._material(child)        # validate even if unused, as Mitsuba does
            elif child.tag == "sensor":
                sensors.append(child)
            elif child.tag == "integrator":
                self._integrator(child)
            elif child.tag == "emitter":
                raise self.err(child.line, f"unsupported emitter type '{child.type}' at scene level "
                                           "(photonmc supports 'area' emitters attached to shapes)")
            else:
                raise self.err(child.line, f"unsupported element <{child.tag} type=\"{child.type}\">")
        if not sensors:
            raise SceneError(f"{self.file}: scene has no <sensor>")
        if len(sensors) > 1:
            raise self.err(sensors[1].line, "more than one <sensor>: photonmc renders one view")
        self.camera = self._sensor(sensors[0])
        if not self.tris["v"] and not self.spheres["c"]:
            raise SceneError(f"{self.file}: scene has no shapes")
        if not self.emitters:
            raise SceneError(f"{self.file}: scene has no emitters, the image would be black")

        t, s = self.tris, self.spheres
        return Scene(
            path=self.file, camera=self.camera, max_depth=self.max_depth, bsdfs=self.bsdfs,
            materials=np.array(self.materials, np.int32).reshape(-1, 2),
            emitter_radiance=np.array(self.emitters, float).reshape(-1, 3),
            tri_vertices=np.concatenate(t["v"]) if t["v"] else np.zeros((0, 3, 3)),
            tri_normals=np.concatenate(t["n"]) if t["n"] else np.zeros((0, 3, 3)),
            tri_material=np.concatenate(t["mat"]).astype(np.int32) if t["mat"] else np.zeros(0, np.int32),
            tri_emitter=np.concatenate(t["em"]).astype(np.int32) if t["em"] else np.zeros(0, np.int32),
            sphere_center=np.array(s["c"], float).reshape(-1, 3),
            sphere_radius=np.array(s["r"], float),
            sphere_flip=np.array(s["flip"], bool),
            sphere_material=np.array(s["mat"], np.int32),
            sphere_emitter=np.array(s["em"], np.int32),
            warnings=self.warnings,
        )

    def _integrator(self, node: Plugin):
        p = _Params(node, self.file)
        depth = p.value("max_depth", ("integer",), -1)
        if depth == 0 or depth < -1:
            raise self.err(p.line_of("max_depth"), f"max_depth must be -1 (unbounded) or >= 1, got {depth}")
        self.max_depth = depth
        p.value("rr_depth", ("integer",), 5)          # Russian roulette never changes the expectation
        if p.value("hide_emitters", ("boolean",), False):
            raise self.err(p.line_of("hide_emitters"), "hide_emitters=true is not supported")
        p.finish()
        for child in node.children:
            raise self.err(getattr(child, "line", node.line), "nested plugins in <integrator> are not supported")

    # -- sensor -----------------------------------------------------------------------
    def _sensor(self, node: Plugin) -> Camera:
        self._check_type(node)
        p = _Params(node, self.file)
        if "focal_length" in node.props:
            raise self.err(node.props["focal_length"].line, "focal_length is not supported: give 'fov'")
        fov = p.number("fov", None)
        if fov is None:
            raise self.err(node.line, "<sensor type=\"perspective\"> needs 'fov' (degrees)")
        if not 0 < fov < 180:
            raise self.err(p.line_of("fov"), f"fov must be between 0 and 180 degrees, got {fov}")
        axis = p.value("fov_axis", ("string",), "x")
        to_world = p.value("to_world", ("transform",), tf.Transform()).m
        if abs(np.linalg.det(to_world[:3, :3])) < 1e-12:
            raise self.err(p.line_of("to_world"), "sensor to_world is singular")
        p.number("near_clip", 0.01)     # clipping planes do not change what a closed scene shows
        p.number("far_clip", 1e4)
        for name in ("principal_point_offset_x", "principal_point_offset_y"):
            if p.number(name, 0.0) != 0.0:
                raise self.err(p.line_of(name), f"{name} is not supported")
        p.finish()
        width, height = 768, 576        # Mitsuba's hdrfilm defaults
        for child in node.children:
            child = self._resolve(child)
            if child.tag == "film":
                width, height = self._film(child)
            elif child.tag == "sampler":
                self._sampler(child)
            else:
                raise self.err(child.line, f"unsupported element <{child.tag}> in <sensor>")
        aspect = width / height
        t = np.tan(np.radians(fov) / 2)
        if axis == "smaller":
            axis = "x" if width < height else "y"
        elif axis == "larger":
            axis = "x" if width >= height else "y"
        if axis == "x":
            tx, ty = t, t / aspect
        elif axis == "y":
            tx, ty = t * aspect, t
        elif axis == "diagonal":
            d = np.hypot(width, height)
            tx, ty = t * width / d, t * height / d
        else:
            raise self.err(p.line_of("fov_axis"), f"fov_axis must be x, y, diagonal, smaller or larger, not '{axis}'")
        return Camera(to_world=to_world, tan_half=(float(tx), float(ty)), width=width, height=height)

    def _film(self, node: Plugin):
        self._check_type(node)
        p = _Params(node, self.file)
        width = p.value("width", ("integer",), 768)
        height = p.value("height", ("integer",), 576)
        for name in ("crop_offset_x", "crop_offset_y", "crop_width", "crop_height"):
            if name in node.props:
                raise self.err(node.props[name].line, f"film cropping ('{name}') is not supported")
        # Output-format options only affect Mitsuba's own file writing.
        p.finish(ignored=("pixel_format", "component_format", "file_format", "banner",
                          "sample_border", "compensate"))
        if not (1 <= width <= 16384 and 1 <= height <= 16384):
            raise self.err(node.line, f"film size {width}x{height} is outside 1..16384")
        for child in node.children:
            child = self._resolve(child)
            if child.tag != "rfilter":
                raise self.err(child.line, f"unsupported element <{child.tag}> in <film>")
            if child.type != "box":
                self.warnings.append(f"{self.file}:{child.line}: reconstruction filter '{child.type}' is "
                                     "rendered as a box filter (affects sharpness only)")
        return width, height

    def _sampler(self, node: Plugin):
        # The sampler only sets Mitsuba's noise pattern and sample count; photonmc's methods
        # choose their own samples, so its parameters are read and not used.
        pass

    # -- materials --------------------------------------------------------------------
    def _add_bsdf(self, b: Bsdf) -> int:
        self.bsdfs.append(b)
        return len(self.bsdfs) - 1

    def _bsdf_sides(self, node: Plugin, nested=False) -> tuple:
        """(front, back) BSDF indices for a bsdf plugin; -1 is black."""
        # Keyed by identity; the cache also holds the node, so that a temporary node (a shape's
        # default BSDF) is never freed and its id handed to a later one (which then got the
        # earlier shape's BSDF: an emitter's black default on the next plain shape).
        key = id(node)
        if key in self._bsdf_cache:
            return self._bsdf_cache[key][1]
        self._check_type(node)
        p = _Params(node, self.file)
        if node.type == "diffuse":
            i = self._add_bsdf(Bsdf(DIFFUSE, self._albedo(p, "reflectance", 0.5)))
            sides = (i, -1)
        elif node.type == "conductor":
            material = p.value("material", ("string",), "none")
            if material != "none":
                raise self.err(p.line_of("material"), f"conductor material '{material}' is not supported "
                                                      "(only material=\"none\", a perfect mirror, with specular_reflectance)")
            for name in ("eta", "k"):
                if name in node.props:
                    raise self.err(node.props[name].line, f"conductor '{name}' is not supported")
            i = self._add_bsdf(Bsdf(CONDUCTOR, self._albedo(p, "specular_reflectance", 1.0)))
            sides = (i, -1)
        elif node.type == "dielectric":
            if nested:
                raise self.err(node.line, "a dielectric inside twosided is not supported (it is two-sided already)")
            int_ior = self._ior(p, "int_ior", "bk7")
            ext_ior = self._ior(p, "ext_ior", "air")
            i = self._add_bsdf(Bsdf(DIELECTRIC, self._albedo(p, "specular_reflectance", 1.0),
                                    self._albedo(p, "specular_transmittance", 1.0), int_ior / ext_ior))
            sides = (i, i)
        else:  # twosided
            if nested:
                raise self.err(node.line, "twosided inside twosided is not supported")
            inner = [self._resolve(c) for c in node.children]
            if not 1 <= len(inner) <= 2 or any(c.tag != "bsdf" for c in inner):
                raise self.err(node.line, "twosided needs one or two nested <bsdf>")
            front = self._bsdf_sides(inner[0], nested=True)[0]
            back = self._bsdf_sides(inner[-1], nested=True)[0]
            sides = (front, back)
        p.finish()
        if node.type != "twosided":
            for c in node.children:
                c = self._resolve(c)
                raise self.err(c.line, f"unsupported <{c.tag} type=\"{c.type}\"> inside <bsdf> "
                                       "(textures are not supported)")
        self._bsdf_cache[key] = (node, sides)
        return sides

    def _albedo(self, p: _Params, name, default):
        if name in p.plugin.props and p.plugin.props[name].kind == "ref":
            raise self.err(p.line_of(name), f"'{name}' must be a constant colour (textures are not supported)")
        v = p.color(name, default)
        if np.any(v > 1.0):
            self.warnings.append(f"{self.file}:{p.line_of(name)}: '{name}' above 1 makes the surface reflect "
                                 "more light than it receives")
        return v

    def _ior(self, p: _Params, name, default):
        v = p.value(name, ("float", "string"), default)
        if isinstance(v, str):
            if v.lower() not in NAMED_IOR:
                raise self.err(p.line_of(name), f"unknown {name} '{v}'")
            v = NAMED_IOR[v.lower()]
        if not v > 0:
            raise self.err(p.line_of(name), f"{name} must be positive")
        return float(v)

    def _material(self, node: Plugin) -> int:
        sides = self._bsdf_sides(node)
        if sides not in self.materials:
            self.materials.append(sides)
        return self.materials.index(sides)

    # -- shapes -----------------------------------------------------------------------
    def _shape(self, node: Plugin):
        self._check_type(node)
        where = f"{self.file}:{node.line}"
        material = emitter = None
        for child in node.children:
            child = self._resolve(child)
            if child.tag == "bsdf":
                if material is not None:
                    raise self.err(child.line, "shape has more than one <bsdf>")
                material = self._material(child)
            elif child.tag == "emitter":
                if emitter is not None:
                    raise self.err(child.line, "shape has more than one <emitter>")
                emitter = self._area_emitter(child)
            else:
                raise self.err(child.line, f"unsupported <{child.tag} type=\"{child.type}\"> inside <shape>")
        if material is None:
            # Mitsuba's default BSDF is diffuse 0.5, but black (reflectance 0) on emitters.
            default = Plugin("bsdf", "diffuse", None, node.line, self.file)
            if emitter is not None:
                default.props["reflectance"] = Property("float", 0.0, node.line)
            material = self._material(default)
        p = _Params(node, self.file)
        xform = p.value("to_world", ("transform",), tf.Transform())
        to_world = xform.m
        flip = p.value("flip_normals", ("boolean",), False)
        if node.type == "sphere":
            self._sphere(node, p, to_world, flip, material, emitter)
            return
        if node.type == "rectangle":
            v, f, n = shapes.rectangle()
        elif node.type == "cube":
            v, f, n = shapes.cube()
        else:
            filename = p.value("filename", ("string",))
            v, f, n = shapes.load_mesh_file(self.base_dir / filename, node.type, where)
            if not np.all(np.isfinite(v)):
                raise SceneError(f"{where}: mesh '{filename}' has NaN or infinite vertex coordinates")
            if p.value("face_normals", ("boolean",), False):
                n = None
            elif n is None or not np.all(np.isfinite(n)):
                n = shapes.angle_weighted_normals(v, f)
        p.finish(ignored=("flip_tex_coords",))
        if abs(np.linalg.det(to_world[:3, :3])) < 1e-300:
            raise self.err(p.line_of("to_world"), "shape to_world is singular (zero scale?)")
        v = tf.apply_points(to_world, v)
        tri = v[f]
        if n is not None:
            n = xform.apply_normals(n)
        face_n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        area2 = np.linalg.norm(face_n, axis=1)
        scale = max(float(np.abs(v).max()), 1e-30)
        good = area2 > (1e-7 * scale) ** 2 * 1e-2
        if not np.any(good):
            raise SceneError(f"{where}: every triangle of this {node.type} is degenerate (zero area)")
        if not np.all(good):
            self.warnings.append(f"{where}: dropped {int((~good).sum())} degenerate (zero-area) triangles "
                                 f"of {len(good)}")
        tri, f, face_n = tri[good], f[good], face_n[good]
        face_n = face_n / np.linalg.norm(face_n, axis=1, keepdims=True)
        if n is None:
            corner_n = np.repeat(face_n[:, None, :], 3, axis=1)
        else:
            corner_n = n[f]
            bad = np.linalg.norm(corner_n, axis=2) < 0.5        # zero normals from the file
            corner_n = np.where(bad[..., None], face_n[:, None, :], corner_n)
        if flip:
            tri = tri[:, [0, 2, 1]]
            corner_n = -corner_n[:, [0, 2, 1]]
        count = len(tri)
        self.tris["v"].append(tri)
        self.tris["n"].append(corner_n)
        self.tris["mat"].append(np.full(count, material))
        self.tris["em"].append(np.full(count, -1 if emitter is None else emitter))

    def _sphere(self, node, p: _Params, to_world, flip, material, emitter):
        center = p.value("center", ("point",), np.zeros(3))
        radius = p.number("radius", 1.0)
        p.finish()
        lin = to_world[:3, :3]
        s = np.linalg.svd(lin, compute_uv=False)
        if s.max() - s.min() > 1e-6 * s.max():
            raise self.err(p.line_of("to_world"), "sphere to_world must not scale non-uniformly "
                                                  "(use an obj/ply mesh for ellipsoids)")
        center = tf.apply_points(to_world, np.asarray(center, float)[None])[0]
        radius = radius * s.max()
        if not (np.isfinite(radius) and radius > 0 and np.all(np.isfinite(center))):
            raise self.err(node.line, f"sphere radius must be positive and finite, got {radius}")
        self.spheres["c"].append(center)
        self.spheres["r"].append(radius)
        self.spheres["flip"].append(bool(flip) != bool(np.linalg.det(lin) < 0))
        self.spheres["mat"].append(material)
        self.spheres["em"].append(-1 if emitter is None else emitter)

    def _area_emitter(self, node: Plugin) -> int:
        self._check_type(node)
        p = _Params(node, self.file)
        radiance = p.color("radiance")
        p.finish()
        if not np.all(np.isfinite(radiance)):
            raise self.err(p.line_of("radiance"), "emitter radiance is not finite")
        if radiance.max() <= 0:
            raise self.err(p.line_of("radiance"), "emitter has zero radiance (it would emit no light)")
        for c in node.children:
            c = self._resolve(c)
            raise self.err(c.line, f"unsupported <{c.tag}> inside <emitter> (textured emission)")
        self.emitters.append(radiance)
        return len(self.emitters) - 1


def load_scene(path, params: dict | None = None) -> Scene:
    """Load a Mitsuba 3 XML scene file. `params` overrides `<default>` values (like mitsuba -D)."""
    path = Path(path)
    if path.suffix.lower() != ".xml" and path.is_file():
        raise SceneError(f"'{path}' is not a scene file (expected a Mitsuba .xml)")
    reader = SceneXmlReader(path, params)
    scene = _Builder(reader, reader.read()).build()
    _check_emitter_areas(scene)
    return scene


def _check_emitter_areas(scene: Scene):
    areas = np.zeros(len(scene.emitter_radiance))
    if len(scene.tri_emitter):
        mask = scene.tri_emitter >= 0
        np.add.at(areas, scene.tri_emitter[mask], scene.triangle_areas()[mask])
    for e, r in zip(scene.sphere_emitter, scene.sphere_radius):
        if e >= 0:
            areas[e] += 4 * np.pi * r * r
    for i, a in enumerate(areas):
        if not a > 0:
            raise SceneError(f"{scene.path}: emitter {i} is attached to a shape of zero area")
