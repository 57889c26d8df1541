#!/usr/bin/env bash
# make arm64-check: focas-edge on aarch64, emulated. Registers qemu-aarch64 with binfmt_misc, makes (once,
# cached under .cache/) an arm64 Debian bookworm root, downloads the dependencies' aarch64 wheels, then in a
# throwaway copy of that root (systemd-nspawn --ephemeral, loopback network only) builds the arm64 .deb,
# installs it, and runs mosquitto, the simulator, `probe` and the daemon for 30 s (scripts/arm64-check-inside.sh).
# The .deb lands in dist/; the container and its copy are gone at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
root=.cache/debian-arm64
wheels=.cache/wheels-arm64
bash scripts/binfmt-enable.sh arm64
bash scripts/debian-root.sh arm64 "$root"
command -v systemd-nspawn >/dev/null || apt-get -o DPkg::Lock::Timeout=900 install -y systemd-container
rm -rf build/arm64 && mkdir -p build/arm64/src dist "$wheels"
python3 -m pip wheel --quiet --no-deps -w build/arm64 .
wheel=$(ls build/arm64/focas_edge-*.whl)
# psutil is for the codec bench only (not a runtime dependency: it goes into the throwaway root, not the .deb)
python3 -m pip download --quiet --only-binary=:all: --platform manylinux2014_aarch64 --python-version 3.11 \
    -d "$wheels" "$wheel" psutil
git ls-files -z --cached --others --exclude-standard | tar --null -T - -cf - | tar -xf - -C build/arm64/src
systemd-nspawn --quiet --register=no --keep-unit --ephemeral --private-network -D "$root" \
    --bind-ro="$PWD/build/arm64/src:/src" --bind-ro="$PWD/$wheels:/mnt/wheels" \
    --bind-ro="$PWD/$wheel:/mnt/$(basename "$wheel")" --bind="$PWD/dist:/mnt/dist" \
    --setenv=WHEEL="/mnt/$(basename "$wheel")" /bin/bash /src/scripts/arm64-check-inside.sh
