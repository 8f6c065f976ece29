#!/usr/bin/env python3
"""The page of `illumnet serve` in headless Chromium, driven over WebDriver
(W3C protocol, plain HTTP to chromedriver; no client library needed).

    python3 tools/browser/test_serve.py --webdriver http://127.0.0.1:PORT \
        --page http://127.0.0.1:PORT2/ [--fan-page http://127.0.0.1:PORT3/]

Checks, on the Cornell box's page: the page loads, solves and draws; the
lamp's intensity control set to 2× makes every patch's radiance 2.00× the
first (to the solver's tolerance: the light is linear in emission) and the
canvas brighter; the red wall's reflectance halved with its sliders takes
more than half of the red wall's red light and some red from the walls
near it; the "render" button's image, shown in the page, is the render
command's (run with the command line it reports) byte for byte, when
--illumnet is given. On the fan room's page (when given): the frame slider at 30 shows
frame 30, its radiance differing from frame 0's and equal to `render
--frames 30`'s solution (`--patch-radiance`) to the solver's tolerance.
Exit 0 only if all hold.
"""
import argparse
import json
import struct
import sys
import time
import urllib.error
import urllib.request


def call(method, url, body=None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=120) as r:
            return json.loads(r.read().decode() or "null")
    except urllib.error.HTTPError as e:
        # WebDriver's error: the script's exception, a missing element…
        fail(f"{method} {url}: {e.code}: {e.read().decode(errors='replace')[:600]}")


