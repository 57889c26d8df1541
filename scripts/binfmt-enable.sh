#!/usr/bin/env bash
# Let this machine run ARCH binaries (arm64 by default) through qemu-user-static: mount binfmt_misc and
# register Debian's qemu entry (its F flag loads the interpreter now, so chroots need no copy of it).
set -euo pipefail
arch=${1:-arm64}
case $arch in arm64) qarch=aarch64 ;; *) qarch=$arch ;; esac
command -v qemu-$qarch-static >/dev/null || apt-get -o DPkg::Lock::Timeout=900 install -y qemu-user-static
mountpoint -q /proc/sys/fs/binfmt_misc || mount -t binfmt_misc binfmt_misc /proc/sys/fs/binfmt_misc
if [[ ! -e /proc/sys/fs/binfmt_misc/qemu-$qarch ]]; then
    cat /usr/lib/binfmt.d/qemu-$qarch.conf > /proc/sys/fs/binfmt_misc/register
fi
echo "binfmt: qemu-$qarch $(head -1 /proc/sys/fs/binfmt_misc/qemu-$qarch)"
