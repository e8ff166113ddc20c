"""Regenerate the meshes of scenes/mesh-room (deterministic; committed to the repository).

    python tools/make_meshes.py

torus.obj is written without normals, so Mitsuba and photonmc both compute smooth
angle-weighted vertex normals; icosphere.ply carries its own per-vertex normals.
"""
from pathlib import Path

import trimesh

out = Path(__file__).resolve().parent.parent / "scenes" / "mesh-room"
torus = trimesh.creation.torus(major_radius=0.55, minor_radius=0.2, major_sections=48, minor_sections=24)
(out / "torus.obj").write_text(trimesh.exchange.obj.export_obj(torus, include_normals=False, include_texture=False))
ico = trimesh.creation.icosphere(subdivisions=3, radius=0.45)
(out / "icosphere.ply").write_bytes(trimesh.exchange.ply.export_ply(ico, encoding="binary", vertex_normal=True))
print(f"torus: {len(torus.faces)} triangles, icosphere: {len(ico.faces)} triangles -> {out}")
