#!/usr/bin/env python3
"""Writes the glTF 2.0 test files of tests/data/gltf/ with pygltflib, a
tool other than ours, so the importer is tested on what others write.

    pip install pygltflib pillow   # pygltflib 1.16.5, Pillow for the texture
    python3 tools/make_gltf.py     # rewrites tests/data/gltf/*

Files:
* cornell_box.glb: scenes/cornell_box.toml exported as glTF: every quad as
  two triangles (0,1,2),(0,2,3); materials metallic 0, roughness 1 with the
  reflectance as base colour; the lamp's radiance as emissiveFactor ×
  KHR_materials_emissive_strength; the camera as a camera node.
* fan_room.glb: scenes/fan_room.toml with its animation: each moving
  surface hangs under a node at its pivot whose translation and rotation
  are animated (LINEAR, keys at frame/15 s) and a child node at -pivot
  holding the mesh; 60 frames at 15 fps (import with fps 15).
* features.gltf (+ features.bin, checker.png): two cameras; one box mesh
  instanced by two nodes under a scaled, translated parent; a textured
  floor; an emissive panel with the strength extension; point, spot and
  directional lights; an anisotropic metal plate with TANGENTs; a node
  animated with STEP translation and CUBICSPLINE rotation; a mesh with a
  morph target. tests/gltf.rs states what each must import as.
* smooth.glb: a faceted half-cylinder (6 facets over 120°, radius 1 m)
  with per-vertex NORMALs pointing radially, below and before an emissive
  panel facing down: the
  shading normals turn direct light smoothly across the facets.
* ../obj/cornell_box.obj (+ .mtl): the Cornell box as Wavefront OBJ, one
  object per surface, quads as `f` of four corners, Kd and the lamp's Ke in
  the MTL; ../obj/textured.obj: a floor with map_Kd (checker.png) and Ks/Ns
  plates, under an emitter.
"""

import math
import pathlib
import struct
import tomllib

import pygltflib as g

ROOT = pathlib.Path(__file__).resolve().parent.parent
OUT = ROOT / "tests" / "data" / "gltf"


