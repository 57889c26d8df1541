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

refused() {  # refused "line": the last start failed with exit 2, no restart scheduled, the line in the journal
    wait_until 20 bash -c 'test "$(systemctl show -p ExecMainStatus --value focas-edge)/$(systemctl is-active focas-edge)" = 2/failed' \
        && journal_has "$1" && return 0
    echo "status $(systemctl show -p ExecMainStatus --value focas-edge)/$(systemctl is-active focas-edge), journal:"
    journalctl -u focas-edge --no-pager -o cat | tail -n 4
    return 1
}
restart_clean() { systemctl stop focas-edge 2>/dev/null; systemctl reset-failed focas-edge 2>/dev/null; true; }

# A minbase root with systemd only: whatever the daemon needs must come from the package's Depends (adduser
# is there anyway: apt itself depends on it). The packages wait in apt's cache: the container has no network.
export DEBIAN_FRONTEND=noninteractive
check "a bare root: no python3 before the package" bash -c '! command -v python3 && ! test -e /usr/bin/python3'
# apt's own W: lines (e.g. a local .deb fetched unsandboxed) are not the package's; anything else that warns is
check "apt-get install the package: its Depends bring python3, no warnings (adduser's neither)" bash -c \
    "apt-get install -y /mnt/dist/$DEB >/tmp/install.out 2>&1; rc=\$?; grep -i -B2 -A2 'warn\|error' /tmp/install.out;
     test \$rc = 0 && ! grep -v '^W: ' /tmp/install.out | grep -i warn"
check "python3 >= 3.11 came with it" /usr/bin/python3 -c 'import sys, sqlite3, ssl; assert sys.version_info >= (3, 11)'
apt-get install -y mosquitto >/dev/null 2>&1
wait_until 60 systemctl is-active --quiet mosquitto || { echo "FAIL mosquitto in the container"; exit 1; }
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
check "runs as user focas-edge" test "$(stat -c %U "/proc/$(systemctl show -p MainPID --value focas-edge)")" = focas-edge
check "journal shows the startup line" wait_until 20 journal_has "started version="
check "JSON data flows (sim-1)" wait_msg "focas/sim-1/#"
check "Sparkplug DDATA flows (sim-1)" wait_msg "spBv1.0/check/DDATA/gw/sim-1"
check "state written to /var/lib/focas-edge" wait_until 20 bash -c 'test -n "$(ls -A /var/lib/focas-edge)"'

# One instance per state_dir: the same config run again (as root, from a shell) while the service runs.
pid=$(systemctl show -p MainPID --value focas-edge)
held="state_dir: /var/lib/focas-edge is in use by another focas-edge (PID $pid, focas-edge.service"
check "a second instance on the service's state_dir: exit 2, one line naming it and the service's PID" bash -c \
    "focas-edge run --config /etc/focas-edge/edge.yaml 2>/tmp/second.err; test \$? = 2 && cat /tmp/second.err &&
     test \$(wc -l </tmp/second.err) = 1 && grep -qF '$held' /tmp/second.err"
check "check-config names the held lock the same way" bash -c \
    "! focas-edge check-config /etc/focas-edge/edge.yaml 2>/tmp/cc.err; cat /tmp/cc.err; grep -qF '$held' /tmp/cc.err"
check "check-config --as-service: the running service's own lock is fine (a reload or restart)" bash -c \
    "focas-edge check-config --as-service /etc/focas-edge/edge.yaml 2>&1 | grep -q 'in use by the running focas-edge.service'"
check "the service is unaffected (same process, still active)" \
    test "$(systemctl show -p MainPID --value focas-edge)/$(systemctl is-active focas-edge)" = "$pid/active"
check "check-config | head -1: no BrokenPipe traceback" bash -c \
    "focas-edge check-config --as-service /etc/focas-edge/edge.yaml 2>/tmp/pipe.err | head -c 1 >/dev/null; ! grep -i 'traceback\|brokenpipe' /tmp/pipe.err"

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

