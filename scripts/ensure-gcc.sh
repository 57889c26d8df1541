#!/usr/bin/env bash
# The FOCAS library host's tests compile a stand-in library (tests/fwlib/standin.c) with gcc; install gcc
# where it is missing and we can. Without it those tests skip, saying so.
set -u
if command -v gcc >/dev/null 2>&1; then exit 0; fi
echo "gcc not found: trying to install it (Debian/Ubuntu: apt-get install gcc libc6-dev)" >&2
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
  (apt-get -o DPkg::Lock::Timeout=900 update -qq && DEBIAN_FRONTEND=noninteractive \
     apt-get -o DPkg::Lock::Timeout=900 install -y -qq gcc libc6-dev) >&2 && exit 0
elif command -v sudo >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  (sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq gcc libc6-dev) >&2 \
     && exit 0
fi
echo "WARNING: gcc is not installed; the FOCAS library host tests will be skipped." >&2
exit 0
