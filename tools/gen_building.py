#!/usr/bin/env python3
"""Writes a closed building of NX x NZ furnished rooms as an illumnet scene.

Rooms sit on a grid, joined by doorways through walls of thickness
--wall; the outer walls, floors and ceilings close the building, so no
light escapes. Some rooms have a ceiling lamp (every --lamp-every-th room
in grid order, room 0 always), every room --furniture boxes (tables,
cabinets, shelves) placed on the floor without overlapping. The camera
stands in room 0 looking at its doorway towards room 1. Surfaces are
one-sided and face into the rooms.

Sizes for benchmarks (tools/bench_ladder.py): the patch count follows the
surface area and --patch-size (illumnet build --patch-size; this script
writes no [build] table), the link ends roughly patches x ~0.6 x
directions. Primitives: ~18 per room plus 5 per furniture box.

With --mesh OBJ, every room also holds a copy of that mesh (for example
scenes/meshes/bunny.obj), --mesh-height metres tall, standing in the
room's centre turned a different way in each room; --mesh-subdivide L
cuts each triangle into 4^L first (tools/obj_subdivide.py), and the mesh
is written next to the output (its triangles count as primitives).

Usage: tools/gen_building.py NX NZ [--furniture K] [--lamp-every N]
                             [--mesh OBJ [--mesh-subdivide L]
                             [--mesh-height H]] [--seed S] -o building.toml
"""

import argparse
import math
import os
import random

import obj_subdivide


def quad(p0, p1, p2, p3):
    return [list(map(float, p)) for p in (p0, p1, p2, p3)]


def fmt(q):
    return "[" + ", ".join("[" + ", ".join(f"{c:.4f}" for c in p) + "]" for p in q) + "]"


