#!/usr/bin/env python3
"""Path-traced reference renderer for illumnet scenes, using Mitsuba 3.

Reads an illumnet TOML scene, converts it to a Mitsuba 3 scene and renders
a linear-RGB float32 OpenEXR image (PIZ-compressed, lossless).

Usage:
    python3 tools/reference/reference.py SCENE.toml -o OUT.exr \
        [--spp N] [--pass-spp N] [--seed S] \
        [--variant llvm_ad_rgb|scalar_rgb] [--max-depth -1] [--png OUT.png] \
        [--compare REF.exr]

See tools/reference/README.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import tomllib

LLVM_DEFAULT = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
if "DRJIT_LIBLLVM_PATH" not in os.environ and os.path.exists(LLVM_DEFAULT):
    os.environ["DRJIT_LIBLLVM_PATH"] = LLVM_DEFAULT

import numpy as np  # noqa: E402


class SceneError(Exception):
    pass


# --------------------------------------------------------------------------
# Scene parsing (independent of Mitsuba)
# --------------------------------------------------------------------------

def _vec3(value, what):
    try:
        v = [float(x) for x in value]
    except TypeError:
        raise SceneError(f"{what}: expected a list of 3 numbers, got {value!r}")
    if len(v) != 3:
        raise SceneError(f"{what}: expected 3 numbers, got {len(v)}")
    return v


def _quad(value, what):
    if not isinstance(value, list) or len(value) != 4:
        raise SceneError(f"{what}: a quad must be a list of 4 vertices")
    return [_vec3(p, f"{what} vertex {i}") for i, p in enumerate(value)]


def _load_obj(path, what):
    """Vertices and triangles of a Wavefront OBJ (`v` and `f` lines; polygons
    as fans from their first corner, as illumnet's loader triangulates)."""
    verts, faces = [], []
    try:
        lines = open(path).read().splitlines()
    except OSError as e:
        raise SceneError(f"{what}: cannot read {path}: {e}")
    for line in lines:
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "v":
            verts.append([float(x) for x in parts[1:4]])
        elif parts[0] == "f":
            idx = [int(c.split("/")[0]) for c in parts[1:]]
            idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
            faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
    if not faces:
        raise SceneError(f"{what}: {path} has no faces")
    return np.asarray(verts, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def _face_tangents(verts, faces, first_edge, grain):
    """Per face, the unit grain direction in its plane (format-spec/scene.md:
    the surface's `grain`, else the primitive's first edge, projected onto
    the face's plane)."""
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    n = np.cross(b - a, c - a)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    g = first_edge if grain is None else np.broadcast_to(grain, n.shape)
    t = g - n * np.sum(g * n, axis=1, keepdims=True)
    norm = np.linalg.norm(t, axis=1, keepdims=True)
    if np.any(norm < 1e-9):
        raise SceneError("a grain is perpendicular to a face it lies on")
    return t / norm


def _transform(verts, faces, t, what, first_edge=None, grain=None):
    """`p' = translate + Rz·Ry·Rx·(scale ⊙ p)` (format-spec/scene.md); a
    mirroring scale reverses the winding so fronts stay on the same side.
    Directions (`first_edge` per face, `grain`) are scaled and rotated too
    when given, and then returned as well."""
    scale = np.asarray(_vec3(t.get("scale", [1, 1, 1]), f"{what}.scale"))
    rx, ry, rz = np.radians(_vec3(t.get("rotate_deg", [0, 0, 0]), f"{what}.rotate_deg"))
    translate = np.asarray(_vec3(t.get("translate", [0, 0, 0]), f"{what}.translate"))
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    r_x = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    r_y = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    r_z = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    rot = r_z @ r_y @ r_x
    verts = (verts * scale) @ rot.T + translate
    if np.prod(scale) < 0:
        faces = faces[:, ::-1]
    if first_edge is None and grain is None:
        return verts, faces
    first_edge = (first_edge * scale) @ rot.T
    if grain is not None:
        grain = (np.asarray(grain) * scale) @ rot.T
    return verts, faces, first_edge, grain


def load_scene(path):
    """Parse the TOML scene into a plain description (dicts and lists)."""
    with open(path, "rb") as f:
        doc = tomllib.load(f)

    if "camera" not in doc:
        raise SceneError("scene has no [camera] table")
    c = doc["camera"]
    for key in ("position", "look_at", "up", "fov_y_deg", "width", "height"):
        if key not in c:
            raise SceneError(f"[camera] is missing '{key}'")
    camera = {
        "position": _vec3(c["position"], "camera.position"),
        "look_at": _vec3(c["look_at"], "camera.look_at"),
        "up": _vec3(c["up"], "camera.up"),
        "fov_y_deg": float(c["fov_y_deg"]),
        "width": int(c["width"]),
        "height": int(c["height"]),
    }

    materials = {}
    for m in doc.get("material", []):
        name = m.get("name")
        if name is None:
            raise SceneError("a [[material]] has no 'name'")
        if name in materials:
            raise SceneError(f"material '{name}' is defined twice")
        mtype = m.get("type")
        if mtype not in ("diffuse", "rough_conductor", "broad_specular"):
            raise SceneError(
                f"material '{name}': unsupported type {mtype!r} "
                "(the reference tool supports 'diffuse', 'rough_conductor' and 'broad_specular')")
        mat = {"type": mtype}
        if mtype in ("diffuse", "broad_specular"):
            mat["reflectance"] = _vec3(m.get("reflectance"), f"material '{name}'.reflectance")
        if mtype in ("rough_conductor", "broad_specular"):
            mat["specular"] = _vec3(m.get("specular"), f"material '{name}'.specular")
            if "ior" in m:
                raise SceneError(
                    f"material '{name}': 'ior' (Schlick Fresnel) has no exact Mitsuba equivalent; "
                    "the reference tool supports Fresnel = 1 only")
            if "alpha" in m:
                au = av = float(m["alpha"])
            else:
                au, av = float(m.get("alpha_u", 0)), float(m.get("alpha_v", 0))
            # Anisotropic roughness runs along each surface's grain: the
            # meshes then get texture coordinates whose u axis is the grain
            # (Mitsuba's shading tangent is dp/du).
            mat["alpha_u"], mat["alpha_v"] = au, av
        materials[name] = mat

    surfaces = []
    known_geometry = ("quad", "quads", "mesh")
    base = os.path.dirname(os.path.abspath(path))
    for s in doc.get("surface", []):
        name = s.get("name", f"surface#{len(surfaces)}")
        mat = s.get("material")
        if mat is None:
            raise SceneError(f"surface '{name}' has no 'material'")
        if mat not in materials:
            raise SceneError(f"surface '{name}': unknown material '{mat}'")
        geo = [k for k in known_geometry if k in s]
        others = [k for k in s if k not in ("name", "material", "emission", "grain", "transform") + known_geometry]
        if others:
            raise SceneError(
                f"surface '{name}': unsupported key(s) {others} "
                "(the reference tool supports 'quad', 'quads' and 'mesh' geometry with a 'transform')")
        if len(geo) != 1:
            raise SceneError(f"surface '{name}' needs exactly one of 'quad', 'quads' or 'mesh'")
        if geo[0] == "mesh":
            verts, faces = _load_obj(os.path.join(base, s["mesh"]), f"surface '{name}'.mesh")
        else:
            if geo[0] == "quad":
                quads = [_quad(s["quad"], f"surface '{name}'.quad")]
            else:
                if not isinstance(s["quads"], list) or not s["quads"]:
                    raise SceneError(f"surface '{name}'.quads must be a non-empty list")
                quads = [_quad(q, f"surface '{name}'.quads[{i}]") for i, q in enumerate(s["quads"])]
            verts = np.asarray(quads, dtype=np.float64).reshape(-1, 3)
            # Each quad as the triangles (v0, v1, v2), (v0, v2, v3).
            faces = np.asarray([[4 * q + i for i in t] for q in range(len(quads)) for t in ((0, 1, 2), (0, 2, 3))])
        # Per face, its primitive's first edge (the default grain): a
        # quad's corner 0 -> 1 for both its triangles.
        first_edge = verts[faces[:, 1]] - verts[faces[:, 0]]
        if geo[0] != "mesh":
            first_edge[1::2] = first_edge[0::2]
        grain = s.get("grain")
        verts, faces, first_edge, grain = _transform(
            verts, faces, s.get("transform", {}), f"surface '{name}'.transform",
            first_edge, None if grain is None else _vec3(grain, f"surface '{name}'.grain"))
        emission = None
        if "emission" in s:
            emission = _vec3(s["emission"], f"surface '{name}'.emission")
        tangents = None
        m = materials[mat]
        if m["type"] != "diffuse" and m["alpha_u"] != m["alpha_v"]:
            tangents = _face_tangents(verts, faces, first_edge, grain)
        surfaces.append({"name": name, "material": mat, "verts": verts, "faces": faces, "emission": emission,
                         "tangents": tangents})

    if not surfaces:
        raise SceneError("scene has no [[surface]]")
    return {"camera": camera, "materials": materials, "surfaces": surfaces}


# --------------------------------------------------------------------------
# Conversion to Mitsuba
# --------------------------------------------------------------------------

def _make_mesh(mi, dr, surf, bsdf):
    verts = np.asarray(surf["verts"], dtype=np.float64)
    faces = np.asarray(surf["faces"], dtype=np.int64)
    uv = None
    if surf.get("tangents") is not None:
        # Anisotropic: every face its own corners, with u along its grain
        # and v across it (u = p·t, v = p·(n × t)), so that Mitsuba's
        # shading tangent dp/du is the grain.
        t = surf["tangents"]
        corners = verts[faces]                                  # (F, 3, 3)
        n = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        b = np.cross(n, t)
        uv = np.stack([np.einsum("fkc,fc->fk", corners, t), np.einsum("fkc,fc->fk", corners, b)], axis=-1)
        verts = corners.reshape(-1, 3)
        faces = np.arange(len(verts)).reshape(-1, 3)
        uv = uv.reshape(-1, 2)
    verts = verts.astype(np.float32)
    faces = faces.astype(np.uint32)

    props = mi.Properties()
    props["bsdf"] = bsdf
    if surf["emission"] is not None:
        props["emitter"] = mi.load_dict({
            "type": "area",
            "radiance": {"type": "rgb", "value": surf["emission"]},
        })
    mesh = mi.Mesh(surf["name"], len(verts), len(faces), props=props,
                   has_vertex_normals=False, has_vertex_texcoords=uv is not None)
    params = mi.traverse(mesh)
    # Buffer types differ between variants (e.g. mi.Float vs dr.scalar.ArrayXf).
    params["vertex_positions"] = type(params["vertex_positions"])(verts.ravel())
    params["faces"] = type(params["faces"])(faces.ravel())
    if uv is not None:
        params["vertex_texcoords"] = type(params["vertex_texcoords"])(uv.astype(np.float32).ravel())
    params.update()
    return mesh


def _bsdf(m, scale=1.0):
    """Mitsuba BSDF dict for an illumnet material (format-spec/scene.md)."""
    if m["type"] == "diffuse":
        return {"type": "diffuse",
                "reflectance": {"type": "rgb", "value": [scale * x for x in m["reflectance"]]}}
    conductor = {
        "type": "roughconductor",
        "material": "none",          # Fresnel = 1
        "distribution": "ggx",
        "alpha_u": m["alpha_u"],
        "alpha_v": m["alpha_v"],
        "sample_visible": True,
        "specular_reflectance": {"type": "rgb", "value": [scale * x for x in m["specular"]]},
    }
    if m["type"] == "rough_conductor":
        return conductor
    # broad_specular = k_d/pi + k_s * lobe = 0.5 * (2 k_d/pi) + 0.5 * (2 k_s * lobe).
    return {
        "type": "blendbsdf",
        "weight": 0.5,
        "bsdf_0": _bsdf({"type": "diffuse", "reflectance": m["reflectance"]}, 2.0),
        "bsdf_1": dict(conductor, specular_reflectance={
            "type": "rgb", "value": [2.0 * x for x in m["specular"]]}),
    }


def build_mitsuba_scene(mi, dr, scene, max_depth):
    cam = scene["camera"]
    # Mitsuba's look_at (camera space +Z = forward, +Y = up, +X = up x forward,
    # with the image x axis running along -X) gives image right =
    # forward x up, the same as illumnet's convention. Verified on the
    # Cornell box: the red wall (x = 0.556) is on the left of the image.
    to_world = mi.ScalarTransform4f().look_at(
        origin=cam["position"], target=cam["look_at"], up=cam["up"])
    d = {
        "type": "scene",
        "integrator": {
            "type": "path",
            "max_depth": int(max_depth),
            "hide_emitters": False,
        },
        "sensor": {
            "type": "perspective",
            "fov": cam["fov_y_deg"],
            "fov_axis": "y",
            "to_world": to_world,
            "sampler": {"type": "independent", "sample_count": 1},
            "film": {
                "type": "hdrfilm",
                "width": cam["width"],
                "height": cam["height"],
                "pixel_format": "rgb",
                "component_format": "float32",
                "rfilter": {"type": "box"},
            },
        },
    }
    bsdfs = {}
    for name, m in scene["materials"].items():
        bsdfs[name] = mi.load_dict(_bsdf(m))
    for i, surf in enumerate(scene["surfaces"]):
        d[f"surface_{i}"] = _make_mesh(mi, dr, surf, bsdfs[surf["material"]])
    return mi.load_dict(d)


# --------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------

def render(mi, dr, mscene, spp, pass_spp, seed, log=True):
    """Render `spp` samples per pixel in passes of `pass_spp` with distinct
    seeds and return the average as a float64 numpy array (H, W, 3)."""
    acc = None
    done = 0
    p = 0
    t0 = time.time()
    while done < spp:
        n = min(pass_spp, spp - done)
        s = seed * 100003 + p  # distinct seed per pass
        img = mi.render(mscene, spp=n, seed=s)
        arr = np.array(img, dtype=np.float64)[..., :3]
        acc = arr * n if acc is None else acc + arr * n
        done += n
        p += 1
        if log:
            el = time.time() - t0
            print(f"  pass {p}: {done}/{spp} spp, {el:.1f} s "
                  f"({done * arr.shape[0] * arr.shape[1] / max(el, 1e-9) / 1e6:.2f} Msamples/s)",
                  file=sys.stderr, flush=True)
    return acc / spp


def write_exr(mi, img, path):
    bmp = mi.Bitmap(np.ascontiguousarray(img, dtype=np.float32),
                    pixel_format=mi.Bitmap.PixelFormat.RGB)
    bmp.write(path)  # default quality -1: lossless PIZ compression


def write_png(mi, img, path):
    x = np.clip(img, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    u8 = np.clip(np.round(srgb * 255.0), 0, 255).astype(np.uint8)
    bmp = mi.Bitmap(np.ascontiguousarray(u8), pixel_format=mi.Bitmap.PixelFormat.RGB)
    bmp.write(path)


def read_exr(mi, path):
    return np.array(mi.Bitmap(path), dtype=np.float64)[..., :3]


def relative_l2(img, ref):
    """||img - ref||_2 / ||ref||_2 over all RGB values of the pixels whose
    reference max channel is < 1.0 (directly seen emitters are excluded)."""
    mask = ref.max(axis=-1) < 1.0
    a, r = img[mask], ref[mask]
    return float(np.linalg.norm(a - r) / np.linalg.norm(r)), int(mask.sum())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="illumnet TOML scene")
    ap.add_argument("-o", "--output", required=True, help="output .exr (linear RGB, float32)")
    ap.add_argument("--spp", type=int, default=1024, help="samples per pixel (default 1024)")
    ap.add_argument("--pass-spp", type=int, default=1024,
                    help="samples per pixel per pass; passes use distinct seeds and are averaged")
    ap.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    ap.add_argument("--variant", default="llvm_ad_rgb", choices=["llvm_ad_rgb", "scalar_rgb"])
    ap.add_argument("--max-depth", type=int, default=-1,
                    help="path integrator max_depth (-1 = unbounded, the default)")
    ap.add_argument("--png", help="also write an sRGB preview PNG (clamped at 1)")
    ap.add_argument("--compare", metavar="REF.exr",
                    help="after rendering, print the relative L2 error against REF.exr "
                         "(pixels whose reference max channel is < 1)")
    args = ap.parse_args(argv)
    if args.spp < 1 or args.pass_spp < 1:
        ap.error("--spp and --pass-spp must be >= 1")

    try:
        scene = load_scene(args.scene)
    except (SceneError, tomllib.TOMLDecodeError, OSError) as e:
        print(f"error: {args.scene}: {e}", file=sys.stderr)
        return 2

    import drjit as dr
    import mitsuba as mi
    try:
        mi.set_variant(args.variant)
    except Exception as e:  # e.g. LLVM not found
        print(f"error: cannot use Mitsuba variant {args.variant}: {e}\n"
              "For llvm_ad_rgb install libllvm19 (apt-get install libllvm19) or set "
              "DRJIT_LIBLLVM_PATH; or use --variant scalar_rgb.", file=sys.stderr)
        return 2

    mscene = build_mitsuba_scene(mi, dr, scene, args.max_depth)
    t0 = time.time()
    img = render(mi, dr, mscene, args.spp, args.pass_spp, args.seed)
    el = time.time() - t0
    write_exr(mi, img, args.output)
    if args.png:
        write_png(mi, img, args.png)
    print(f"wrote {args.output}: {img.shape[1]}x{img.shape[0]}, {args.spp} spp, "
          f"{el:.1f} s, variant {args.variant}, max_depth {args.max_depth}", file=sys.stderr)
    if args.compare:
        ref = read_exr(mi, args.compare)
        if ref.shape != img.shape:
            print(f"error: {args.compare} is {ref.shape}, render is {img.shape}", file=sys.stderr)
            return 1
        err, n = relative_l2(img, ref)
        print(f"relative L2 error vs {args.compare}: {err:.5f} "
              f"({n} of {ref.shape[0] * ref.shape[1]} pixels)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
