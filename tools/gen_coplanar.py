#!/usr/bin/env python3
"""Writes a scene of N coplanar quads in one surface (issue 42 §4).

The floor, a square of --size metres, is one surface of N quads in a grid
of about sqrt(N) x sqrt(N) (--layout grid) or one row of N (--layout
strip); a lamp hangs above it. Used to measure the build's setup time
against the coplanar quads of one surface (docs/notebook/2026-12-07-coplanar-setup.md):

    tools/gen_coplanar.py 100000 -o /tmp/coplanar.toml
    illumnet build /tmp/coplanar.toml -o /tmp/c.inet --frequency 2

Usage: tools/gen_coplanar.py N [--layout grid|strip] [--size M]
                             [--depth M] [--patch-size M] -o scene.toml
"""

import argparse
import math


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("n", type=int, help="coplanar quads in the floor")
    ap.add_argument("--layout", choices=["grid", "strip"], default="grid")
    ap.add_argument("--size", type=float, default=1.0, help="floor edge (m)")
    ap.add_argument("--depth", type=float, help="floor extent along z (m; default --size)")
    ap.add_argument("--patch-size", type=float, help="[build] patch_size (m)")
    ap.add_argument("-o", "--output", required=True)
    a = ap.parse_args()
    if a.layout == "grid":
        nx = max(1, round(math.sqrt(a.n)))
        nz = math.ceil(a.n / nx)
    else:
        nx, nz = a.n, 1
    depth = a.size if a.depth is None else a.depth
    dx, dz = a.size / nx, depth / nz
    s = a.size
    out = []
    out.append("[camera]\nposition = [%g, %g, %g]\nlook_at = [%g, 0.0, %g]\n"
               "up = [0.0, 1.0, 0.0]\nfov_y_deg = 60.0\nwidth = 64\nheight = 64\n"
               % (s / 2, s, -s, s / 2, s / 2))
    if a.patch_size is not None:
        out.append("[build]\npatch_size = %r\n" % a.patch_size)
    out.append('[[material]]\nname = "white"\ntype = "diffuse"\nreflectance = [0.7, 0.7, 0.7]\n')
    out.append('[[surface]]\nname = "lamp"\nmaterial = "white"\nemission = [10.0, 10.0, 10.0]\n'
               "quad = [[%r, %r, %r], [%r, %r, %r], [%r, %r, %r], [%r, %r, %r]]\n"
               % (0.4 * s, 0.5 * s, 0.4 * s, 0.6 * s, 0.5 * s, 0.4 * s,
                  0.6 * s, 0.5 * s, 0.6 * s, 0.4 * s, 0.5 * s, 0.6 * s))
    out.append('[[surface]]\nname = "floor"\nmaterial = "white"\nquads = [\n')
    rows = []
    k = 0
    for j in range(nz):
        for i in range(nx):
            if k == a.n:
                break
            x0, x1, z0, z1 = i * dx, (i + 1) * dx, j * dz, (j + 1) * dz
            # Counter-clockwise seen from above (+y): the front faces up.
            rows.append("  [[%r, 0.0, %r], [%r, 0.0, %r], [%r, 0.0, %r], [%r, 0.0, %r]],"
                        % (x0, z0, x0, z1, x1, z1, x1, z0))
            k += 1
    out.append("\n".join(rows) + "\n]\n")
    with open(a.output, "w") as f:
        f.write("\n".join(out))


if __name__ == "__main__":
    main()
