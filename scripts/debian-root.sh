#!/usr/bin/env bash
# Build (once) a minimal Debian bookworm root for ARCH under DIR, cached: a second call returns at once.
# Used by `make systemd-check` (amd64, booted with systemd-nspawn) and `make arm64-check` (arm64 under
# qemu-user-static). The mirror is the one this machine's apt uses.
set -euo pipefail
arch=${1:?usage: debian-root.sh ARCH DIR}
dir=${2:?usage: debian-root.sh ARCH DIR}
mirror=${DEBIAN_MIRROR:-$(grep -rhoE '^URIs: *http[^ ]*/debian$' /etc/apt/sources.list.d/ 2>/dev/null | head -1 | awk '{print $2}')}
mirror=${mirror:-http://deb.debian.org/debian}
packages=python3,python3-venv,mosquitto,adduser,procps,ca-certificates
[[ $arch == amd64 ]] && packages=$packages,systemd,systemd-sysv,dbus

if [[ -f $dir/.complete ]]; then
    echo "debian-root: cached $arch root at $dir"
    exit 0
fi
command -v debootstrap >/dev/null \
    || apt-get -o DPkg::Lock::Timeout=900 install -y debootstrap systemd-container qemu-user-static
if [[ $arch != "$(dpkg --print-architecture)" ]]; then
    bash "$(dirname "$0")/binfmt-enable.sh" "$arch"
fi
rm -rf "$dir"
mkdir -p "$(dirname "$dir")"
echo "debian-root: debootstrap $arch bookworm from $mirror into $dir (a few minutes, once)"
debootstrap --arch="$arch" --variant=minbase --include="$packages" bookworm "$dir" "$mirror"
touch "$dir/.complete"
