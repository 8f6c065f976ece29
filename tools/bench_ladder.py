#!/usr/bin/env python3
"""The ladder benchmark (issue 11, item 7): buildings of furnished rooms
(tools/gen_building.py) built and rendered at growing sizes, from ~10^7 to
~10^9 link ends, under memory budgets, with the machine's limits measured
by the same run.

Per rung: archive size, build time, peak RSS (VmHWM, as the command
reports it) and spilled runs; the distribution's time per iteration, link
ends/s and bytes/s of the gather's stream (3 bytes per end: LOTH + LCNT)
with the archive in the page cache, and again with its pages dropped
before every pass (render --evict-each-pass), as fractions of the
sequential memory and disk read rates measured here.

Needs numpy (the memory rate) and matplotlib (the plot): pip install
numpy matplotlib; without them the script runs and says what it skipped.

Rungs need disk: the script checks free space (archive + spilled runs)
and says what it skipped. Large rungs take many minutes: run them once
and record them as a docs/notebook/YYYY-MM-DD-ladder-*.md entry (and
the "Scale ladder" table of docs/PERFORMANCE.md); they are not for CI.

Usage: tools/bench_ladder.py [--rungs 1,2,3,4] [--dir DIR] [--keep]
                             [--plot docs/images/ladder.png] [--threads1]
       tools/bench_ladder.py --replot DIR/ladder.jsonl --plot OUT.png
"""

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release", "illumnet")

# name, rooms (nx, nz), boxes a room, frequency, patch size, ray spacing,
# link ends expected (for the disk check), build budget, render budget
# (below the archive's size: renders stream the link ends, as out of core).
RUNGS = [
    ("1e7", (2, 1), 3, 16, 0.15, 0.075, 1.0e7, "1G", "48M"),
    ("1e8", (3, 3), 3, 16, 0.10, 0.05, 1.2e8, "1G", "400M"),
    ("5e8", (4, 4), 3, 8, 0.036, 0.018, 5.0e8, "1900M", "960M"),
    ("2e9", (4, 4), 3, 16, 0.036, 0.018, 2.0e9, "1900M", "960M"),
]
HOT_BYTES_PER_END = 3  # LOTH (2) + LCNT (1); LRUN adds 8 bytes a run
DISK_BYTES_PER_END = 7.2  # + LDIR (4) and the runs (format 10)
SPILL_BYTES_PER_END = 10  # 8-byte end records and ~1.6 bytes of slot records an end


def run(args, log=None):
    t = time.time()
    p = subprocess.run(args, capture_output=True, text=True)
    wall = time.time() - t
    text = p.stdout + p.stderr
    if log:
        with open(log, "a") as f:
            f.write("$ " + " ".join(args) + "\n" + text + "\n")
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed ({p.returncode}):\n{text}")
    return text, wall


def number(pattern, text, cast=float, default=None):
    m = re.search(pattern, text)
    return cast(m.group(1)) if m else default


def peak_mib(text):
    m = re.search(r"peak memory ([0-9.]+) ([KMG])iB", text)
    if not m:
        return None
    return float(m.group(1)) * {"K": 1 / 1024, "M": 1, "G": 1024}[m.group(2)]


def drop_cache(path):
    fd = os.open(path, os.O_RDONLY)
    try:
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)


def read_rate(path, limit=4 << 30):
    """GB/s of one sequential pass of 16 MiB reads over (up to) `limit` bytes."""
    buf = bytearray(16 << 20)
    n, t = 0, time.time()
    with open(path, "rb", buffering=0) as f:
        while n < limit:
            k = f.readinto(buf)
            if not k:
                break
            n += k
    return n / (time.time() - t) / 1e9


def memory_rate():
    """GB/s summing a 1 GiB array in this process (numpy, one thread), or
    None without numpy."""
    try:
        import numpy as np
    except ImportError:
        return None
    a = np.ones(1 << 27)
    a.sum()
    best = 0.0
    for _ in range(3):
        t = time.time()
        a.sum()
        best = max(best, a.nbytes / (time.time() - t) / 1e9)
    return best