class Browser:
    def __init__(self, webdriver):
        caps = {"capabilities": {"alwaysMatch": {"browserName": "chrome", "goog:chromeOptions": {"args": [
            "--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=800,600",
            "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]}}}}
        self.base = webdriver
        self.session = call("POST", f"{webdriver}/session", caps)["value"]["sessionId"]

    def go(self, url):
        call("POST", f"{self.base}/session/{self.session}/url", {"url": url})

    def js(self, script, *args):
        return call("POST", f"{self.base}/session/{self.session}/execute/sync",
                    {"script": script, "args": list(args)})["value"]

    def wait(self, script, what, timeout=60):
        end = time.time() + timeout
        while time.time() < end:
            v = self.js(script)
            if v:
                return v
            time.sleep(0.05)
        fail(f"timed out waiting for {what}; page error: {self.js('return window.illumnet.lastError || null')}")

    def screenshot(self, path):
        import base64
        png = call("GET", f"{self.base}/session/{self.session}/screenshot")["value"]
        with open(path, "wb") as f:
            f.write(base64.b64decode(png))

    def close(self):
        call("DELETE", f"{self.base}/session/{self.session}")


ILLUMNET = None
FAN_ARCHIVE = None


def fail(message):
    print(f"test_serve.py: FAILED: {message}", file=sys.stderr)
    sys.exit(1)


VERSION = "return window.illumnet.status && window.illumnet.radiance && window.illumnet.drawn > 0 " \
          "&& window.illumnet.status.version"
RADIANCE = "return Array.from(window.illumnet.radiance)"
# Mean of the canvas's pixels (RGB, 0-255), drawn into a 2-D canvas.
BRIGHTNESS = """
const c = document.getElementById('canvas');
const o = document.createElement('canvas'); o.width = c.width; o.height = c.height;
const g = o.getContext('2d'); g.drawImage(c, 0, 0);
const d = g.getImageData(0, 0, o.width, o.height).data;
let s = 0; for (let i = 0; i < d.length; i += 4) s += d[i] + d[i + 1] + d[i + 2];
return s / (d.length / 4) / 3;
"""
# Sets an input (found by a CSS selector) and fires its `input` event, as a
# user's drag does.
SET = """
const e = document.querySelector(arguments[0]); e.value = arguments[1];
e.dispatchEvent(new Event('input')); return e.value;
"""


def solved_after(b, version, what, condition="true"):
    return b.wait(f"const s = window.illumnet.status; return s && s.version > {version} && ({condition}) "
                  f"&& window.illumnet.drawn > 0 && s.version", what)


def surfaces_of(page):
    with urllib.request.urlopen(page + "patch-surfaces.bin", timeout=60) as r:
        data = r.read()
    return struct.unpack(f"<{len(data) // 4}I", data)


def cornell(b, page):
    b.go(page)
    v0 = b.wait(VERSION, "the first solution drawn")
    one = b.js(RADIANCE)
    bright0 = b.js(BRIGHTNESS)
    if not bright0 > 1:
        fail(f"the canvas is black ({bright0:.2f})")
    b.js(SET, 'input[data-surface="light"]', "2")
    v1 = solved_after(b, v0, "the lamp at 2×", "s.sets.some(x => x.startsWith('light.emission='))")
    two = b.js(RADIANCE)
    if len(one) != len(two):
        fail("the patch count changed")
    peak = max(one)
    worst, diff, total = 0.0, 0.0, 0.0
    for x, y in zip(one, two):
        err = abs(y - 2 * x)
        worst = max(worst, err / (2e-3 * peak + 1e-2 * x))
        diff += err
        total += 2 * x
    if worst > 1 or diff / total > 1e-3:
        fail(f"the lamp at 2× did not double every patch: relative L1 {diff / total:.2e}, worst {worst:.2f} of the bound")
    bright1 = b.js(BRIGHTNESS)
    if not bright1 > bright0 * 1.05:
        fail(f"the canvas did not get brighter: {bright0:.2f} → {bright1:.2f}")
    print(f"test_serve.py: lamp 2×: radiance 2.00× (relative L1 {diff / total:.1e}), canvas {bright0:.1f} → {bright1:.1f}")

    scene = b.js("return window.illumnet.scene")
    names = [s["name"] for s in scene["surfaces"]]
    red = names.index("red_wall")
    rho = scene["surfaces"][red]["reflectance"]
    for k in range(3):
        b.js(SET, f'[data-albedo="red_wall/{k}"]', str(rho[k] / 2))
    want = f"red_wall.reflectance={rho[0] / 2:g}"
    solved_after(b, v1, "the red wall halved",
                 "s.sets.some(x => x.startsWith('red_wall.reflectance=') && "
                 f"Math.abs(Number(x.split('=')[1].split(',')[0]) - {rho[0] / 2}) < 1e-6 && "
                 f"Math.abs(Number(x.split('=')[1].split(',')[2]) - {rho[2] / 2}) < 1e-6)")
    halved = b.js(RADIANCE)
    surface = surfaces_of(page)

    def red_on(name, r):
        s = names.index(name)
        return sum(r[3 * p] for p in range(len(surface)) if surface[p] == s)

    before, after = red_on("red_wall", two), red_on("red_wall", halved)
    if not after < 0.5 * before:
        fail(f"the red wall's red light {before:.3f} → {after:.3f}: not less than half")
    for wall in ["back_wall", "floor", "ceiling"]:
        x, y = red_on(wall, two), red_on(wall, halved)
        if not y < x:
            fail(f"{wall}'s red light {x:.4f} → {y:.4f}: the red wall reflects less onto it")
    print(f"test_serve.py: red wall halved ({want}…): its red {before:.2f} → {after:.2f}; the walls near it lost red")
    if ILLUMNET:
        render_button(b, page)


def render_button(b, page):
    """The "render" button: the page shows the image, which is the render
    command's for that view and light, byte for byte."""
    import subprocess
    import tempfile
    b.js("document.getElementById('render').click()")
    r = b.wait("return window.illumnet.rendered", "the render button's image", timeout=300)
    b.wait("const i = document.querySelector('#rendered img'); return i && i.complete && i.naturalWidth > 0",
           "the rendered image shown")
    with urllib.request.urlopen(page.rstrip("/") + r["url"], timeout=60) as f:
        served = f.read()
    args = list(r["args"])
    with tempfile.TemporaryDirectory() as d:
        args[args.index("-o") + 1] = f"{d}/cli.png"
        subprocess.run([ILLUMNET, "-q"] + args, check=True, stdout=subprocess.DEVNULL)
        with open(f"{d}/cli.png", "rb") as f:
            cli = f.read()
    if served != cli:
        fail(f"the page's render differs from `{r['command']}`")
    print(f"test_serve.py: render button: {len(served)} bytes, identical to the render command's")


def fan_room(b, page):
    b.go(page)
    v0 = b.wait(VERSION, "the fan room's first solution drawn")
    first = b.js(RADIANCE)
    b.js(SET, "#frame", "30")
    solved_after(b, v0, "frame 30", "s.frame === 30")
    if b.js("return window.illumnet.frame") != 30:
        fail("the radiance shown is not frame 30's")
    thirty = b.js(RADIANCE)
    if thirty == first:
        fail("frame 30's light is frame 0's")
    if not (ILLUMNET and FAN_ARCHIVE):
        print("test_serve.py: the fan room scrubbed to frame 30")
        return
    # What `render --frames 30` solves (frame 30 alone, cold; the page's
    # came warm from frame 0's): the same light to the solver's tolerance.
    import subprocess
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        subprocess.run([ILLUMNET, "render", "-q", FAN_ARCHIVE, "--frames", "30", "--shading", "inet", "--samples", "1",
                        "--size", "16x12", "-o", f"{d}/x.png", "--patch-radiance", f"{d}/r.bin"],
                       check=True, stdout=subprocess.DEVNULL)
        with open(f"{d}/r.bin", "rb") as f:
            data = f.read()
    want = struct.unpack(f"<{len(data) // 4}f", data)
    if len(want) != len(thirty):
        fail(f"render wrote {len(want) // 3} patches, the page has {len(thirty) // 3}")
    peak = max(want)
    diff = total = 0.0
    hidden = 0
    for p in range(len(want) // 3):
        if thirty[3 * p] < 0:
            hidden += 1
            continue
        for c in range(3):
            x, y = want[3 * p + c], thirty[3 * p + c]
            if abs(y - x) > 2e-3 * peak + 1e-2 * x:
                fail(f"frame 30, patch {p}: the page shows {y}, render solved {x}")
            diff += abs(y - x)
            total += x
    if not diff / total < 1e-3 or hidden == 0:
        fail(f"frame 30 against render's: relative L1 {diff / total:.2e}, {hidden} patches hidden")
    print(f"test_serve.py: the fan room at frame 30 is render --frames 30's light (relative L1 {diff / total:.1e}; "
          f"{hidden} absent patches hidden)")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--webdriver", required=True)
    ap.add_argument("--page", required=True)
    ap.add_argument("--fan-page")
    ap.add_argument("--illumnet", help="the binary, to run the render button's command line")
    ap.add_argument("--fan-archive", help="the fan room's archive, to solve frame 30 with `render`")
    a = ap.parse_args()
    global ILLUMNET, FAN_ARCHIVE
    ILLUMNET, FAN_ARCHIVE = a.illumnet, a.fan_archive
    b = Browser(a.webdriver)
    try:
        cornell(b, a.page)
        if a.fan_page:
            fan_room(b, a.fan_page)
    finally:
        b.close()
    print("test_serve.py: passed")


if __name__ == "__main__":
    main()
