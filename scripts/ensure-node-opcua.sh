#!/usr/bin/env bash
# The OPC UA interop tests drive the gateway's server with node-opcua, an independent client stack (npm).
# Installed into .node/ (untracked) at a pinned version; never fails: without node/npm or the registry the
# tests that need it skip and say why.
set -u
here=$(cd "$(dirname "$0")/.." && pwd)
version=2.186.4
prefix="$here/.node"
if [ -f "$prefix/node_modules/node-opcua/package.json" ] && \
   grep -q "\"version\": \"$version\"" "$prefix/node_modules/node-opcua/package.json"; then
  exit 0
fi
if ! command -v npm >/dev/null 2>&1; then
  echo "WARNING: npm is not installed; the node-opcua interop tests will be skipped (apt-get install nodejs npm)." >&2
  exit 0
fi
mkdir -p "$prefix"
echo "installing node-opcua@$version into $prefix (the OPC UA interop tests' client)" >&2
if ! (cd "$prefix" && npm install --no-audit --no-fund --loglevel=error --prefix "$prefix" "node-opcua@$version" >&2); then
  echo "WARNING: npm install node-opcua@$version failed; the node-opcua interop tests will be skipped." >&2
fi
exit 0
