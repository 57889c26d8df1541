#!/usr/bin/env bash
# The status-page test drives a real headless Chromium; install Debian's chromium where it is missing and we can.
set -u
for p in chromium chromium-browser google-chrome; do
  if command -v "$p" >/dev/null 2>&1; then exit 0; fi
done
echo "chromium not found: trying to install it (Debian/Ubuntu: apt-get install chromium)" >&2
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
  (apt-get -o DPkg::Lock::Timeout=900 update -qq &&
   DEBIAN_FRONTEND=noninteractive apt-get -o DPkg::Lock::Timeout=900 install -y -qq chromium) >&2 && exit 0
elif command -v sudo >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  (sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium) >&2 && exit 0
fi
echo "WARNING: chromium is not installed; the status-page browser test will be skipped." >&2
echo "Install it with your package manager (e.g. 'apt-get install chromium')." >&2
exit 0
