#!/usr/bin/env python3
"""Runs a command and logs its resident memory over time, with its output.

Every INTERVAL seconds it writes one line of the child's VmRSS, RssAnon,
RssFile and VmHWM (MiB, from /proc/PID/status); every line the command prints
is written too, with the same clock. So a peak can be placed in a phase:
a build prints `memory: ...` when tracing ends and `built ...` after writing.
At the end it prints the peak and when it was first reached.

Usage: tools/rss_trace.py [--interval S] LOG -- COMMAND [ARGS...]
Example (docs/notebook/2026-12-05-bounded-build-peaks.md):
  tools/rss_trace.py b4.log -- target/release/illumnet build b.toml \\
      --frequency 16 --patch-size 0.036 --ray-spacing 0.018 --memory-budget 1800M -o b4.inet
"""

import argparse
import subprocess
import sys
import threading
import time


def status(pid):
    """VmRSS, RssAnon, RssFile and VmHWM of `pid` in KiB, or None once it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            fields = dict(line.split(":", 1) for line in f if ":" in line)
    except OSError:
        return None
    kib = lambda k: int(fields.get(k, "0 kB").split()[0])
    return kib("VmRSS"), kib("RssAnon"), kib("RssFile"), kib("VmHWM")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--interval", type=float, default=0.5, help="seconds between samples (default 0.5)")
    ap.add_argument("log", help="where the timeline goes")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND [ARGS...]")
    args = ap.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        ap.error("no command given")
    out = open(args.log, "w")
    lock = threading.Lock()
    t0 = time.monotonic()

    def write(text):
        with lock:
            out.write(f"{time.monotonic() - t0:9.2f} {text}\n")
            out.flush()

    child = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1)

    def pump(stream, tag):
        for line in stream:
            write(f"{tag} {line.rstrip()}")

    pumps = [threading.Thread(target=pump, args=(s, t)) for s, t in ((child.stdout, "OUT"), (child.stderr, "ERR"))]
    for p in pumps:
        p.start()
    peak, peak_at = 0, 0.0
    while child.poll() is None:
        s = status(child.pid)
        if s:
            rss, anon, file, hwm = s
            write(f"MEM rss {rss >> 10} anon {anon >> 10} file {file >> 10} hwm {hwm >> 10} MiB")
            if hwm > peak:
                peak, peak_at = hwm, time.monotonic() - t0
        time.sleep(args.interval)
    for p in pumps:
        p.join()
    write(f"EXIT {child.returncode}")
    print(f"peak {peak >> 10} MiB (VmHWM), first seen at {peak_at:.1f} s; exit {child.returncode}; timeline in {args.log}")
    sys.exit(child.returncode)


if __name__ == "__main__":
    main()