class Writer:
    """One glTF document and its single binary buffer."""

    def __init__(self):
        self.doc = g.GLTF2(asset=g.Asset(generator="tools/make_gltf.py (pygltflib)", version="2.0"))
        self.doc.scenes = [g.Scene(nodes=[])]
        self.doc.scene = 0
        self.blob = bytearray()

    def view(self, data, target=None):
        while len(self.blob) % 4:
            self.blob.append(0)
        self.doc.bufferViews.append(g.BufferView(buffer=0, byteOffset=len(self.blob), byteLength=len(data), target=target))
        self.blob += data
        return len(self.doc.bufferViews) - 1

    def accessor(self, values, kind, component=g.FLOAT, target=None, bounds=False):
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[kind]
        flat = [x for v in values for x in (v if width > 1 else [v])]
        fmt = {g.FLOAT: "f", g.UNSIGNED_INT: "I"}[component]
        data = struct.pack("<%d%s" % (len(flat), fmt), *flat)
        acc = g.Accessor(bufferView=self.view(data, target), componentType=component, count=len(values), type=kind)
        if bounds:
            acc.min = [min(v[i] for v in values) for i in range(width)]
            acc.max = [max(v[i] for v in values) for i in range(width)]
        self.doc.accessors.append(acc)
        return len(self.doc.accessors) - 1

    def mesh(self, name, quads, material, tangent=None, uv=None, triangles=()):
        """A mesh of quads (each split (0,1,2),(0,2,3)) and triangles."""
        pos, idx, uvs = [], [], []
        for q in quads:
            base = len(pos)
            pos += [list(map(float, p)) for p in q]
            idx += [base, base + 1, base + 2, base, base + 2, base + 3]
            uvs += [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]
        for t in triangles:
            base = len(pos)
            pos += [list(map(float, p)) for p in t]
            idx += [base, base + 1, base + 2]
            uvs += [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]
        attrs = g.Attributes(POSITION=self.accessor(pos, "VEC3", target=g.ARRAY_BUFFER, bounds=True))
        if uv:
            attrs.TEXCOORD_0 = self.accessor(uvs, "VEC2", target=g.ARRAY_BUFFER)
        if tangent:
            attrs.TANGENT = self.accessor([tangent] * len(pos), "VEC4", target=g.ARRAY_BUFFER)
        prim = g.Primitive(
            attributes=attrs,
            indices=self.accessor(idx, "SCALAR", g.UNSIGNED_INT, g.ELEMENT_ARRAY_BUFFER),
            material=material,
        )
        self.doc.meshes.append(g.Mesh(name=name, primitives=[prim]))
        return len(self.doc.meshes) - 1

    def material(self, name, base, metallic=0.0, roughness=1.0, emission=None, **kw):
        m = g.Material(
            name=name,
            pbrMetallicRoughness=g.PbrMetallicRoughness(
                baseColorFactor=list(base) + [1.0], metallicFactor=metallic, roughnessFactor=roughness
            ),
            **kw,
        )
        if emission is not None and max(emission) > 0:
            peak = max(emission)
            m.emissiveFactor = [e / peak for e in emission]
            m.extensions["KHR_materials_emissive_strength"] = {"emissiveStrength": peak}
            self.use("KHR_materials_emissive_strength")
        self.doc.materials.append(m)
        return len(self.doc.materials) - 1

    def use(self, ext):
        if ext not in self.doc.extensionsUsed:
            self.doc.extensionsUsed.append(ext)

    def node(self, root=True, **kw):
        self.doc.nodes.append(g.Node(**kw))
        i = len(self.doc.nodes) - 1
        if root:
            self.doc.scenes[0].nodes.append(i)
        return i

    def camera_node(self, name, position, look_at, up, fov_deg, aspect):
        self.doc.cameras.append(
            g.Camera(
                name=name,
                type="perspective",
                perspective=g.Perspective(yfov=math.radians(fov_deg), aspectRatio=aspect, znear=0.01),
            )
        )
        return self.node(name=name, camera=len(self.doc.cameras) - 1, translation=list(position), rotation=look_rotation(position, look_at, up))

    def channel(self, node, path, times, values, interpolation="LINEAR"):
        if not self.doc.animations:
            self.doc.animations.append(g.Animation(name="motion", channels=[], samplers=[]))
        a = self.doc.animations[0]
        kind = "VEC4" if path == "rotation" else "VEC3"
        a.samplers.append(
            g.AnimationSampler(
                input=self.accessor(times, "SCALAR", bounds=False),
                output=self.accessor(values, kind),
                interpolation=interpolation,
            )
        )
        # Input accessors need min and max.
        acc = self.doc.accessors[a.samplers[-1].input]
        acc.min, acc.max = [min(times)], [max(times)]
        a.channels.append(g.AnimationChannel(sampler=len(a.samplers) - 1, target=g.AnimationChannelTarget(node=node, path=path)))

    def save(self, path, binary=True):
        self.doc.buffers = [g.Buffer(byteLength=len(self.blob))]
        path.parent.mkdir(parents=True, exist_ok=True)
        if binary:
            self.doc.set_binary_blob(bytes(self.blob))
            self.doc.save_binary(str(path))
        else:
            bin_name = path.with_suffix(".bin").name
            (path.parent / bin_name).write_bytes(bytes(self.blob))
            self.doc.buffers[0].uri = bin_name
            self.doc.save_json(str(path))


def normalize(v):
    n = math.sqrt(sum(x * x for x in v))
    return [x / n for x in v]


