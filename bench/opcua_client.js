// The OPC UA benchmark's client (node-opcua, its own process): subscribes to every variable below every
// machine's Metrics folder and times what arrives. A compiled-JIT client, so on a 2-core host the client's
// own decoding does not take the CPU the gateway is measured with. Commands on stdin, JSON lines on stdout:
//   node bench/opcua_client.js '{"url","user","password","namespaceUri","stampMetric","pki","modulo"}'
//   -> {"items": N, "stamp_items": M}   once subscribed
//   start   forget what arrived so far, record from now on          -> {"started": true}
//   report  -> {"notifications", "seconds", "change_ms": [...], "wait_ms": [...], "sample_ms": [...]}
//   burst   one CreateMonitoredItems request of 10,000 items (a second subscription) -> {"burst_s"} or {"error"}
//   stop    disconnect and exit
// change = the simulator's stamp macro value (its clock, seconds mod `modulo`) to receipt; sample =
// SourceTimestamp (the CNC time of the read) to receipt, over every notification; wait = the stamp's change to
// the read that saw it (SourceTimestamp - the stamp's value: the part of change that is the poll period's).
"use strict";
const path = require("path");
const readline = require("readline");
const opcua = require("node-opcua");

const args = JSON.parse(process.argv[2]);
const BURST_ITEMS = 10000;
const say = (obj) => process.stdout.write(JSON.stringify(obj) + "\n");

async function variables(session, ns) {
  const machines = await session.browse(`ns=${ns};s=Machines`);
  let level = machines.references.map((r) => `ns=${ns};s=${r.nodeId.value}/Metrics`);
  const found = [];
  while (level.length) {
    const next = [];
    for (let i = 0; i < level.length; i += 500) {
      const results = await session.browse(level.slice(i, i + 500).map((nodeId) => ({
        nodeId, browseDirection: opcua.BrowseDirection.Forward, includeSubtypes: true,
        referenceTypeId: "HierarchicalReferences", nodeClassMask: 0, resultMask: 63,
      })));
      for (const result of results) {
        for (const ref of result.references || []) {
          if (ref.nodeClass === opcua.NodeClass.Variable) {
            if (ref.browseName.name !== "EngineeringUnits") found.push(ref.nodeId.toString());
          } else {
            next.push(ref.nodeId.toString());
          }
        }
      }
    }
    level = next;
  }
  return found;
}

async function main() {
  const certificateManager = new opcua.OPCUACertificateManager({
    rootFolder: path.join(args.pki, "PKI"), automaticallyAcceptUnknownCertificate: true,
  });
  await certificateManager.initialize();
  const client = opcua.OPCUAClient.create({
    applicationName: "focas-edge-bench", securityMode: opcua.MessageSecurityMode.SignAndEncrypt,
    securityPolicy: opcua.SecurityPolicy.Basic256Sha256, endpointMustExist: false,
    clientCertificateManager: certificateManager, requestedSessionTimeout: 600000,
    connectionStrategy: { maxRetry: 1, initialDelay: 200, maxDelay: 500 },
  });
  await client.connect(args.url);
  const session = await client.createSession({ type: opcua.UserTokenType.UserName, userName: args.user,
    password: args.password });
  const ns = (await session.readNamespaceArray()).indexOf(args.namespaceUri);
  const nodes = await variables(session, ns);
  let recording = false, started = Date.now(), notifications = 0, changeMs = [], waitMs = [], sampleMs = [];
  const subscription = await session.createSubscription2({
    requestedPublishingInterval: 20, requestedLifetimeCount: 3000, requestedMaxKeepAliveCount: 100,
    maxNotificationsPerPublish: 0, publishingEnabled: true, priority: 1,
  });
  const items = nodes.map((nodeId) => ({ nodeId, attributeId: opcua.AttributeIds.Value }));
  const group = await subscription.monitorItems(items, { samplingInterval: 0, discardOldest: true, queueSize: 10 },
    opcua.TimestampsToReturn.Both);
  const stamp = new Set();
  nodes.forEach((nodeId, index) => { if (nodeId.endsWith(`/Metrics/${args.stampMetric}`)) stamp.add(index); });
  group.on("changed", (item, dataValue, index) => {
    if (!recording) return;
    const received = Date.now();
    notifications += 1;
    if (dataValue.sourceTimestamp) sampleMs.push(received - dataValue.sourceTimestamp.getTime());
    if (stamp.has(index) && typeof dataValue.value.value === "number") {
      const modulo = args.modulo * 1000;
      changeMs.push((((received - dataValue.value.value * 1000) % modulo) + modulo) % modulo);
      if (dataValue.sourceTimestamp) {
        // signed: a read stamped a few ms before the change (the stamp's own error) is a small negative wait
        const wait = (((dataValue.sourceTimestamp.getTime() - dataValue.value.value * 1000) % modulo) + modulo) % modulo;
        waitMs.push(wait > modulo / 2 ? wait - modulo : wait);
      }
    }
  });
  say({ items: nodes.length, stamp_items: stamp.size });
  const lines = readline.createInterface({ input: process.stdin });
  for await (const line of lines) {
    const command = line.trim();
    if (command === "start") {
      recording = true; started = Date.now(); notifications = 0; changeMs = []; waitMs = []; sampleMs = [];
      say({ started: true });
    } else if (command === "report") {
      say({ notifications, seconds: (Date.now() - started) / 1000, change_ms: changeMs, wait_ms: waitMs,
        sample_ms: sampleMs });
    } else if (command === "burst") {
      try {
        const second = await session.createSubscription2({ requestedPublishingInterval: 1000,
          requestedLifetimeCount: 600, requestedMaxKeepAliveCount: 20, publishingEnabled: true });
        const burst = Array.from({ length: BURST_ITEMS }, (_, i) => items[i % items.length]);
        const t0 = Date.now();
        await second.monitorItems(burst, { samplingInterval: 0, discardOldest: true, queueSize: 1 },
          opcua.TimestampsToReturn.Both);
        say({ burst_s: (Date.now() - t0) / 1000 });
      } catch (err) {
        say({ error: String(err.message) });
      }
    } else {
      break;
    }
  }
  await session.close();
  await client.disconnect();
  await certificateManager.dispose();
}

main().then(() => process.exit(0)).catch((err) => { say({ error: String(err && err.stack || err) }); process.exit(1); });
