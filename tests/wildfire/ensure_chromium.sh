#!/bin/sh
# Installs Debian's chromium for the wildfire browser tests when it is missing.
# Playwright drives it through executable_path: its own browser download cannot
# work here. Run as root (CI and the developers' machines are), or with sudo.
set -eu
CHROMIUM=/usr/bin/chromium
if [ -x "$CHROMIUM" ]; then
    exit 0
fi
if [ "$(id -u)" -eq 0 ]; then SUDO=""; else SUDO="sudo"; fi
echo "installing Debian's chromium for the browser tests" >&2
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium >/dev/null
test -x "$CHROMIUM"
