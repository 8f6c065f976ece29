#!/usr/bin/env python3
"""Latency of `illumnet serve`'s page in headless Chromium: from a control's
change to the new light drawn (the page's own clock: the request sent, the
radiance received, uploaded and drawn), median and range over N changes,
beside the server's solve time for each. Started by `tools/browser/test.sh
--bench` (which starts the servers and chromedriver).

    python3 tools/browser/bench_serve.py --webdriver URL --page URL [--fan-page URL] [--changes N]
"""
import argparse
import statistics
import sys

sys.path.insert(0, __import__("os").path.dirname(__file__))
from test_serve import SET, VERSION, Browser, solved_after  # noqa: E402


def measure(b, page, what, change, n):
    b.go(page)
    version = b.wait(VERSION, f"{what}: the first solution drawn")
    b.js("window.illumnet.latencies = []")
    solves = []
    for i in range(n):
        change(b, i)
        version = solved_after(b, version, f"{what}: change {i}")
        b.wait(f"return window.illumnet.latencies.length > {i}", f"{what}: change {i} drawn")
        solves.append(b.js("return window.illumnet.status.solve_ms"))
    lat = b.js("return window.illumnet.latencies")
    print(f"{what}: {n} changes: change to drawn median {statistics.median(lat):.1f} ms "
          f"({min(lat):.1f}–{max(lat):.1f}); solve median {statistics.median(solves):.1f} ms "
          f"({min(solves):.1f}–{max(solves):.1f})")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--webdriver", required=True)
    ap.add_argument("--page", required=True)
    ap.add_argument("--fan-page")
    ap.add_argument("--changes", type=int, default=20)
    ap.add_argument("--extra-page", help="a page of another archive (BENCH_ARCHIVE): its first emitter")
    ap.add_argument("--screenshot", help="also save the Cornell box's page as this PNG")
    a = ap.parse_args()
    b = Browser(a.webdriver)
    try:
        measure(b, a.page, "Cornell box, lamp intensity",
                lambda b, i: b.js(SET, 'input[data-surface="light"]', str(1.0 + 0.5 * ((i + 1) % 2))), a.changes)
        if a.screenshot:
            b.screenshot(a.screenshot)
        if a.extra_page:
            measure(b, a.extra_page, "extra archive, first emitter's intensity",
                    lambda b, i: b.js(SET, "input[data-surface]", str(1.0 + 0.5 * ((i + 1) % 2))), a.changes)
        if a.fan_page:
            measure(b, a.fan_page, "fan room, frame scrub",
                    lambda b, i: b.js(SET, "#frame", str((7 * (i + 1)) % 60)), a.changes)
    finally:
        b.close()


if __name__ == "__main__":
    main()