# A `focas-edge run` as root before the service (it warns) leaves root-owned state files behind.
config 1 > /etc/focas-edge/edge.yaml
focas-edge run --config /etc/focas-edge/edge.yaml >/tmp/root-run.log 2>&1 &
root_run=$!
wait_until 30 grep -q "started version=" /tmp/root-run.log
kill -TERM "$root_run"; wait "$root_run"
check "a run as root warns that it leaves root's files in the service's state_dir" \
    grep -q "running as root in state_dir=/var/lib/focas-edge, which belongs to focas-edge:focas-edge" /tmp/root-run.log
check "it left root-owned files there" bash -c 'find /var/lib/focas-edge -user root | grep -q .'
fix="fix: chown -R focas-edge:focas-edge /var/lib/focas-edge"
check "check-config --as-service names a root-owned state file and the fix" bash -c \
    "! focas-edge check-config --as-service /etc/focas-edge/edge.yaml 2>/tmp/cc.err; cat /tmp/cc.err;
     grep 'state_dir: /var/lib/focas-edge/.* belongs to root:root' /tmp/cc.err | grep -qF '$fix'"
systemctl start focas-edge 2>/dev/null
check "the service refuses it: exit 2, failed, no restart scheduled, the same line in the journal" \
    refused "$(grep -o 'state_dir: /var/lib/focas-edge/.*' /tmp/cc.err)"
check "the package's postinst (an upgrade, a reinstall) gives the state back" bash -c \
    '/var/lib/dpkg/info/focas-edge.postinst configure 0 && ! find /var/lib/focas-edge ! -user focas-edge | grep .'
restart_clean
check "then the service starts" systemctl start focas-edge
restart_clean

# The status HTTP port taken by another program.
systemd-run --quiet --unit=port-holder /usr/bin/python3 -m http.server 9108 --bind 127.0.0.1
wait_until 30 bash -c 'exec 3<>/dev/tcp/127.0.0.1/9108' 2>/dev/null
{ config 1; printf 'http: {enabled: true, port: 9108}\n'; } > /etc/focas-edge/edge.yaml
taken="http.port: 127.0.0.1:9108 is already in use by another program"
check "check-config --as-service names the port in use" bash -c \
    "! focas-edge check-config --as-service /etc/focas-edge/edge.yaml 2>/tmp/cc.err; cat /tmp/cc.err; grep -qF '$taken' /tmp/cc.err"
systemctl start focas-edge 2>/dev/null
check "a port clash: exit 2, failed, no restart scheduled, one line in the journal" refused "$taken"
systemctl stop port-holder
restart_clean

# A config the service user cannot read (root:root 0600).
config 1 > /etc/focas-edge/edge.yaml
chown root:root /etc/focas-edge/edge.yaml; chmod 0600 /etc/focas-edge/edge.yaml
check "check-config --as-service names the config the service cannot read" bash -c \
    "focas-edge check-config --as-service /etc/focas-edge/edge.yaml 2>&1 | grep -q 'config: user focas-edge cannot read /etc/focas-edge/edge.yaml'"
systemctl start focas-edge 2>/dev/null
check "an unreadable config: exit 2, failed, no restart scheduled, one line in the journal" \
    refused "config: user focas-edge cannot read /etc/focas-edge/edge.yaml (owner root:root, mode -rw-------)"
chown root:focas-edge /etc/focas-edge/edge.yaml; chmod 0640 /etc/focas-edge/edge.yaml
restart_clean

# A password that the config reads as a systemd credential, without the drop-in that loads it.
{ printf 'mqtt:\n  username: focas-edge\n  password_file: /run/credentials/focas-edge.service/mqtt-password\n'
  config 1 | tail -n +2; } > /etc/focas-edge/edge.yaml
check "check-config --as-service: a credential no unit loads" bash -c \
    "focas-edge check-config --as-service /etc/focas-edge/edge.yaml 2>&1 | grep -q \"loads no credential 'mqtt-password'\""
systemctl start focas-edge 2>/dev/null
check "the password file missing: exit 2, failed, no restart scheduled, one line in the journal" \
    refused "mqtt.password_file: cannot read /run/credentials/focas-edge.service/mqtt-password: "
restart_clean