def wall_quads(axis, at, lo, hi, height, facing, door):
    """Quads of a wall in the plane axis = at (axis 'x' or 'z'), spanning
    lo..hi along the other horizontal axis and 0..height, front facing
    +axis (facing = +1) or -axis; with a doorway (centre, width, height)
    cut out when door is given."""

    def point(u, y):
        return (at, y, u) if axis == "x" else (u, y, at)

    def rect(u0, u1, y0, y1):
        # Counter-clockwise seen from the front.
        a, b, c, d = point(u0, y0), point(u1, y0), point(u1, y1), point(u0, y1)
        # For a wall at x = const, (u along z, y up) gives normal
        # (b-a)x(d-a) = z x y = -x; at z = const, x x y = +z.
        natural = -1 if axis == "x" else 1
        return quad(a, b, c, d) if natural == facing else quad(b, a, d, c)

    if door is None:
        return [rect(lo, hi, 0.0, height)]
    centre, width, dh = door
    d0, d1 = centre - width / 2, centre + width / 2
    return [rect(lo, d0, 0.0, height), rect(d1, hi, 0.0, height), rect(d0, d1, dh, height)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("nx", type=int)
    ap.add_argument("nz", type=int)
    ap.add_argument("--room", type=float, nargs=3, default=[4.0, 3.0, 4.0], metavar=("W", "H", "D"))
    ap.add_argument("--wall", type=float, default=0.2)
    ap.add_argument("--door", type=float, nargs=2, default=[1.0, 2.1], metavar=("WIDTH", "HEIGHT"))
    ap.add_argument("--furniture", type=int, default=3)
    ap.add_argument("--lamp-every", type=int, default=3)
    ap.add_argument("--lamp-radiance", type=float, default=30.0)
    ap.add_argument("--mesh", help="a Wavefront OBJ to stand in every room")
    ap.add_argument("--mesh-subdivide", type=int, default=0, metavar="L")
    ap.add_argument("--mesh-height", type=float, default=0.6, metavar="H")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--size", type=int, nargs=2, default=[320, 240], metavar=("WIDTH", "HEIGHT"))
    ap.add_argument("-o", "--output", required=True)
    a = ap.parse_args()
    if a.nx < 1 or a.nz < 1 or a.nx * a.nz < 2:
        ap.error("at least two rooms")
    rnd = random.Random(a.seed)
    w, h, d = a.room
    t = a.wall
    px, pz = w + t, d + t  # room pitch
    dw, dh = a.door
    out = []
    out.append(f"# {a.nx} x {a.nz} rooms of {w} x {h} x {d} m, walls {t} m, "
               f"{a.furniture} boxes a room, a lamp every {a.lamp_every} rooms (tools/gen_building.py)")
    cx, cz = w / 2, d / 2
    out.append(f"""
[camera]
position = [{cx - 1.0:.3f}, 1.6, {d * 0.15:.3f}]
look_at = [{w:.3f}, 1.1, {cz:.3f}]
fov_y_deg = 60
width = {a.size[0]}
height = {a.size[1]}

[[material]]
name = "wall"
type = "diffuse"
reflectance = [0.72, 0.70, 0.66]

[[material]]
name = "floor"
type = "diffuse"
reflectance = [0.45, 0.38, 0.30]

[[material]]
name = "wood"
type = "diffuse"
reflectance = [0.50, 0.30, 0.16]

[[material]]
name = "lamp"
type = "diffuse"
reflectance = [0.8, 0.8, 0.8]
""")
    walls, floors, ceilings, jambs = [], [], [], []
    furniture = []
    lamps = []
    for i in range(a.nx):
        for k in range(a.nz):
            x0, z0 = i * px, k * pz
            x1, z1 = x0 + w, z0 + d
            floors.append(quad((x0, 0, z0), (x0, 0, z1), (x1, 0, z1), (x1, 0, z0)))
            ceilings.append(quad((x0, h, z0), (x1, h, z0), (x1, h, z1), (x0, h, z1)))
            # Walls facing into the room, with doorways to neighbours.
            walls += wall_quads("x", x0, z0, z1, h, +1, (z0 + d / 2, dw, dh) if i > 0 else None)
            walls += wall_quads("x", x1, z0, z1, h, -1, (z0 + d / 2, dw, dh) if i + 1 < a.nx else None)
            walls += wall_quads("z", z0, x0, x1, h, +1, (x0 + w / 2, dw, dh) if k > 0 else None)
            walls += wall_quads("z", z1, x0, x1, h, -1, (x0 + w / 2, dw, dh) if k + 1 < a.nz else None)
            # The doorway through the wall to the +x and +z neighbours:
            # its two sides, its top and its floor.
            if i + 1 < a.nx:
                zc = z0 + d / 2
                za, zb = zc - dw / 2, zc + dw / 2
                jambs.append(quad((x1, 0, za), (x1 + t, 0, za), (x1 + t, dh, za), (x1, dh, za)))  # faces +z
                jambs.append(quad((x1 + t, 0, zb), (x1, 0, zb), (x1, dh, zb), (x1 + t, dh, zb)))  # faces -z
                jambs.append(quad((x1, dh, za), (x1 + t, dh, za), (x1 + t, dh, zb), (x1, dh, zb)))  # faces -y
                floors.append(quad((x1, 0, za), (x1, 0, zb), (x1 + t, 0, zb), (x1 + t, 0, za)))
            if k + 1 < a.nz:
                xc = x0 + w / 2
                xa, xb = xc - dw / 2, xc + dw / 2
                jambs.append(quad((xa, 0, z1 + t), (xa, 0, z1), (xa, dh, z1), (xa, dh, z1 + t)))  # faces +x
                jambs.append(quad((xb, 0, z1), (xb, 0, z1 + t), (xb, dh, z1 + t), (xb, dh, z1)))  # faces -x
                jambs.append(quad((xa, dh, z1), (xa, dh, z1 + t), (xb, dh, z1 + t), (xb, dh, z1)))  # faces -y
                floors.append(quad((xa, 0, z1), (xa, 0, z1 + t), (xb, 0, z1 + t), (xb, 0, z1)))
            room = i * a.nz + k
            if room % a.lamp_every == 0:
                s = 0.25
                lamps.append(quad((x0 + w / 2 - s, h - 0.02, z0 + d / 2 - s), (x0 + w / 2 + s, h - 0.02, z0 + d / 2 - s),
                                  (x0 + w / 2 + s, h - 0.02, z0 + d / 2 + s), (x0 + w / 2 - s, h - 0.02, z0 + d / 2 + s)))
            # Furniture on a 3 x 3 grid of cells away from the doorways'
            # centre lines, at most one box a cell.
            cells = [(u, v) for u in range(3) for v in range(3) if (u, v) != (1, 1)]
            rnd.shuffle(cells)
            for u, v in cells[: a.furniture]:
                kind = rnd.choice([(1.2, 0.75, 0.8), (0.6, 1.8, 0.4), (0.9, 1.2, 0.35), (0.5, 0.45, 0.5)])
                bx, by, bz = kind
                cw, cd = w / 3, d / 3
                ox = x0 + u * cw + (cw - bx) / 2 + rnd.uniform(-0.1, 0.1)
                oz = z0 + v * cd + (cd - bz) / 2 + rnd.uniform(-0.1, 0.1)
                furniture.append(((ox, 0.0, oz), (ox + bx, by, oz + bz)))

    def surface(name, material, quads, emission=None):
        lines = [f"\n[[surface]]\nname = \"{name}\"\nmaterial = \"{material}\""]
        if emission:
            lines.append(f"emission = [{emission}, {emission}, {emission * 0.9:.3f}]")
        lines.append("quads = [\n  " + ",\n  ".join(fmt(q) for q in quads) + "\n]")
        out.append("\n".join(lines))

    mesh_triangles = 0
    if a.mesh:
        verts, faces = obj_subdivide.subdivide(*obj_subdivide.load(a.mesh), a.mesh_subdivide)
        name = os.path.splitext(os.path.basename(a.output))[0] + ".mesh.obj"
        obj_subdivide.save(os.path.join(os.path.dirname(os.path.abspath(a.output)), name), verts, faces,
                           f"{a.mesh} cut {4 ** a.mesh_subdivide} ways (tools/gen_building.py)")
        lo = [min(v[i] for v in verts) for i in range(3)]
        hi = [max(v[i] for v in verts) for i in range(3)]
        scale = a.mesh_height / (hi[1] - lo[1])
        centre = [(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2]
        for i in range(a.nx):
            for k in range(a.nz):
                # Rotation about y keeps the base on the floor: translate
                # the scaled, turned centre of the base to the room's centre.
                turn = rnd.uniform(0.0, 360.0)
                c, s_ = math.cos(math.radians(turn)), math.sin(math.radians(turn))
                bx, bz = centre[0] * scale, centre[2] * scale
                rx, rz = c * bx + s_ * bz, -s_ * bx + c * bz
                tx, tz = i * px + w / 2 - rx, k * pz + d / 2 - rz
                out.append(f"\n[[surface]]\nname = \"mesh{i * a.nz + k}\"\nmaterial = \"wall\"\nmesh = \"{name}\"\n"
                           f"transform = {{ scale = [{scale:.6g}, {scale:.6g}, {scale:.6g}], rotate_deg = [0.0, {turn:.2f}, 0.0], "
                           f"translate = [{tx:.4f}, {-lo[1] * scale + 1e-4:.6f}, {tz:.4f}] }}")
                mesh_triangles += len(faces)

    surface("walls", "wall", walls + jambs)
    surface("floors", "floor", floors)
    surface("ceilings", "wall", ceilings)
    surface("lamps", "lamp", lamps, emission=a.lamp_radiance)
    for n, (lo, hi) in enumerate(furniture):
        out.append(f"\n[[surface]]\nname = \"box{n}\"\nmaterial = \"wood\"\n"
                   f"box = {{ min = [{lo[0]:.4f}, {lo[1]:.4f}, {lo[2]:.4f}], "
                   f"max = [{hi[0]:.4f}, {hi[1]:.4f}, {hi[2]:.4f}], omit = [\"-y\"] }}")
    with open(a.output, "w") as f:
        f.write("\n".join(out) + "\n")
    prims = len(walls) + len(jambs) + len(floors) + len(ceilings) + len(lamps) + 5 * len(furniture) + mesh_triangles
    area = a.nx * a.nz * (2 * w * d + 2 * (w + d) * h)
    print(f"wrote {a.output}: {a.nx * a.nz} rooms, {prims} primitives, {len(lamps)} lamps, "
          f"about {area:.0f} m2 of walls, floors and ceilings")


if __name__ == "__main__":
    main()
