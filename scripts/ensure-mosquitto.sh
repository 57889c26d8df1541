#!/usr/bin/env bash
# The integration tests start their own mosquitto; install it where it is missing and we can.
set -u
for p in mosquitto /usr/sbin/mosquitto /usr/local/sbin/mosquitto; do
  if command -v "$p" >/dev/null 2>&1; then exit 0; fi
done
echo "mosquitto not found: trying to install it (Debian/Ubuntu: apt-get install mosquitto)" >&2
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
  (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mosquitto) >&2 && exit 0
elif command -v sudo >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
  (sudo apt-get update -qq && sudo DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mosquitto) >&2 && exit 0
fi
echo "WARNING: mosquitto is not installed; integration tests that need a broker will be skipped." >&2
echo "Install it with your package manager (e.g. 'apt-get install mosquitto' or 'brew install mosquitto')." >&2
exit 0
