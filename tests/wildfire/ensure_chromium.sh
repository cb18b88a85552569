#!/bin/sh
# Installs Debian's chromium for the browser tests when it is missing. Playwright
# drives it through executable_path: its own browser download cannot work here.
# It installs as root, or with password-less sudo; where it cannot, it says so
# and the run goes on: the browser tests then fail, each with what to install.
CHROMIUM=/usr/bin/chromium
if [ -x "$CHROMIUM" ]; then
    exit 0
fi
if [ "$(id -u)" -eq 0 ]; then
    SUDO=""
elif command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then
    SUDO="sudo -n"
else
    SUDO="cannot"
fi
if [ "$SUDO" != cannot ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing Debian's chromium for the browser tests" >&2
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq chromium >/dev/null
fi
if [ ! -x "$CHROMIUM" ]; then
    echo "chromium is missing and could not be installed here (that needs root or" \
         "password-less sudo, and apt-get): the browser tests will fail until" \
         "\`sudo apt-get install chromium\`." >&2
fi
exit 0
