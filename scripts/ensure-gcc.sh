#!/usr/bin/env bash
# The FOCAS library host's tests compile a stand-in library (tests/fwlib/standin.c) with gcc.
exec bash "$(dirname "$0")/ensure-apt-package.sh" "the FOCAS library host tests" gcc gcc libc6-dev
