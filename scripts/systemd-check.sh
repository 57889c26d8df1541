#!/usr/bin/env bash
# make systemd-check: build the .deb, boot a minimal Debian bookworm (cached under .cache/) with systemd as
# PID 1 in systemd-nspawn, install the package there and run scripts/systemd-check-inside.sh: data flows,
# reload, clean stop, journal lines. The container runs on a throwaway copy (--ephemeral) with only a
# loopback network, and is powered off and removed at the end, pass or fail.
set -euo pipefail
cd "$(dirname "$0")/.."
root=.cache/debian-amd64
bash scripts/debian-root.sh amd64 "$root"
command -v systemd-nspawn >/dev/null || apt-get -o DPkg::Lock::Timeout=900 install -y systemd-container
deb=$(bash scripts/build-deb.sh | tail -n 1)
name=focas-check-$$
log=build/systemd-check-console.log
mkdir -p build
systemd-nspawn --quiet --register=no --keep-unit --ephemeral --boot --private-network --machine="$name" -D "$root" \
    --bind-ro="$PWD/dist:/mnt/dist" --bind-ro="$PWD/scripts:/mnt/scripts" >"$log" 2>&1 </dev/null &
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
    [[ -n $leader ]] && nsenter -t "$leader" -a true 2>/dev/null \
        && nsenter -t "$leader" -a systemctl is-system-running --wait >/dev/null 2>&1 && break
    kill -0 "$nspawn" 2>/dev/null || { echo "systemd-nspawn exited:"; cat "$log"; exit 1; }
    sleep 1
done
echo "systemd-check: container $name booted ($(nsenter -t "$leader" -a systemctl --version | head -n 1))"
nsenter -t "$leader" -a env DEB="$(basename "$deb")" bash /mnt/scripts/systemd-check-inside.sh
