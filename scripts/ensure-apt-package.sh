#!/usr/bin/env bash
# Install a Debian package where the command the test suite needs is missing and we can (root or sudo);
# otherwise say which tests will be skipped. Never fails: a missing tool is a skip, not a broken set-up.
#   ensure-apt-package.sh "WHAT SKIPS WITHOUT IT" "COMMAND [ALTERNATIVE ...]" PACKAGE [PACKAGE ...]
set -u
skipped=$1 commands=$2
shift 2
for c in $commands; do
  if command -v "$c" >/dev/null 2>&1; then exit 0; fi
done
echo "${commands%% *} not found: trying to install it (Debian/Ubuntu: apt-get install $*)" >&2
apt=(apt-get -o DPkg::Lock::Timeout=900)
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
  ("${apt[@]}" update -qq && DEBIAN_FRONTEND=noninteractive "${apt[@]}" install -y -qq "$@") >&2 && exit 0
elif command -v sudo >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  (sudo "${apt[@]}" update -qq && sudo DEBIAN_FRONTEND=noninteractive "${apt[@]}" install -y -qq "$@") >&2 && exit 0
fi
echo "WARNING: $* is not installed; $skipped will be skipped." >&2
echo "Install it with your package manager (e.g. 'apt-get install $*')." >&2
exit 0
