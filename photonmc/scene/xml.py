"""Reading Mitsuba 3 scene XML into plugin nodes with typed properties.

This module knows the XML syntax only (elements, `$name` defaults, property tags,
transforms). Which plugins and parameters photonmc supports is decided in loader.py.
Every node keeps its line number so that errors can point at the element.
"""
from __future__ import annotations

import re
import xml.parsers.expat
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import SceneError
from . import transform as tf

PLUGIN_TAGS = ("shape", "bsdf", "emitter", "sensor", "film", "rfilter", "sampler",
               "integrator", "texture", "medium", "phase", "volume")
PROPERTY_TAGS = ("float", "integer", "boolean", "string", "rgb", "spectrum", "point",
                 "vector", "transform", "ref")


@dataclass
class XmlElement:
    tag: str
    attrs: dict
    line: int
    children: list = field(default_factory=list)


@dataclass
class Plugin:
    """One plugin element: `<shape type="obj" id="...">` with its properties and nested plugins."""
    tag: str
    type: str
    id: str | None
    line: int
    file: str
    props: dict = field(default_factory=dict)       # name -> Property
    children: list = field(default_factory=list)   # nested Plugin or Ref, in document order

    def where(self) -> str:
        return f"{self.file}:{self.line}"


@dataclass
class Property:
    kind: str      # float, integer, boolean, string, rgb, spectrum, point, vector, transform
    value: object
    line: int


@dataclass
class Ref:
    id: str
    name: str | None
    line: int


def _parse_xml(path: Path) -> XmlElement:
    parser = xml.parsers.expat.ParserCreate()
    stack: list[XmlElement] = []
    root: list[XmlElement] = []

    def start(tag, attrs):
        el = XmlElement(tag, dict(attrs), parser.CurrentLineNumber)
        if stack:
            stack[-1].children.append(el)
        else:
            root.append(el)
        stack.append(el)

    def end(tag):
        stack.pop()

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    try:
        data = path.read_bytes()
    except OSError as e:
        raise SceneError(f"cannot read scene file '{path}': {e.strerror}") from None
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        raise SceneError(f"{path}:{e.lineno}: malformed XML: {xml.parsers.expat.errors.messages[e.code]}") from None
    return root[0]


_SUBST = re.compile(r"\$([A-Za-z_][A-Za-z0-9_]*)")


