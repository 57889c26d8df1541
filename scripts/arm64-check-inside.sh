#!/usr/bin/env bash
# Run inside the emulated arm64 root by scripts/arm64-check.sh (as root, no systemd): build and install the
# arm64 .deb, then mosquitto + simulator + probe + the daemon for 30 s, and the codec bench.
set -uo pipefail
failures=0
pids=()
check() {
    local what=$1; shift
    if "$@" >/tmp/check.out 2>&1; then echo "PASS $what"; else echo "FAIL $what"; sed 's/^/     /' /tmp/check.out; failures=$((failures + 1)); fi
}
wait_port() { local deadline=$((SECONDS + $2)); until (exec 3<>"/dev/tcp/127.0.0.1/$1") 2>/dev/null; do (( SECONDS < deadline )) || return 1; sleep 0.5; done; }
cleanup() { for pid in "${pids[@]}"; do kill "$pid" 2>/dev/null; done; wait 2>/dev/null; }
trap cleanup EXIT

echo "arm64-check: $(uname -m), $(python3 --version), Debian $(cat /etc/debian_version)"
cp -r /src /tmp/src
start=$SECONDS
check "build the arm64 .deb (WHEELHOUSE, no index)" env WHEELHOUSE=/mnt/wheels bash /tmp/src/scripts/build-deb.sh
echo "     built in $((SECONDS - start)) s under emulation"
deb=$(ls /tmp/src/dist/focas-edge_*_arm64.deb)
cp "$deb" /mnt/dist/
check "dpkg -i $(basename "$deb")" dpkg -i "$deb"
check "focas-edge --version" focas-edge --version
check "the venv's python is aarch64" test "$(/opt/focas-edge/bin/python -c 'import platform; print(platform.machine())')" = aarch64
check "pydantic-core is the aarch64 build" bash -c "ls /opt/focas-edge/lib/python3.11/site-packages/pydantic_core/*aarch64*.so"

mosquitto -p 18830 >/tmp/mosquitto.log 2>&1 & pids+=($!)
focas-edge sim --machines 1 --port 18193 >/tmp/sim.log 2>&1 & pids+=($!)
check "mosquitto and the simulator listen" bash -c "$(declare -f wait_port); wait_port 18830 120 && wait_port 18193 120"
check "probe 127.0.0.1:18193" bash -c "focas-edge probe 127.0.0.1:18193 | tee /tmp/probe.out | grep -q 30i"
head -n 4 /tmp/probe.out | sed 's/^/     /'

cat > /tmp/edge.yaml <<'YAML'
mqtt:
  host: 127.0.0.1
  port: 18830
  formats: [sparkplug, json]
  sparkplug: {group_id: arm64, edge_node_id: gw}
state_dir: /tmp/state
machines:
  - id: sim-1
    host: 127.0.0.1
    port: 18193
    poll: {macros: ["500-505"]}
YAML
check "check-config" focas-edge check-config /tmp/edge.yaml
started=$SECONDS
focas-edge run --config /tmp/edge.yaml >/tmp/daemon.log 2>&1 & daemon=$!
check "DDATA arrives" /opt/focas-edge/bin/python /tmp/src/scripts/wait-for-message.py 127.0.0.1 18830 "spBv1.0/arm64/DDATA/gw/sim-1" 120
echo "     first DDATA $((SECONDS - started)) s after start"
while (( SECONDS - started < 30 )) && kill -0 "$daemon" 2>/dev/null; do sleep 1; done
check "daemon still running after 30 s" kill -0 "$daemon"
check "JSON data still flowing at 30 s" /opt/focas-edge/bin/python /tmp/src/scripts/wait-for-message.py 127.0.0.1 18830 "focas/arm64/gw/sim-1/#" 60
kill -TERM "$daemon"; wait "$daemon"; rc=$?
check "SIGTERM: exit 0" test "$rc" = 0
grep -E "started|stopped|ERROR|Traceback" /tmp/daemon.log | sed 's/^/     /'

/opt/focas-edge/bin/python -m pip install --quiet --no-index --find-links /mnt/wheels psutil
echo "--- codec bench (python -m bench codec --quick), emulated aarch64 ---"
(cd /tmp/src && timeout 1800 /opt/focas-edge/bin/python -m bench codec --quick --results /tmp/bench-results) || echo "(codec bench failed)"
echo "arm64-check: $failures failure(s)"
exit $((failures > 0))
