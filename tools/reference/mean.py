#!/usr/bin/env python3
"""The mean of independent references of one scene, and its own noise.

Usage: python3 tools/reference/mean.py A.exr B.exr [C.exr ...] -o MEAN.exr

Each input is a render of the same scene with its own --seed. The mean is
written as a linear float32 OpenEXR (lossless PIZ). Its noise, printed, is
the relative L2 spread of the inputs about the mean over sqrt(n − 1) · sqrt(n)
(for two inputs, half their relative difference), over the pixels whose mean
is below 1.0 in every channel, as `illumnet compare` measures: what an error
measured against the mean carries of the reference's own noise, in quadrature.
"""

import argparse
import math

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="+", help="independent references (different seeds)")
    ap.add_argument("-o", "--output", required=True, help="output .exr")
    a = ap.parse_args()
    if len(a.inputs) < 2:
        ap.error("needs at least two references to estimate the noise")
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    images = [np.array(mi.Bitmap(p), dtype=np.float64)[..., :3] for p in a.inputs]
    if any(i.shape != images[0].shape for i in images):
        ap.error("the references differ in size")
    mean = sum(images) / len(images)
    mask = mean.max(axis=2) < 1.0
    n = len(images)
    spread = sum(((i - mean)[mask] ** 2).sum() for i in images) / (n - 1)
    noise = math.sqrt(spread / n / (mean[mask] ** 2).sum())
    mi.Bitmap(np.ascontiguousarray(mean, dtype=np.float32), pixel_format=mi.Bitmap.PixelFormat.RGB).write(a.output)
    print(f"wrote {a.output}: mean of {n}; its own noise {100 * noise:.2f}% relative L2")


if __name__ == "__main__":
    main()