class SceneXmlReader:
    def __init__(self, path: Path, params: dict | None = None):
        self.path = Path(path)
        self.params = {k: str(v) for k, v in (params or {}).items()}
        self.ids: dict[str, Plugin] = {}
        self.warnings: list[str] = []

    def err(self, line: int, msg: str) -> SceneError:
        return SceneError(f"{self.path}:{line}: {msg}")

    def read(self) -> Plugin:
        root = _parse_xml(self.path)
        if root.tag != "scene":
            raise self.err(root.line, f"root element must be <scene>, found <{root.tag}>")
        # <default> values first: they hold wherever they appear and command-line values win.
        for el in root.children:
            if el.tag == "default":
                name, value = el.attrs.get("name"), el.attrs.get("value")
                if name is None or value is None:
                    raise self.err(el.line, "<default> needs 'name' and 'value'")
                self.params.setdefault(name, value)
        scene = Plugin("scene", "scene", None, root.line, str(self.path))
        for el in root.children:
            if el.tag == "default":
                continue
            self._child(scene, el)
        return scene

    def _attr(self, el: XmlElement, name: str, required=True):
        if name not in el.attrs:
            if required:
                raise self.err(el.line, f"<{el.tag}> needs attribute '{name}'")
            return None
        value = el.attrs[name]

        def sub(m):
            key = m.group(1)
            if key not in self.params:
                raise self.err(el.line, f"parameter '${key}' has no value (add <default name=\"{key}\" value=\"...\"/>)")
            return self.params[key]
        return _SUBST.sub(sub, value)

    def _child(self, parent: Plugin, el: XmlElement):
        if el.tag in PLUGIN_TAGS:
            parent.children.append(self._plugin(el))
        elif el.tag == "ref":
            rid = self._attr(el, "id")
            parent.children.append(Ref(rid, el.attrs.get("name"), el.line))
        elif el.tag in PROPERTY_TAGS:
            name = self._attr(el, "name")
            if name in parent.props:
                raise self.err(el.line, f"property '{name}' given twice in <{parent.tag} type=\"{parent.type}\">")
            parent.props[name] = Property(el.tag, self._property_value(el), el.line)
        else:
            raise self.err(el.line, f"unsupported element <{el.tag}>")

    def _plugin(self, el: XmlElement) -> Plugin:
        ptype = self._attr(el, "type")
        pid = self._attr(el, "id", required=False)
        node = Plugin(el.tag, ptype, pid, el.line, str(self.path))
        for child in el.children:
            self._child(node, child)
        if pid is not None:
            if pid in self.ids:
                raise self.err(el.line, f"id '{pid}' is used twice")
            self.ids[pid] = node
        return node

    # -- property values -------------------------------------------------------------
    def _floats(self, el, text, count=None):
        parts = [p for p in re.split(r"[,\s]+", text.strip()) if p]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise self.err(el.line, f"<{el.tag}>: '{text}' is not a list of numbers") from None
        if count is not None and len(values) not in (count if isinstance(count, tuple) else (count,)):
            raise self.err(el.line, f"<{el.tag}>: expected {count} numbers, got {len(values)}")
        if not all(np.isfinite(values)):
            raise self.err(el.line, f"<{el.tag}>: value '{text}' is not finite")
        return values

    def _property_value(self, el: XmlElement):
        kind = el.tag
        if kind == "transform":
            return self._transform(el)
        if kind in ("point", "vector"):
            if "value" in el.attrs:
                return np.array(self._floats(el, self._attr(el, "value"), 3))
            return np.array([float(self._floats(el, self._attr(el, a, required=False) or "0", 1)[0])
                             for a in "xyz"])
        value = self._attr(el, "value")
        if kind == "float":
            return self._floats(el, value, 1)[0]
        if kind == "integer":
            try:
                return int(value)
            except ValueError:
                raise self.err(el.line, f"<integer>: '{value}' is not an integer") from None
        if kind == "boolean":
            if value.lower() not in ("true", "false"):
                raise self.err(el.line, f"<boolean>: '{value}' is neither true nor false")
            return value.lower() == "true"
        if kind == "string":
            return value
        if kind == "rgb":
            v = self._floats(el, value, (1, 3))
            return np.array(v * 3 if len(v) == 1 else v)
        if kind == "spectrum":
            if ":" in value:
                raise self.err(el.line, "<spectrum> with wavelength:value pairs is not supported "
                                        "(photonmc renders in RGB); use <rgb> or a single constant value")
            v = self._floats(el, value, 1)
            return np.array(v * 3)
        raise self.err(el.line, f"unsupported property <{kind}>")

    def _transform(self, el: XmlElement) -> tf.Transform:
        t = tf.Transform()
        for step in el.children:
            matrix = self._transform_step(step)
            # document order: later steps apply last; see Transform for the normal matrix
            t = t.then(matrix, matrix[:3, :3] if step.tag == "rotate" else None)
        if not np.all(np.isfinite(t.m)):
            raise self.err(el.line, "transform is not finite")
        return t

    def _vec_attrs(self, el, default):
        if "value" in el.attrs:
            v = self._floats(el, self._attr(el, "value"), (1, 3))
            return np.array(v * 3 if len(v) == 1 else v)
        return np.array([float(self._floats(el, self._attr(el, a, required=False) or str(default), 1)[0])
                         for a in "xyz"])

    def _transform_step(self, el: XmlElement) -> np.ndarray:
        if el.tag == "translate":
            return tf.translate(self._vec_attrs(el, 0.0))
        if el.tag == "scale":
            return tf.scale(self._vec_attrs(el, 1.0))
        if el.tag == "rotate":
            angle = self._floats(el, self._attr(el, "angle"), 1)[0]
            if "value" in el.attrs:
                axis = np.array(self._floats(el, self._attr(el, "value"), 3))
            else:
                axis = self._vec_attrs(el, 0.0)
            if np.linalg.norm(axis) == 0:
                raise self.err(el.line, "<rotate> axis is zero")
            if abs(np.linalg.norm(axis) - 1) > 1e-6:
                self.warnings.append(f"{self.path}:{el.line}: <rotate> axis {axis.tolist()} is not unit length; "
                                     "as in Mitsuba it is used as given, which also scales and shears the shape "
                                     "while normals are turned as by a pure rotation")
            return tf.rotate(axis, angle)
        if el.tag == "matrix":
            return tf.matrix(self._floats(el, self._attr(el, "value"), (9, 16)))
        if el.tag == "lookat":
            origin = np.array(self._floats(el, self._attr(el, "origin"), 3))
            target = np.array(self._floats(el, self._attr(el, "target"), 3))
            up_text = self._attr(el, "up", required=False)
            up = np.array(self._floats(el, up_text, 3)) if up_text else np.zeros(3)  # Mitsuba then picks one
            try:
                return tf.look_at(origin, target, up)
            except ValueError as e:
                raise self.err(el.line, f"<lookat>: {e}") from None
        raise self.err(el.line, f"unsupported transform step <{el.tag}>")
