#!/usr/bin/env bash
# The status-page test drives a real headless Chromium.
exec bash "$(dirname "$0")/ensure-apt-package.sh" "the status-page browser test" \
  "chromium chromium-browser google-chrome" chromium
