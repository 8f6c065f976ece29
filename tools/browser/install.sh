#!/usr/bin/env bash
# Installs headless Chromium and its WebDriver from Debian's packages
# (chromium, chromium-driver) for the browser test of `illumnet serve`
# (tests/browser.rs, run by tools/browser/test.sh). Does nothing when they
# are there. Needs root (apt-get).
set -euo pipefail
prog=tools/browser/install.sh
say() { echo "$prog: $*" >&2; }
packages=(chromium chromium-driver)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]} == 0)); then
    say "already installed: $(chromium --version 2>/dev/null), $(chromedriver --version 2>/dev/null | cut -d' ' -f1-2)"
    exit 0
fi
[[ $(id -u) == 0 ]] || {
    say "error: installing ${missing[*]} needs root (apt-get install -y ${missing[*]})"
    exit 1
}
say "installing ${missing[*]} with apt-get"
apt=(apt-get -o DPkg::Lock::Timeout=300 install -y -q --no-install-recommends "${missing[@]}")
if ! DEBIAN_FRONTEND=noninteractive "${apt[@]}" >&2; then
    say "apt-get install failed; running apt-get update and trying again"
    apt-get -o DPkg::Lock::Timeout=300 update -q >&2 || true
    DEBIAN_FRONTEND=noninteractive "${apt[@]}" >&2 || {
        say "error: apt-get install ${missing[*]} failed"
        exit 1
    }
fi
say "installed: $(chromium --version 2>/dev/null), $(chromedriver --version 2>/dev/null | cut -d' ' -f1-2)"
