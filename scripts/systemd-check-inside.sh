#!/usr/bin/env bash
# Run inside the booted Debian container by scripts/systemd-check.sh: install the package, start the service
# against two simulated CNCs and the root's mosquitto, and check what an admin would.
set -uo pipefail
failures=0
check() {  # check "what" command...: one PASS/FAIL line per check
    local what=$1; shift
    if "$@" >/tmp/check.out 2>&1; then echo "PASS $what"; else echo "FAIL $what"; sed 's/^/     /' /tmp/check.out; failures=$((failures + 1)); fi
}
wait_until() {  # wait_until SECONDS command...
    local deadline=$((SECONDS + $1)); shift
    until "$@"; do (( SECONDS < deadline )) || return 1; sleep 0.5; done
}
journal_has() { journalctl -u focas-edge --no-pager -o cat | grep -q -- "$1"; }
wait_msg() { /opt/focas-edge/bin/python /mnt/scripts/wait-for-message.py 127.0.0.1 1883 "$1" 60; }
config() {  # config N: the edge.yaml for machines sim-1..sim-N on 127.0.0.1:18193...
    printf 'mqtt:\n  host: 127.0.0.1\n  formats: [sparkplug, json]\n  sparkplug: {group_id: check, edge_node_id: gw}\n  json: {prefix: focas}\nmachines:\n'
    for i in $(seq 1 "$1"); do
        printf '  - id: sim-%d\n    host: 127.0.0.1\n    port: %d\n    poll: {macros: ["500-502"]}\n' "$i" $((18192 + i))
    done
}

wait_until 60 systemctl is-active --quiet mosquitto || { echo "FAIL mosquitto in the container"; exit 1; }
check "dpkg -i the package" dpkg -i /mnt/dist/"$DEB"
check "focas-edge on PATH" focas-edge --version
check "service user and group exist" id focas-edge
check "installed, not enabled" test "$(systemctl is-enabled focas-edge 2>&1)" = disabled
check "installed, not started" test "$(systemctl is-active focas-edge 2>&1)" = inactive
check "/etc/focas-edge is root:focas-edge 0750" test "$(stat -c %U:%G:%a /etc/focas-edge)" = root:focas-edge:750
check "edge.yaml is root:focas-edge 0640" test "$(stat -c %U:%G:%a /etc/focas-edge/edge.yaml)" = root:focas-edge:640

systemd-run --quiet --unit=focas-sim /opt/focas-edge/bin/focas-edge sim --machines 2 --port 18193
wait_until 30 bash -c 'exec 3<>/dev/tcp/127.0.0.1/18194' 2>/dev/null
config 1 > /etc/focas-edge/edge.yaml
check "check-config --as-service passes on the installed config" focas-edge check-config --as-service /etc/focas-edge/edge.yaml
echo "state_dir: /var/lib/other" > /tmp/bad.yaml; config 1 >> /tmp/bad.yaml
check "check-config --as-service refuses a state_dir the unit cannot write" \
    bash -c '! focas-edge check-config --as-service /tmp/bad.yaml && focas-edge check-config --as-service /tmp/bad.yaml 2>&1 | grep -q ProtectSystem'

check "systemctl start" systemctl start focas-edge
check "service active (READY=1 received)" systemctl is-active --quiet focas-edge
check "runs as user focas-edge" test "$(ps -o user= -p "$(systemctl show -p MainPID --value focas-edge)")" = focas-edge
check "journal shows the startup line" wait_until 20 journal_has "started version="
check "JSON data flows (sim-1)" wait_msg "focas/sim-1/#"
check "Sparkplug DDATA flows (sim-1)" wait_msg "spBv1.0/check/DDATA/gw/sim-1"
check "state written to /var/lib/focas-edge" wait_until 20 bash -c 'test -n "$(ls -A /var/lib/focas-edge)"'

config 2 > /etc/focas-edge/edge.yaml
check "systemctl reload (SIGHUP)" systemctl reload focas-edge
check "journal shows the reload" wait_until 20 journal_has "reloaded added=\['sim-2'\]"
check "the machine added by reload publishes (sim-2)" wait_msg "spBv1.0/check/DDATA/gw/sim-2"
check "same process after reload" test "$(systemctl show -p NRestarts --value focas-edge)" = 0

check "systemctl stop" systemctl stop focas-edge
check "stop was clean (exit 0, Result=success)" \
    test "$(systemctl show -p Result --value focas-edge)/$(systemctl show -p ExecMainStatus --value focas-edge)" = success/0
check "journal shows the stopped line" journal_has "stopped"
check "no SIGKILL at stop" bash -c '! journalctl -u focas-edge --no-pager | grep -q "SIGKILL"'

# The credentials drop-in that config/tls-broker.yaml relies on (LoadCredential=mqtt-password).
install -D -m 0644 /usr/share/focas-edge/systemd/focas-edge-credentials.conf \
    /etc/systemd/system/focas-edge.service.d/credentials.conf
systemctl daemon-reload
{ printf 'mqtt:\n  username: focas-edge\n  password_file: /run/credentials/focas-edge.service/mqtt-password\n'
  config 1 | tail -n +2; } > /etc/focas-edge/edge.yaml
check "credentials drop-in without its source file: start refused" bash -c '! systemctl start focas-edge 2>/dev/null'
systemctl reset-failed focas-edge
install -d -m 0700 /etc/focas-edge/credentials
install -m 0600 /dev/null /etc/focas-edge/credentials/mqtt-password && echo s3cret > /etc/focas-edge/credentials/mqtt-password
check "start with the password as a credential (source root-only 0600)" systemctl start focas-edge
check "data flows with it" wait_msg "spBv1.0/check/DDATA/gw/sim-1"
systemctl stop focas-edge
rm -r /etc/systemd/system/focas-edge.service.d && systemctl daemon-reload

echo "state_dir: /proc/nope" > /tmp/proc.yaml; config 1 >> /tmp/proc.yaml; cp /tmp/proc.yaml /etc/focas-edge/edge.yaml
systemctl start focas-edge 2>/dev/null
# "failed" (not "activating (auto-restart)"): RestartPreventExitStatus=2 means no restart is scheduled.
check "an unusable state_dir: exit 2, failed, no restart scheduled" wait_until 20 bash -c \
    'test "$(systemctl show -p ExecMainStatus --value focas-edge)/$(systemctl is-active focas-edge)" = 2/failed'
check "its one-line reason in the journal" journal_has "state_dir: cannot create or write /proc/nope"
systemctl stop focas-sim
echo "--- journal of focas-edge.service ---"
journalctl -u focas-edge --no-pager -o short-monotonic | tail -n 25
echo "systemd-check: $failures failure(s)"
exit $((failures > 0))
