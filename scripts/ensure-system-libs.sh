#!/usr/bin/env bash
# Installs the system libraries hd needs where they are missing (Debian/Ubuntu).
# Open3D's Python wheel links against libusb-1.0.
set -euo pipefail
if ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    exit 0
fi
if ! command -v apt-get >/dev/null 2>&1; then
    echo "hd set-up: libusb-1.0 is missing and apt-get is not available; install libusb-1.0 with your package manager." >&2
    exit 1
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "hd set-up: installing libusb-1.0-0 (needed by Open3D)"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libusb-1.0-0 >/dev/null