def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def quat_from_matrix(c0, c1, c2):
    """Quaternion [x, y, z, w] of the rotation whose columns are c0, c1, c2."""
    m = [[c0[0], c1[0], c2[0]], [c0[1], c1[1], c2[1]], [c0[2], c1[2], c2[2]]]
    tr = m[0][0] + m[1][1] + m[2][2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        return [(m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s, 0.25 * s]
    i = max(range(3), key=lambda k: m[k][k])
    j, k = (i + 1) % 3, (i + 2) % 3
    s = math.sqrt(1.0 + m[i][i] - m[j][j] - m[k][k]) * 2
    q = [0.0] * 4
    q[i] = 0.25 * s
    q[j] = (m[j][i] + m[i][j]) / s
    q[k] = (m[k][i] + m[i][k]) / s
    q[3] = (m[k][j] - m[j][k]) / s
    return q


def look_rotation(position, look_at, up):
    """A glTF camera looks down its -Z with +Y up."""
    back = normalize([p - l for p, l in zip(position, look_at)])
    right = normalize(cross(up, back))
    return quat_from_matrix(right, cross(back, right), back)


def quat_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return [
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]


def axis_angle(axis, deg):
    h = math.radians(deg) / 2
    return [axis[0] * math.sin(h), axis[1] * math.sin(h), axis[2] * math.sin(h), math.cos(h)]


def rotation_deg(r):
    """Our rotate_deg = [rx, ry, rz] as Rz·Ry·Rx."""
    return quat_mul(axis_angle([0, 0, 1], r[2]), quat_mul(axis_angle([0, 1, 0], r[1]), axis_angle([1, 0, 0], r[0])))


def box_quads(b):
    """format-spec/scene.md's `box`: faces ±x, ±y, ±z facing out (or in)."""
    lo, hi = b["min"], b["max"]
    labels = ["-x", "+x", "-y", "+y", "-z", "+z"]
    out = []
    for axis in range(3):
        for positive in (False, True):
            if labels[axis * 2 + positive] in b.get("omit", []):
                continue
            bx, cx = (axis + 1) % 3, (axis + 2) % 3

            def corner(s, t):
                v = [0.0] * 3
                v[axis] = hi[axis] if positive else lo[axis]
                v[bx] = hi[bx] if s else lo[bx]
                v[cx] = hi[cx] if t else lo[cx]
                return v

            q = [corner(False, False), corner(True, False), corner(True, True), corner(False, True)]
            if positive == b.get("inward", False):
                q.reverse()
            out.append(q)
    return out


def surface_quads(s):
    if "quad" in s:
        return [s["quad"]]
    if "quads" in s:
        return s["quads"]
    return box_quads(s["box"])


def from_toml(scene_path, out_path):
    scene = tomllib.loads(scene_path.read_text())
    w = Writer()
    mats = {}
    cam = scene["camera"]
    w.camera_node("camera", cam["position"], cam["look_at"], cam["up"], cam["fov_y_deg"], cam["width"] / cam["height"])
    fps = scene.get("animation", {}).get("fps", 24)
    for s in scene["surface"]:
        key = (s["material"], tuple(s.get("emission", [0, 0, 0])))
        if key not in mats:
            m = next(m for m in scene["material"] if m["name"] == s["material"])
            name = m["name"] if key[1] == (0, 0, 0) else m["name"] + "_emitter"
            mats[key] = w.material(name, m["reflectance"], emission=s.get("emission"))
        if "keyframes" not in s:
            w.node(name=s["name"], mesh=w.mesh(s["name"], surface_quads(s), mats[key]))
            continue
        pivot = s.get("pivot", [0.0, 0.0, 0.0])
        inner = w.node(root=False, name=s["name"], translation=[-x for x in pivot], mesh=w.mesh(s["name"], surface_quads(s), mats[key]))
        outer = w.node(name=s["name"] + "_pivot", translation=list(pivot), children=[inner])
        keys = s["keyframes"]
        times = [k["frame"] / fps for k in keys]
        if any("translate" in k for k in keys):
            w.channel(outer, "translation", times, [[p + t for p, t in zip(pivot, k.get("translate", [0, 0, 0]))] for k in keys])
        if any("rotate_deg" in k for k in keys):
            w.channel(outer, "rotation", times, [rotation_deg(k.get("rotate_deg", [0, 0, 0])) for k in keys])
    w.save(out_path)


def features(out_path):
    from PIL import Image

    w = Writer()
    for ext in ("KHR_lights_punctual", "KHR_materials_anisotropy", "KHR_materials_emissive_strength"):
        w.use(ext)
    w.camera_node("main", [0.0, 1.5, 4.0], [0.0, 0.5, 0.0], [0.0, 1.0, 0.0], 45.0, 1.5)
    w.camera_node("side", [4.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0], 30.0, 1.0)

    # Floor 4 × 4 m, facing +y, with a 2 × 2 texture: red, green, blue, white
    # (sRGB 255/0, linear 1/0: mean linear albedo 0.5 per band) × 0.8.
    Image.frombytes("RGB", (2, 2), bytes([255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255])).save(out_path.parent / "checker.png")
    w.doc.images.append(g.Image(uri="checker.png"))
    w.doc.samplers.append(g.Sampler(wrapS=g.REPEAT, wrapT=g.REPEAT))
    w.doc.textures.append(g.Texture(source=0, sampler=0))
    floor_mat = w.material("checker", [0.8, 0.8, 0.8])
    w.doc.materials[floor_mat].pbrMetallicRoughness.baseColorTexture = g.TextureInfo(index=0)
    floor = [[[-2, 0, 2], [2, 0, 2], [2, 0, -2], [-2, 0, -2]]]
    w.node(name="floor", mesh=w.mesh("floor", floor, floor_mat, uv=True))

    # A 0.2 m box (12 triangles, closed, double sided) instanced twice under
    # a parent scaled by 2 and moved up 0.5 m: instances at x = ±0.5 local.
    grey = w.material("grey", [0.5, 0.5, 0.5], metallic=0.0, roughness=0.9, doubleSided=True)
    box = w.mesh("box", box_quads({"min": [-0.1, -0.1, -0.1], "max": [0.1, 0.1, 0.1]}), grey)
    a = w.node(root=False, name="box_a", mesh=box, translation=[-0.5, 0.0, 0.0])
    b = w.node(root=False, name="box_b", mesh=box, translation=[0.5, 0.0, 0.0])
    w.node(name="boxes", children=[a, b], translation=[0.0, 0.5, 0.0], scale=[2.0, 2.0, 2.0])

    # Emissive panel 0.5 × 0.5 m at y = 2.5 facing down: (1, .5, .25) × 8.
    lamp_mat = w.material("panel", [0.8, 0.8, 0.8], emission=[8.0, 4.0, 2.0])
    panel = [[[-0.25, 2.5, -0.25], [0.25, 2.5, -0.25], [0.25, 2.5, 0.25], [-0.25, 2.5, 0.25]]]
    w.node(name="panel", mesh=w.mesh("panel", panel, lamp_mat))

    # Anisotropic brushed metal plate facing +y, tangent +x; rotation π/2
    # turns the anisotropy direction onto the bitangent (N × T = -z).
    metal = w.material("brushed", [0.9, 0.9, 0.9], metallic=1.0, roughness=0.4)
    w.doc.materials[metal].extensions["KHR_materials_anisotropy"] = {"anisotropyStrength": 0.6, "anisotropyRotation": math.pi / 2}
    plate = [[[1.0, 0.01, -1.5], [1.0, 0.01, -1.0], [1.8, 0.01, -1.0], [1.8, 0.01, -1.5]]]
    w.node(name="plate", mesh=w.mesh("plate", plate, metal, tangent=[1.0, 0.0, 0.0, 1.0]))

    # Lights: 683 cd is 1 W/sr.
    w.doc.extensions["KHR_lights_punctual"] = {
        "lights": [
            {"name": "bulb", "type": "point", "color": [1.0, 0.5, 0.25], "intensity": 683.0 * 2.0},
            {"name": "spot", "type": "spot", "intensity": 683.0, "spot": {"outerConeAngle": 0.6}},
            {"name": "sun", "type": "directional", "intensity": 3.0},
        ]
    }
    w.node(name="bulb_node", translation=[-1.0, 2.0, 0.0], extensions={"KHR_lights_punctual": {"light": 0}})
    # The spot at (1, 2, 1) pointing straight down: -Z turned onto -Y.
    w.node(name="spot_node", translation=[1.0, 2.0, 1.0], rotation=axis_angle([1, 0, 0], -90.0), extensions={"KHR_lights_punctual": {"light": 1}})
    w.node(name="sun_node", extensions={"KHR_lights_punctual": {"light": 2}})

    # Animated: a 0.1 m triangle; translation STEP (0,1,0) then (0,1,1) at
    # 1 s; rotation CUBICSPLINE about y from 0° to 90° over 1 s, zero tangents.
    spin = w.node(name="spinner", mesh=w.mesh("tri", [], grey, triangles=[[[0, 0, 0], [0.1, 0, 0], [0, 0, -0.1]]]))
    w.channel(spin, "translation", [0.0, 1.0], [[0.0, 1.0, 0.0], [0.0, 1.0, 1.0]], "STEP")
    zero = [0.0, 0.0, 0.0, 0.0]
    w.channel(spin, "rotation", [0.0, 1.0], [zero, [0, 0, 0, 1], zero, zero, axis_angle([0, 1, 0], 90.0), zero], "CUBICSPLINE")

    # A mesh with a morph target (unsupported: said, base shape used).
    morph = w.mesh("morphing", [[[-1.9, 0.01, 1.9], [-1.5, 0.01, 1.9], [-1.5, 0.01, 1.5], [-1.9, 0.01, 1.5]]], grey)
    disp = w.accessor([[0.0, 0.1, 0.0]] * 4, "VEC3", target=g.ARRAY_BUFFER, bounds=True)
    w.doc.meshes[morph].primitives[0].targets = [{"POSITION": disp}]
    w.node(name="morpher", mesh=morph)
    w.save(out_path, binary=False)


def smooth(out_path):
    w = Writer()
    w.camera_node("main", [0.0, 0.5, 4.0], [0.0, 0.5, 0.0], [0.0, 1.0, 0.0], 40.0, 1.0)
    n = 6
    pos, nrm, idx = [], [], []
    for i in range(n + 1):
        t = math.radians(-60.0 + 120.0 * i / n)
        for y in (0.0, 1.0):
            pos.append([math.sin(t), y, math.cos(t)])
            nrm.append([math.sin(t), 0.0, math.cos(t)])
    for i in range(n):
        a, d, b, c = 2 * i, 2 * i + 1, 2 * i + 2, 2 * i + 3
        idx += [a, b, c, a, c, d]
    grey = w.material("grey", [0.6, 0.6, 0.6])
    attrs = g.Attributes(
        POSITION=w.accessor(pos, "VEC3", target=g.ARRAY_BUFFER, bounds=True),
        NORMAL=w.accessor(nrm, "VEC3", target=g.ARRAY_BUFFER),
    )
    prim = g.Primitive(attributes=attrs, indices=w.accessor(idx, "SCALAR", g.UNSIGNED_INT, g.ELEMENT_ARRAY_BUFFER), material=grey)
    w.doc.meshes.append(g.Mesh(name="drum", primitives=[prim]))
    w.node(name="drum", mesh=len(w.doc.meshes) - 1)
    lamp = w.material("panel", [0.0, 0.0, 0.0], emission=[20.0, 20.0, 20.0])
    panel = [[[-0.5, 2.0, 0.5], [0.5, 2.0, 0.5], [0.5, 2.0, 1.5], [-0.5, 2.0, 1.5]]]
    w.node(name="panel", mesh=w.mesh("panel", panel, lamp))
    w.save(out_path)


def obj_from_toml(scene_path, out_path):
    scene = tomllib.loads(scene_path.read_text())
    lines, mtl, v = ["mtllib %s" % out_path.with_suffix(".mtl").name], [], 0
    for m in scene["material"]:
        mtl += ["newmtl " + m["name"], "Kd %g %g %g" % tuple(m["reflectance"]), "Ks 0 0 0"]
    for s in scene["surface"]:
        name = s["material"]
        if "emission" in s:
            name += "_emitter"
            m = next(m for m in scene["material"] if m["name"] == s["material"])
            mtl += ["newmtl " + name, "Kd %g %g %g" % tuple(m["reflectance"]), "Ke %.9g %.9g %.9g" % tuple(s["emission"])]
        lines += ["o " + s["name"], "usemtl " + name]
        for q in surface_quads(s):
            lines += ["v %.9g %.9g %.9g" % tuple(p) for p in q]
            lines.append("f %d %d %d %d" % (v + 1, v + 2, v + 3, v + 4))
            v += 4
    out_path.parent.mkdir(parents=True, exist_ok=True)
    out_path.write_text("\n".join(lines) + "\n")
    out_path.with_suffix(".mtl").write_text("\n".join(mtl) + "\n")


def obj_textured(out_path):
    from PIL import Image

    Image.frombytes("RGB", (2, 2), bytes([255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255])).save(out_path.parent / "checker.png")
    out_path.with_suffix(".mtl").write_text(
        "newmtl checker\nKd 0.8 0.8 0.8\nmap_Kd -s 1 1 1 checker.png\n"
        "newmtl steel\nKd 0 0 0\nKs 0.9 0.9 0.9\nNs 48\n"
        "newmtl lamp\nKd 0 0 0\nKe 5 5 5\n"
    )
    out_path.write_text(
        "mtllib textured.mtl\n"
        "o floor\nusemtl checker\n"
        "v -2 0 2\nv 2 0 2\nv 2 0 -2\nv -2 0 -2\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f 1/1 2/2 3/3 4/4\n"
        "o plate\nusemtl steel\n"
        "v 0 0.5 0\nv 1 0.5 0\nv 1 0.5 -1\nv 0 0.5 -1\nf 5 6 7 8\n"
        "o lamp\nusemtl lamp\n"
        "v -0.5 2 -0.5\nv 0.5 2 -0.5\nv 0.5 2 0.5\nv -0.5 2 0.5\nf 9 10 11 12\n"
    )


if __name__ == "__main__":
    obj_from_toml(ROOT / "scenes" / "cornell_box.toml", ROOT / "tests" / "data" / "obj" / "cornell_box.obj")
    obj_textured(ROOT / "tests" / "data" / "obj" / "textured.obj")
    from_toml(ROOT / "scenes" / "cornell_box.toml", OUT / "cornell_box.glb")
    from_toml(ROOT / "scenes" / "fan_room.toml", OUT / "fan_room.glb")
    features(OUT / "features.gltf")
    smooth(OUT / "smooth.glb")
    for p in sorted(OUT.iterdir()):
        print(p.relative_to(ROOT), p.stat().st_size, "bytes")
