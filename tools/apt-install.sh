#!/usr/bin/env bash
# Installs Debian packages the test scripts need, once: does nothing when
# they are all installed, else apt-get install (no recommends; an update
# and one more try when the first fails). Needs root to install.
#   bash tools/apt-install.sh CALLER PACKAGE...
set -euo pipefail
caller=$1
shift
say() { echo "$caller: $*" >&2; }
missing=()
for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
((${#missing[@]} > 0)) || exit 0
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