def render(archive, budget, log, extra):
    """One render's distribution: budget None for the default budget (an
    archive that fits it is mapped whole)."""
    limit = ["--memory-budget", budget] if budget else []
    tolerance = [] if "--tolerance" in extra else ["--tolerance", "1e-4"]
    text, wall = run([BIN, "render", "-q", archive, "-o", archive + ".png", "--shading", "inet", "--samples", "1"]
                     + tolerance + limit + extra, log)
    it = number(r"distribution [0-9.]+ s \((\d+) iterations", text, int)
    dist = number(r"distribution ([0-9.]+) s", text)
    rate = number(r"(\d+) M link ends/s", text)
    gather = number(r"gather (\d+) M ends/s", text)
    return {"iterations": it, "distribution_s": dist, "per_iteration_s": dist / it if it else None,
            "ends_per_s": rate * 1e6 if rate else None, "gather_ends_per_s": gather * 1e6 if gather else None,
            "peak_mib": peak_mib(text), "wall_s": wall,
            "streamed": "streamed from disk in windows" in text}


def baseline(work, log):
    """The default Cornell box's gather rate in this run, mapped whole and
    streamed under 48M, with enough iterations (tolerance 1e-9, no
    acceleration) that start-up does not dominate its 0.05 s distribution."""
    archive = os.path.join(work, "cornell_box.inet")
    run([BIN, "build", "-q", os.path.join(ROOT, "scenes", "cornell_box.toml"), "-o", archive], log)
    deep = ["--tolerance", "1e-9", "--max-iterations", "200", "--anderson", "0"]
    out = {"mapped": render(archive, None, log, deep), "streamed": render(archive, "48M", log, deep)}
    os.remove(archive)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rungs", default="1,2,3,4")
    ap.add_argument("--dir", default=os.path.join(ROOT, "ladder-work"))
    ap.add_argument("--keep", action="store_true", help="keep the archives")
    ap.add_argument("--plot", default=None)
    ap.add_argument("--threads1", action="store_true", help="also distribute the largest rung run on one thread")
    ap.add_argument("--replot", metavar="JSONL", help="only plot the results recorded in JSONL (to --plot)")
    a = ap.parse_args()
    if a.replot:
        with open(a.replot) as f:
            plot([json.loads(line) for line in f if line.strip()], a.plot or "ladder.png")
        return
    os.makedirs(a.dir, exist_ok=True)
    log = os.path.join(a.dir, "ladder.log")
    subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=ROOT, check=True)
    mem = memory_rate()
    if mem is None:
        print(f"machine: {os.cpu_count()} cores; sequential memory read not measured (no numpy: pip install numpy)")
    else:
        print(f"machine: {os.cpu_count()} cores; sequential memory read {mem:.1f} GB/s (numpy sum, 1 thread)")
    base = baseline(a.dir, log)
    bm, bs = base["mapped"]["ends_per_s"], base["streamed"]["ends_per_s"]
    gm, gs = base["mapped"]["gather_ends_per_s"], base["streamed"]["gather_ends_per_s"]
    print(f"baseline: default Cornell box {bm / 1e6:.0f} M ends/s mapped (gather {gm / 1e6:.0f}), "
          f"{bs / 1e6:.0f} M ends/s streamed under 48M (gather {gs / 1e6:.0f})")
    results = []
    for i in [int(x) for x in a.rungs.split(",")]:
        name, (nx, nz), furniture, f, patch, rays, ends, build_budget, render_budget = RUNGS[i - 1]
        need = ends * (DISK_BYTES_PER_END + SPILL_BYTES_PER_END) * 1.2
        free = shutil.disk_usage(a.dir).free
        if free < need:
            print(f"rung {name}: skipped, needs ~{need / 1e9:.0f} GB free for the archive and its spilled runs, "
                  f"{free / 1e9:.0f} GB free")
            continue
        scene = os.path.join(a.dir, f"building-{name}.toml")
        archive = os.path.join(a.dir, f"building-{name}.inet")
        run([sys.executable, os.path.join(ROOT, "tools", "gen_building.py"), str(nx), str(nz),
             "--furniture", str(furniture), "-o", scene], log)
        text, wall = run([BIN, "build", "-q", scene, "-o", archive, "--frequency", str(f), "--patch-size", str(patch),
                          "--ray-spacing", str(rays), "--memory-budget", build_budget], log)
        r = {
            "rung": name,
            "rooms": nx * nz,
            "frequency": f,
            "patches": number(r"built \S+: (\d+) patches", text, int),
            "primitives": None,
            "ends": number(r"\((\d+) ends[;)]", text, int),
            "archive_bytes": os.path.getsize(archive),
            "build_s": wall,
            "build_peak_mib": peak_mib(text),
            "build_budget": build_budget,
            "spilled_runs": number(r"spilled (\d+) runs", text, int, 0),
        }
        disk = None
        drop_cache(archive)
        disk = read_rate(archive)
        r["disk_read_gbs"] = disk
        r["cached_read_gbs"] = read_rate(archive)
        r["render_budget"] = render_budget
        r["cached"] = render(archive, render_budget, log, [])
        # Mapped whole when it fits the default budget (the machine's RAM).
        r["mapped"] = render(archive, None, log, [])
        r["baseline"] = base
        r["evicted"] = render(archive, render_budget, log, ["--evict-each-pass"])
        if a.threads1 and i == max(int(x) for x in a.rungs.split(",")):
            r["one_thread"] = render(archive, render_budget, log, ["--threads", "1"])
        for k in ("cached", "evicted", "one_thread"):
            if k in r and r[k]["ends_per_s"]:
                r[k]["hot_gbs"] = r[k]["ends_per_s"] * HOT_BYTES_PER_END / 1e9
        r["memory_read_gbs"] = mem
        results.append(r)
        c, e = r["cached"], r["evicted"]
        print(f"rung {name}: {r['patches']} patches, {r['ends']:.3g} ends, {r['archive_bytes'] / 1e9:.2f} GB; "
              f"build {r['build_s']:.0f} s, peak {r['build_peak_mib']:.0f} MiB ({r['spilled_runs']} runs, "
              f"budget {build_budget}); cached {c['per_iteration_s']:.3f} s/iteration, "
              f"{c['ends_per_s'] / 1e6:.0f} M ends/s ({c['hot_gbs']:.1f} GB/s), peak {c['peak_mib']:.0f} MiB; "
              f"evicted {e['per_iteration_s']:.3f} s/iteration ({e['hot_gbs']:.2f} GB/s of the stream, "
              f"disk {disk:.2f} GB/s); default budget: {r['mapped']['ends_per_s'] / 1e6:.0f} M ends/s "
              f"({'streamed' if r['mapped']['streamed'] else 'mapped'}); against the Cornell box: "
              f"{c['ends_per_s'] / bs:.2f}x streamed, {r['mapped']['ends_per_s'] / bm:.2f}x mapped; gathers alone "
              f"{c['gather_ends_per_s'] / 1e6:.0f} and {r['mapped']['gather_ends_per_s'] / 1e6:.0f} M ends/s: "
              f"{c['gather_ends_per_s'] / gs:.2f}x and {r['mapped']['gather_ends_per_s'] / gm:.2f}x", flush=True)
        with open(os.path.join(a.dir, "ladder.jsonl"), "a") as fjs:
            fjs.write(json.dumps(r) + "\n")
        if not a.keep:
            os.remove(archive)
    if a.plot and results:
        plot(results, a.plot)


def plot(results, path):
    """Log-log time per iteration against link ends, cached and evicted."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("no matplotlib: no plot")
        return
    results = sorted(results, key=lambda r: r["ends"])
    xs = [r["ends"] for r in results]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.loglog(xs, [r["cached"]["per_iteration_s"] for r in results], "o-", label="page-cached (streamed)")
    ax.loglog(xs, [r["evicted"]["per_iteration_s"] for r in results], "s-", label="evicted before each pass")
    lo, hi = min(xs), max(xs)
    ref = results[-1]["cached"]["per_iteration_s"] / xs[-1]
    ax.loglog([lo, hi], [ref * lo, ref * hi], "k:", label="linear in link ends")
    for r in results:
        ax.annotate(f"{r['patches']:,} patches", (r["ends"], r["cached"]["per_iteration_s"]),
                    textcoords="offset points", xytext=(4, -12), fontsize=7)
    ax.set_xlabel("link ends")
    ax.set_ylabel("seconds per distribution iteration")
    ax.set_title("illumnet ladder: buildings of furnished rooms (2 cores)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
