#!/usr/bin/env python3
"""The brushed plate of issue 12 against Mitsuba 3, in one run.

For each turn of the plate about its normal (default 0, 45, 67.5, 90
degrees): writes the turned scene (tests/data/brushed_metal.toml turned as
`illumnet build --turn plate=DEG` turns it), renders two independent
Mitsuba references (different seeds) whose mean is the reference and whose
difference estimates its own noise, builds and renders with illumnet at
defaults (`--shading direct`, the default, and `--shading inet`, the
paper's per-patch term), and renders Mitsuba at a ladder of samples per
pixel, timing each. Errors are relative L2 over the pixels whose reference
is below 20 in every channel (the highlight counts, the light does not),
each also with the reference's noise removed: sqrt(err^2 - noise^2).

Prints a Markdown table (and writes it with --table FILE). Needs Mitsuba 3
(tools/reference/requirements.txt) and a release build of illumnet.

    python3 tools/brushed_study.py --work /tmp/brushed --table docs/data/brushed.md
"""

import argparse
import math
import os
import re
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(HERE, "reference"))
import reference  # noqa: E402  (tools/reference/reference.py)

LIMIT = 20.0


def turned_scene(text, degrees):
    """The scene with the plate turned about its normal (+y) through its
    centre by `degrees`, as Scene::turn_surface does (a right-handed turn
    about +y: x goes towards -z), grain included."""
    t = math.radians(degrees)
    c, s = math.cos(t), math.sin(t)

    def rot(x, z):
        return c * x + s * z, -s * x + c * z

    m = re.search(r'(name = "plate"\nmaterial = "brushed"\n)quad = \[(.*)\]\ngrain = \[(.*)\]', text)
    corners = [list(map(float, p.split(","))) for p in re.findall(r"\[([^\[\]]+)\]", m.group(2))]
    cx = sum(p[0] for p in corners) / 4
    cz = sum(p[2] for p in corners) / 4
    quad = ", ".join("[%.9f, %.9f, %.9f]" % (cx + rot(p[0] - cx, p[2] - cz)[0], p[1], cz + rot(p[0] - cx, p[2] - cz)[1])
                     for p in corners)
    g = list(map(float, m.group(3).split(",")))
    gx, gz = rot(g[0], g[2])
    new = f"{m.group(1)}quad = [{quad}]\ngrain = [{gx:.9f}, {g[1]:.9f}, {gz:.9f}]"
    return text[:m.start()] + new + text[m.end():]


def rel_l2(img, ref):
    mask = ref.max(axis=-1) < LIMIT
    return float(np.linalg.norm(img[mask] - ref[mask]) / np.linalg.norm(ref[mask]))


def denoised(err, noise):
    return math.sqrt(max(err * err - noise * noise, 0.0))


