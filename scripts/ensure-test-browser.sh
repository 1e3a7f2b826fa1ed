#!/usr/bin/env bash
# Installs the headless browser that the tests of hd view's pages drive (Debian/Ubuntu: chromium and
# chromium-driver, about 380 MB), where it is missing. `make test` runs it; `make demo` does not
# need it. Where apt-get is not available the browser tests skip, saying what is missing.
set -euo pipefail
if command -v chromedriver >/dev/null 2>&1 && { command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; }; then
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "hd test set-up: Chromium and chromedriver are missing and apt-get is not available: the browser tests of hd view will skip." >&2
    exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "hd test set-up: installing chromium and chromium-driver (the browser tests of hd view)"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium chromium-driver >/dev/null