# The credentials drop-in that config/tls-broker.yaml relies on (LoadCredential=mqtt-password).
install -D -m 0644 /usr/share/focas-edge/systemd/focas-edge-credentials.conf \
    /etc/systemd/system/focas-edge.service.d/credentials.conf
systemctl daemon-reload
check "check-config --as-service: the drop-in's source file is missing" bash -c \
    "focas-edge check-config --as-service /etc/focas-edge/edge.yaml 2>&1 | grep -q 'from /etc/focas-edge/credentials/mqtt-password (LoadCredential=), which does not exist'"
check "credentials drop-in without its source file: start refused" bash -c '! systemctl start focas-edge 2>/dev/null'
check "... and not restarted (RestartPreventExitStatus covers 243/CREDENTIALS)" wait_until 20 bash -c \
    'test "$(systemctl show -p ExecMainStatus --value focas-edge)/$(systemctl is-active focas-edge)" = 243/failed'
systemctl reset-failed focas-edge
install -d -m 0700 /etc/focas-edge/credentials
install -m 0600 /dev/null /etc/focas-edge/credentials/mqtt-password && echo s3cret > /etc/focas-edge/credentials/mqtt-password
check "check-config --as-service is content with the credential" focas-edge check-config --as-service /etc/focas-edge/edge.yaml
check "start with the password as a credential (source root-only 0600)" systemctl start focas-edge
check "data flows with it" wait_msg "spBv1.0/check/DDATA/gw/sim-1"
systemctl stop focas-edge
rm -r /etc/systemd/system/focas-edge.service.d && systemctl daemon-reload

# One identity per gateway: a second gateway cloned from the first (its own state_dir, the same Sparkplug ids).
config 1 > /etc/focas-edge/edge.yaml
restart_clean
systemctl start focas-edge
{ echo "state_dir: /var/lib/focas-edge-clone"; config 1; } > /tmp/clone.yaml
systemd-run --quiet --unit=focas-edge-clone /opt/focas-edge/bin/focas-edge run --config /tmp/clone.yaml
conflict="identity conflict: another gateway uses Sparkplug id check/gw on this broker"
check "a clone with the same Sparkplug ids: the ERROR naming the id in the journal" \
    wait_until 90 bash -c "journalctl -u focas-edge -u focas-edge-clone --no-pager -o cat | grep -qF '$conflict'"
check "... one ERROR per gateway at most, not one per reconnect" \
    bash -c "both_journals() { journalctl -u focas-edge -u focas-edge-clone --no-pager -o cat; };
             both_journals | grep -F '$conflict' | head -n 2; test \$(both_journals | grep -cF '$conflict') -le 2"
check "... and neither unit restarted" test "$(systemctl show -p NRestarts --value focas-edge)" = 0
systemctl stop focas-edge-clone focas-edge
restart_clean

echo "state_dir: /proc/nope" > /tmp/proc.yaml; config 1 >> /tmp/proc.yaml; cp /tmp/proc.yaml /etc/focas-edge/edge.yaml
systemctl start focas-edge 2>/dev/null
# "failed" (not "activating (auto-restart)"): RestartPreventExitStatus=2 means no restart is scheduled.
check "an unusable state_dir: exit 2, failed, no restart scheduled" wait_until 20 bash -c \
    'test "$(systemctl show -p ExecMainStatus --value focas-edge)/$(systemctl is-active focas-edge)" = 2/failed'
check "its one-line reason in the journal" journal_has "state_dir: cannot create or write /proc/nope"
check "init --units from the package writes units that run /opt/focas-edge" bash -c \
    'focas-edge init 127.0.0.1:18193 --units /tmp/units -o /tmp/init.yaml 2>/dev/null;
     grep -qx "ExecStart=/opt/focas-edge/bin/focas-edge run --config /etc/focas-edge/edge.yaml" /tmp/units/focas-edge.service'
systemctl stop focas-sim
echo "--- journal of focas-edge.service ---"
journalctl -u focas-edge --no-pager -o short-monotonic | tail -n 25
echo "systemd-check: $failures failure(s)"
exit $((failures > 0))
