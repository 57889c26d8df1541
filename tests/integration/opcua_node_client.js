// An independent OPC UA client (node-opcua) for the interop tests: runs one scenario against the gateway
// and prints one JSON object with what it saw. Usage:
//   node opcua_node_client.js '<json: url, user, password, namespaceUri, machine, read, subscribe, changes,
//                              writes: [{node, value, dataType}], pki}>'
// Every network step has a timeout; any failure is reported in the JSON ("error"), never swallowed.
"use strict";
const path = require("path");
const opcua = require("node-opcua");

const args = JSON.parse(process.argv[2]);
const TIMEOUT_MS = args.timeoutMs || 15000;

function withTimeout(promise, what) {
  let timer;
  const expired = new Promise((_, reject) => {
    timer = setTimeout(() => reject(new Error(`timed out after ${TIMEOUT_MS} ms: ${what}`)), TIMEOUT_MS);
  });
  return Promise.race([promise, expired]).finally(() => clearTimeout(timer));
}

function dataValue(dv) {
  return {
    value: dv.value && dv.value.value !== undefined ? dv.value.value : null,
    dataType: dv.value ? opcua.DataType[dv.value.dataType] : null,
    status: dv.statusCode.name,
    sourceTimestamp: dv.sourceTimestamp ? dv.sourceTimestamp.getTime() : null,
    serverTimestamp: dv.serverTimestamp ? dv.serverTimestamp.getTime() : null,
  };
}

async function anonymousRefused(certificateManager) {
  const client = opcua.OPCUAClient.create({
    securityMode: opcua.MessageSecurityMode.SignAndEncrypt, securityPolicy: opcua.SecurityPolicy.Basic256Sha256,
    endpointMustExist: false, clientCertificateManager: certificateManager,
    connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
  });
  await withTimeout(client.connect(args.url), "connect (anonymous)");
  try {
    const session = await withTimeout(client.createSession(), "anonymous session");
    await session.close();
    return { refused: false };
  } catch (err) {
    return { refused: true, message: String(err.message).split("\n")[0] };
  } finally {
    await client.disconnect();
  }
}

async function main() {
  const out = {};
  const certificateManager = new opcua.OPCUACertificateManager({
    rootFolder: path.join(args.pki, "PKI"), automaticallyAcceptUnknownCertificate: true,
  });
  await withTimeout(certificateManager.initialize(), "client PKI");
  const client = opcua.OPCUAClient.create({
    applicationName: "focas-edge-interop", securityMode: opcua.MessageSecurityMode.SignAndEncrypt,
    securityPolicy: opcua.SecurityPolicy.Basic256Sha256, endpointMustExist: false,
    clientCertificateManager: certificateManager,
    connectionStrategy: { maxRetry: 1, initialDelay: 200, maxDelay: 500 },
  });
  await withTimeout(client.connect(args.url), "connect");
  const session = await withTimeout(client.createSession({
    type: opcua.UserTokenType.UserName, userName: args.user, password: args.password,
  }), "session");
  try {
    const ns = (await session.readNamespaceArray()).indexOf(args.namespaceUri);
    out.namespace = ns;
    const id = (p) => `ns=${ns};s=${p}`;
    // browse: the machine object's components
    const browsed = await withTimeout(session.browse(id(args.machine)), "browse");
    out.components = browsed.references.map((r) => r.browseName.name);
    const metrics = await withTimeout(session.browse(id(`${args.machine}/Metrics`)), "browse Metrics");
    out.metricFolders = metrics.references.map((r) => r.browseName.name);
    // read
    out.read = dataValue(await withTimeout(session.read({ nodeId: id(args.read), attributeId: opcua.AttributeIds.Value }),
      "read"));
    // subscribe and wait for changes
    const subscription = opcua.ClientSubscription.create(session, {
      requestedPublishingInterval: 50, requestedLifetimeCount: 600, requestedMaxKeepAliveCount: 20,
      maxNotificationsPerPublish: 1000, publishingEnabled: true, priority: 1,
    });
    const changes = [];
    const item = opcua.ClientMonitoredItem.create(subscription,
      { nodeId: id(args.subscribe), attributeId: opcua.AttributeIds.Value },
      { samplingInterval: 0, discardOldest: true, queueSize: 10 }, opcua.TimestampsToReturn.Both);
    await new Promise((resolve, reject) => {
      const timer = setTimeout(() => resolve(), TIMEOUT_MS);
      item.on("changed", (dv) => {
        changes.push(dataValue(dv));
        if (changes.length >= args.changes) { clearTimeout(timer); resolve(); }
      });
      item.on("err", (message) => { clearTimeout(timer); reject(new Error(message)); });
    });
    out.changes = changes;
    await subscription.terminate();
    // writes
    out.writes = [];
    for (const w of args.writes) {
      const status = await withTimeout(session.write({
        nodeId: id(w.node), attributeId: opcua.AttributeIds.Value,
        value: { value: { dataType: opcua.DataType[w.dataType], value: w.value } },
      }), `write ${w.node}`);
      out.writes.push({ node: w.node, status: status.name });
    }
  } finally {
    await session.close();
    await client.disconnect();
  }
  out.anonymous = await anonymousRefused(certificateManager);
  await certificateManager.dispose();
  return out;
}

main().then((out) => {
  process.stdout.write(JSON.stringify(out) + "\n");
  process.exit(0);
}).catch((err) => {
  process.stdout.write(JSON.stringify({ error: String(err && err.stack || err) }) + "\n");
  process.exit(1);
});
