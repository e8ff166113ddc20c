"""Reading and writing images through OpenImageIO.

EXR holds linear float32 RGB with the render's provenance in its header; PNG holds the
same image clamped and encoded with the sRGB transfer curve (as Mitsuba writes PNGs).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenImageIO as oiio

from .errors import PhotonmcError

OUTPUT_SUFFIXES = (".exr", ".png")


def check_output_path(path) -> Path:
    """Fail before rendering, not after, when the output cannot be written."""
    path = Path(path)
    if path.suffix.lower() not in OUTPUT_SUFFIXES:
        raise PhotonmcError(f"--out must end in .exr or .png, got '{path}'")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise PhotonmcError(f"output directory '{parent}' does not exist")
    return path


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    x = np.clip(np.nan_to_num(linear, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    encoded = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(encoded * 255.0).astype(np.uint8)


def _write(path: Path, pixels: np.ndarray, fmt: str, metadata: dict):
    h, w, c = pixels.shape
    spec = oiio.ImageSpec(w, h, c, fmt)
    for key, value in metadata.items():
        spec.attribute(f"photonmc:{key}", str(value))
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise PhotonmcError(f"cannot write '{path}': {oiio.geterror()}")
    ok = out.open(str(path), spec) and out.write_image(pixels)
    err = out.geterror()
    out.close()
    if not ok:
        raise PhotonmcError(f"cannot write '{path}': {err}")


def write_image(path, image: np.ndarray, metadata: dict | None = None) -> list[Path]:
    """Write `image` (H,W,3 linear). An .exr also gets a .png beside it. Returns the paths."""
    path = check_output_path(path)
    metadata = metadata or {}
    written = []
    if path.suffix.lower() == ".exr":
        _write(path, np.ascontiguousarray(image, np.float32), "float", metadata)
        written.append(path)
        path = path.with_suffix(".png")
    _write(path, srgb_encode(image), "uint8", metadata)
    written.append(path)
    return written


def read_image(path) -> np.ndarray:
    """Read an image as (H,W,3) float32 linear RGB (EXR/HDR as stored)."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise PhotonmcError(f"cannot read image '{path}': {oiio.geterror()}")
    pixels = inp.read_image("float")
    inp.close()
    if pixels is None:
        raise PhotonmcError(f"cannot read image '{path}'")
    pixels = np.asarray(pixels, np.float32)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.shape[2] == 1:
        pixels = np.repeat(pixels, 3, axis=2)
    return pixels[..., :3]


def read_metadata(path) -> dict:
    """The photonmc:* attributes of an image's header (provenance; a reference's noise_mse)."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise PhotonmcError(f"cannot read image '{path}': {oiio.geterror()}")
    spec = inp.spec()
    inp.close()
    return {a.name.split(":", 1)[1]: a.value for a in spec.extra_attribs if a.name.startswith("photonmc:")}

