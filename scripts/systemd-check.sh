#!/usr/bin/env bash
# make systemd-check: build the .deb, boot a minimal Debian bookworm (debootstrap --variant=minbase with only
# systemd added: no python3, no adduser; cached under .cache/) with systemd as PID 1 in systemd-nspawn,
# install the package there with apt (so its Depends must bring everything) and run
# scripts/systemd-check-inside.sh: data flows, reload, clean stop, journal lines, and the refusals (a second
# instance, a root-owned state file, a port clash, a missing credential: exit 2, no restart; a clone with the
# same Sparkplug ids: the identity conflict ERROR in the journal). The container
# runs on a throwaway copy (--ephemeral) with only a loopback network, and is powered off and removed at the
# end, pass or fail.
set -euo pipefail
cd "$(dirname "$0")/.."
root=.cache/debian-amd64
apt_cache=$PWD/.cache/apt-amd64   # the packages apt fetched for the container (it has no network)
bash scripts/debian-root.sh amd64 "$root" systemd,systemd-sysv
command -v systemd-nspawn >/dev/null || apt-get -o DPkg::Lock::Timeout=900 install -y systemd-container
# DEB=FILE checks that package (e.g. a release, to compare) instead of building this checkout's.
if [[ -n ${DEB:-} ]]; then
    deb=dist/$(basename "$DEB")
    mkdir -p dist && { [[ $(realpath "$DEB") == $(realpath -m "$deb") ]] || cp "$DEB" "$deb"; }
else
    deb=$(bash scripts/build-deb.sh | tail -n 1)
fi
# With the root's own apt (on an overlay, the cached root stays untouched), fetch what installing the
# package pulls in, and mosquitto for the checks' broker. The lists and archives land in .cache/apt-amd64.
mkdir -p "$apt_cache/lists/partial" "$apt_cache/archives/partial"
apt_binds=(--bind="$apt_cache/lists:/var/lib/apt/lists" --bind="$apt_cache/archives:/var/cache/apt/archives")
systemd-nspawn --quiet --register=no --keep-unit --volatile=overlay -D "$root" "${apt_binds[@]}" \
    --bind-ro="$PWD/dist:/mnt/dist" /bin/bash -c \
    "apt-get -qq update && apt-get -qq install --download-only -y /mnt/dist/$(basename "$deb") mosquitto" \
    >/dev/null </dev/null
name=focas-check-$$
log=build/systemd-check-console.log
mkdir -p build
systemd-nspawn --quiet --register=no --keep-unit --ephemeral --boot --private-network --machine="$name" -D "$root" \
    "${apt_binds[@]}" --bind-ro="$PWD/dist:/mnt/dist" --bind-ro="$PWD/scripts:/mnt/scripts" >"$log" 2>&1 </dev/null &
nspawn=$!
cleanup() {
    kill -TERM "$nspawn" 2>/dev/null || true   # nspawn --boot: SIGTERM powers the container off cleanly
    for _ in $(seq 60); do kill -0 "$nspawn" 2>/dev/null || break; sleep 0.5; done
    kill -KILL "$nspawn" 2>/dev/null || true
    wait "$nspawn" 2>/dev/null || true
}
trap cleanup EXIT
leader=""
for _ in $(seq 120); do
    leader=$(pgrep -P "$nspawn" | head -n 1 || true)
    # "degraded" is booted too: without dbus (not in the root) systemd-logind cannot start
    [[ -n $leader ]] && nsenter -t "$leader" -a true 2>/dev/null \
        && [[ $(nsenter -t "$leader" -a systemctl is-system-running --wait 2>/dev/null) =~ ^(running|degraded)$ ]] \
        && break
    kill -0 "$nspawn" 2>/dev/null || { echo "systemd-nspawn exited:"; cat "$log"; exit 1; }
    sleep 1
done
echo "systemd-check: container $name booted ($(nsenter -t "$leader" -a systemctl --version | head -n 1))"
nsenter -t "$leader" -a env DEB="$(basename "$deb")" bash /mnt/scripts/systemd-check-inside.sh
