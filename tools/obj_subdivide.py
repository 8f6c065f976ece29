#!/usr/bin/env python3
"""Midpoint subdivision of a triangle mesh (Wavefront OBJ, `v` and `f` lines).

Every triangle becomes 4 (corners and edge midpoints), `levels` times; the
surface does not change, so a path-traced reference of the coarse mesh is a
reference of the fine one too. Used by tools/mesh_study.py and
tools/gen_building.py (meshes in every room) to make finer meshes.

Usage: tools/obj_subdivide.py IN.obj OUT.obj LEVELS
"""

from __future__ import annotations

import sys


def load(path: str) -> tuple[list[tuple[float, float, float]], list[tuple[int, int, int]]]:
    """Vertices and triangles (0-based; polygons as fans from their first corner)."""
    verts, faces = [], []
    for line in open(path):
        p = line.split()
        if p and p[0] == "v":
            verts.append((float(p[1]), float(p[2]), float(p[3])))
        elif p and p[0] == "f":
            idx = [int(x.split("/")[0]) for x in p[1:]]
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            faces.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1))
    return verts, faces


def subdivide(verts, faces, levels: int):
    """The mesh with every triangle cut into 4^levels."""
    verts = list(verts)
    for _ in range(levels):
        mid: dict[tuple[int, int], int] = {}

        def m(a: int, b: int) -> int:
            k = (min(a, b), max(a, b))
            if k not in mid:
                verts.append(tuple((verts[a][i] + verts[b][i]) / 2 for i in range(3)))
                mid[k] = len(verts) - 1
            return mid[k]

        faces = [
            t
            for a, b, c in faces
            for t in ((a, m(a, b), m(c, a)), (m(a, b), b, m(b, c)), (m(c, a), m(b, c), c), (m(a, b), m(b, c), m(c, a)))
        ]
    return verts, faces


def save(path: str, verts, faces, header: str = "") -> None:
    with open(path, "w") as o:
        if header:
            o.write("".join(f"# {line}\n" for line in header.splitlines()))
        o.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in verts)
        o.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces)


def main() -> None:
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    verts, faces = subdivide(*load(sys.argv[1]), int(sys.argv[3]))
    save(sys.argv[2], verts, faces)
    print(f"wrote {sys.argv[2]}: {len(verts)} vertices, {len(faces)} triangles")


if __name__ == "__main__":
    main()
