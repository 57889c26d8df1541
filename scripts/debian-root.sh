#!/usr/bin/env bash
# Build (once) a minimal Debian bookworm root for ARCH under DIR (debootstrap --variant=minbase) with the
# comma-separated PACKAGES on top, cached: a second call with the same packages returns at once.
#   make systemd-check: amd64 with only systemd (no python3, no adduser: the .deb's Depends must bring them)
#   make arm64-check:   arm64 with what building the .deb inside needs (the default PACKAGES)
# The mirror is the one this machine's apt uses.
set -euo pipefail
arch=${1:?usage: debian-root.sh ARCH DIR [PACKAGES]}
dir=${2:?usage: debian-root.sh ARCH DIR [PACKAGES]}
packages=${3:-python3,python3-venv,mosquitto,adduser,procps,ca-certificates}
mirror=${DEBIAN_MIRROR:-$(grep -rhoE '^URIs: *http[^ ]*/debian$' /etc/apt/sources.list.d/ 2>/dev/null | head -1 | awk '{print $2}')}
mirror=${mirror:-http://deb.debian.org/debian}
stamp="$arch bookworm minbase $packages"

if [[ -f $dir/.complete && $(cat "$dir/.complete") == "$stamp" ]]; then
    echo "debian-root: cached $arch root at $dir ($packages)"
    exit 0
fi
command -v debootstrap >/dev/null \
    || apt-get -o DPkg::Lock::Timeout=900 install -y debootstrap systemd-container qemu-user-static
if [[ $arch != "$(dpkg --print-architecture)" ]]; then
    bash "$(dirname "$0")/binfmt-enable.sh" "$arch"
fi
rm -rf "$dir"
mkdir -p "$(dirname "$dir")"
echo "debian-root: debootstrap $arch bookworm from $mirror into $dir with $packages (a few minutes, once)"
debootstrap --arch="$arch" --variant=minbase --include="$packages" bookworm "$dir" "$mirror"
echo "$stamp" > "$dir/.complete"
