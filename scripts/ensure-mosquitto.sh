#!/usr/bin/env bash
# The integration tests start their own mosquitto (elsewhere: 'brew install mosquitto' or 'dnf install mosquitto').
exec bash "$(dirname "$0")/ensure-apt-package.sh" "integration tests that need a broker" \
  "mosquitto /usr/sbin/mosquitto /usr/local/sbin/mosquitto" mosquitto