def run(cmd):
    t = time.perf_counter()
    out = subprocess.run(cmd, check=True, capture_output=True, text=True)
    return time.perf_counter() - t, out.stdout


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", required=True, help="directory for scenes, archives and images")
    ap.add_argument("--angles", default="0,45,67.5,90")
    ap.add_argument("--ref-spp", type=int, default=16384, help="samples per pixel of each of the two references")
    ap.add_argument("--ladder", default="16,64,256,1024,2048,4096", help="Mitsuba samples per pixel to time")
    ap.add_argument("--illumnet", default=os.path.join(ROOT, "target", "release", "illumnet"))
    ap.add_argument("--table", help="also write the Markdown table here")
    args = ap.parse_args()
    os.makedirs(args.work, exist_ok=True)
    import mitsuba as mi
    import drjit as dr
    mi.set_variant("llvm_ad_rgb")
    base = open(os.path.join(ROOT, "tests", "data", "brushed_metal.toml")).read()
    ladder = [int(x) for x in args.ladder.split(",")]
    rows = []
    for deg in [float(a) for a in args.angles.split(",")]:
        tag = f"{deg:g}"
        scene_path = os.path.join(args.work, f"plate_{tag}.toml")
        with open(scene_path, "w") as f:
            f.write(turned_scene(base, deg))
        mscene = reference.build_mitsuba_scene(mi, dr, reference.load_scene(scene_path), -1)
        refs = []
        for seed in (1, 2):
            path = os.path.join(args.work, f"ref_{tag}_s{seed}.exr")
            if not os.path.exists(path):
                img = reference.render(mi, dr, mscene, args.ref_spp, 1024, seed, log=False)
                reference.write_exr(mi, img, path)
            refs.append(reference.read_exr(mi, path))
        ref = 0.5 * (refs[0] + refs[1])
        # Each reference's error is |s1 - s2|/sqrt(2); their mean's, half the difference.
        noise = rel_l2(refs[0], refs[1]) / 2.0
        reference.write_exr(mi, ref, os.path.join(args.work, f"ref_{tag}.exr"))
        archive = os.path.join(args.work, f"plate_{tag}.inet")
        # The first build of a material makes its prototype table (about
        # 0.3 s) and keeps it in the library; later builds read it. Time
        # those: median of three, build and render each a process.
        run([args.illumnet, "-q", "build", scene_path, "-o", archive])
        t_build = sorted(run([args.illumnet, "-q", "build", scene_path, "-o", archive])[0] for _ in range(3))[1]
        ours = {}
        for shading in ("direct", "inet"):
            exr = os.path.join(args.work, f"plate_{tag}_{shading}.exr")
            png = os.path.join(args.work, f"plate_{tag}_{shading}.png")
            cmd = [args.illumnet, "-q", "render", archive, "-o", png, "--exr", exr, "--shading", shading]
            t_render = sorted(run(cmd)[0] for _ in range(3))[1]
            img = reference.read_exr(mi, exr)
            ours[shading] = (rel_l2(img, ref), t_build + t_render)
        # Mitsuba's ladder, in process, scene loaded (the first render
        # compiles its kernels: warm up); median of three.
        mi.render(mscene, spp=1, seed=999)
        mits = []
        for spp in ladder:
            times = []
            for k in range(3):
                t = time.perf_counter()
                img = np.array(mi.render(mscene, spp=spp, seed=12345 + 7 * spp + k), dtype=np.float64)[..., :3]
                times.append(time.perf_counter() - t)
            mits.append((spp, sorted(times)[1], rel_l2(img, ref)))
        # Mitsuba's time for illumnet's error (log-log interpolation along the ladder).
        err = denoised(ours["direct"][0], noise)
        match = None
        for (s0, t0, e0), (s1, t1, e1) in zip(mits, mits[1:]):
            e0d, e1d = denoised(e0, noise), denoised(e1, noise)
            if e0d >= err >= e1d and e0d > e1d > 0:
                f = math.log(e0d / err) / math.log(e0d / e1d)
                match = (s0 * (s1 / s0) ** f, t0 * (t1 / t0) ** f)
        rows.append((deg, noise, ours, mits, match))
        print(f"{tag}°: noise {noise:.4f}, direct {ours['direct'][0]:.4f} in {ours['direct'][1]:.2f} s, "
              f"inet {ours['inet'][0]:.4f}; Mitsuba " +
              ", ".join(f"{s} spp {e:.4f} in {t:.2f} s" for s, t, e in mits), flush=True)
    lines = [
        "| turn | reference noise | illumnet direct (build + render) | illumnet inet | Mitsuba at illumnet's error |",
        "|---|---|---|---|---|",
    ]
    for deg, noise, ours, mits, match in rows:
        d, i = ours["direct"], ours["inet"]
        m = f"{match[0]:.0f} spp, {match[1]:.2f} s" if match else "beyond the ladder"
        lines.append(f"| {deg:g}° | {100 * noise:.2f}% | {100 * denoised(d[0], noise):.2f}% "
                     f"({100 * d[0]:.2f}% raw), {d[1]:.2f} s | {100 * denoised(i[0], noise):.1f}% | {m} |")
    lines += ["", "Mitsuba's ladder (relative L2 with the reference's noise removed, seconds):", "",
              "| turn | " + " | ".join(f"{s} spp" for s in ladder) + " |",
              "|---|" + "---|" * len(ladder)]
    for deg, noise, ours, mits, match in rows:
        lines.append(f"| {deg:g}° | " + " | ".join(f"{100 * denoised(e, noise):.1f}%, {t:.2f} s" for s, t, e in mits)
                     + " |")
    table = "\n".join(lines)
    print(table)
    if args.table:
        with open(args.table, "w") as f:
            f.write(table + "\n")


if __name__ == "__main__":
    main()
