#!/usr/bin/env bash
# Installs headless Chromium and its WebDriver from Debian's packages
# (chromium, chromium-driver) for the browser test of `illumnet serve`
# (tools/browser/test.sh). Does nothing when they are there. Needs root
# (apt-get).
set -euo pipefail
cd "$(dirname "$0")/../.."
bash tools/apt-install.sh tools/browser/install.sh chromium chromium-driver
echo "tools/browser/install.sh: $(chromium --version 2>/dev/null), $(chromedriver --version 2>/dev/null | cut -d' ' -f1-2)" >&2
