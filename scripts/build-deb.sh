#!/usr/bin/env bash
# Build dist/ (or $DEB_OUT_DIR) focas-edge_<version>_<arch>.deb for this machine's architecture with dpkg-deb:
#   /opt/focas-edge          the daemon in its own venv (Debian's python3, so it runs on Debian 12 / Pi OS)
#   /usr/bin/focas-edge      on PATH
#   /lib/systemd/system/     every unit in systemd/ (enabled by nobody: the admin enables it)
#   /etc/focas-edge/edge.yaml  an example config (a conffile), root:focas-edge 0640
#   /usr/share/focas-edge/   all example configs and drop-ins
# WHEELHOUSE=DIR installs the dependencies from DIR only (no index): an offline or cross-platform build.
# WHEEL=FILE uses that focas-edge wheel instead of building one (it is pure Python: any machine builds it).
set -euo pipefail
cd "$(dirname "$0")/.."
python=${DEB_PYTHON:-/usr/bin/python3}
arch=$(dpkg --print-architecture)
version=$(sed -n 's/^version *= *"\(.*\)"/\1/p' pyproject.toml | head -1)
build=${DEB_BUILD_DIR:-build}/deb-$arch
out=${DEB_OUT_DIR:-dist}
stage=$(realpath -m "$build")/root
venv=/opt/focas-edge
rm -rf "$build"
mkdir -p "$stage/DEBIAN" "$out"

if [[ -n ${WHEEL:-} ]]; then
    mkdir -p "$build/wheel" && cp "$WHEEL" "$build/wheel/"
else
    "$python" -m pip wheel --quiet --no-deps -w "$build/wheel" .
fi
"$python" -m venv "$stage$venv"
pip_args=(--quiet --no-compile --disable-pip-version-check)
[[ -n ${WHEELHOUSE:-} ]] && pip_args+=(--no-index --find-links "$WHEELHOUSE")
"$stage$venv/bin/python" -m pip install "${pip_args[@]}" "$build"/wheel/focas_edge-*.whl
# The venv was made at the staging path: point its scripts and config at where it is installed.
grep -rlI --null "$stage$venv" "$stage$venv/bin" "$stage$venv/pyvenv.cfg" | xargs -0 -r sed -i "s|$stage$venv|$venv|g"
find "$stage$venv" -name __pycache__ -prune -exec rm -rf {} +

install -d "$stage/usr/bin" "$stage/lib/systemd/system" "$stage/etc/focas-edge" \
    "$stage/usr/share/focas-edge/examples" "$stage/usr/share/focas-edge/systemd" "$stage/usr/share/doc/focas-edge"
ln -s "$venv/bin/focas-edge" "$stage/usr/bin/focas-edge"
for unit in systemd/*; do
    case $unit in
        *.service|*.socket|*.timer|*.path|*.target) install -m 0644 "$unit" "$stage/lib/systemd/system/" ;;
        *) install -m 0644 "$unit" "$stage/usr/share/focas-edge/systemd/" ;;
    esac
done
install -m 0644 config/*.yaml "$stage/usr/share/focas-edge/examples/"
install -m 0640 config/single-machine.yaml "$stage/etc/focas-edge/edge.yaml"
install -m 0644 LICENSE "$stage/usr/share/doc/focas-edge/copyright"
install -m 0644 docs/install.md "$stage/usr/share/doc/focas-edge/"

# The venv runs on the python3 it was made with (bin/python -> /usr/bin/python3, lib/python3.N/): Debian's
# python3 of that minor version, which brings libpython3.N-stdlib (sqlite3, ssl). The wheels' own C parts
# (pydantic-core, PyYAML, protobuf) need only libc. procps: the unit's ExecReload=/bin/kill. ca-certificates:
# the system CAs, for a TLS broker without ca_file.
python_dep=$("$python" -c 'import sys; v = sys.version_info; print(f"python3 (>= {v[0]}.{v[1]}), python3 (<< {v[0]}.{v[1] + 1})")')
size=$(du -sk --exclude=DEBIAN "$stage" | cut -f1)
cat > "$stage/DEBIAN/control" <<CONTROL
Package: focas-edge
Version: $version
Architecture: $arch
Maintainer: focas-edge maintainers <focas-edge@users.noreply.github.com>
Depends: $python_dep, adduser, procps
Recommends: ca-certificates
Installed-Size: $size
Section: net
Priority: optional
Homepage: https://github.com/focas-edge/focas-edge
Description: FANUC CNC (FOCAS/Ethernet) to MQTT collector
 Polls FANUC CNCs over FOCAS/Ethernet with a pure-Python client and publishes what changes to MQTT
 (Sparkplug B 3.0 and JSON), with a store-and-forward spool and an opt-in command path for writes.
 The service is installed but not enabled: edit /etc/focas-edge/edge.yaml, then
 systemctl enable --now focas-edge.
CONTROL
echo /etc/focas-edge/edge.yaml > "$stage/DEBIAN/conffiles"
install -m 0755 packaging/deb/postinst packaging/deb/prerm packaging/deb/postrm "$stage/DEBIAN/"
deb=$out/focas-edge_${version}_${arch}.deb
dpkg-deb --root-owner-group -Zxz --build "$stage" "$deb" >/dev/null
echo "$deb"
