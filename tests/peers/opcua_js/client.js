// The OPC UA tests' client of another stack: node-opcua's (npm node-opcua-client), not asyncua.
// One job as JSON on stdin, one JSON line per step on stdout, then it exits:
//   {"endpoint": "opc.tcp://...", "pki": "<folder>", "policy": "Basic256Sha256",
//    "mode": "SignAndEncrypt", "user": "olga", "password": "...", "namespace": "urn:...",
//    "steps": [{"browse": "gateway"}, {"read": "pump1.state"},
//              {"write": "pump1.set_frequency_hz", "value": 20.5},
//              {"call": "pump1", "method": "pump1.RunForward"},
//              {"call": "pump1", "method": "pump1.RunForward", "arguments": [30.0]},
//              {"subscribe": "pump1.state", "until": "running_forward", "timeout_ms": 5000},
//              {"events": "pump1", "count": 2, "timeout_ms": 10000}]}
// An "events" step answers {"listening": true} once its monitored item is made (the test then
// trips the drive), {"event": {...}} as each event comes, then its own answer.
// Node ids are the string ids of `namespace`; each step answers {"status": "Good", ...}, or
// the failed step's status name. "certificate" as a step answers the client's own certificate
// file (made by node-opcua in `pki` on its first connection), for the test to trust it.
"use strict";
const fs = require("fs");
const path = require("path");
const {
  OPCUAClient,
  MessageSecurityMode,
  SecurityPolicy,
  AttributeIds,
  DataType,
  TimestampsToReturn,
  ClientMonitoredItem,
  UserTokenType,
  NodeId,
  constructEventFilter,
} = require("node-opcua-client");
const { OPCUACertificateManager } = require("node-opcua-certificate-manager");

function answerOf(error) {
  const text = String(error && error.message ? error.message : error);
  const match = text.match(/Bad[A-Za-z]+/);
  return { status: match ? match[0] : "Error", message: text.split("\n")[0] };
}

async function step(session, ns, job, out) {
  const id = (text) => new NodeId(NodeId.NodeIdType.STRING, text, ns);
  if (job.browse !== undefined) {
    const result = await session.browse(id(job.browse));
    return {
      status: result.statusCode.name,
      names: result.references.map((r) => r.browseName.name),
    };
  }
  if (job.read !== undefined) {
    const value = await session.read({ nodeId: id(job.read), attributeId: AttributeIds.Value });
    return {
      status: value.statusCode.name,
      value: value.value.value,
      dataType: DataType[value.value.dataType],
      sourceTimestamp: value.sourceTimestamp ? value.sourceTimestamp.toISOString() : null,
    };
  }
  if (job.write !== undefined) {
    const status = await session.write({
      nodeId: id(job.write),
      attributeId: AttributeIds.Value,
      value: { value: { dataType: DataType.Double, value: job.value } },
    });
    return { status: status.name };
  }
  if (job.call !== undefined) {
    const result = await session.call({
      objectId: id(job.call),
      methodId: id(job.method),
      // Doubles (a set frequency), as a SCADA fills a method's input arguments.
      inputArguments: (job.arguments || []).map((value) => ({ dataType: DataType.Double, value })),
    });
    const outputs = (result.outputArguments || []).map((v) => v.value);
    return { status: result.statusCode.name, outputs };
  }
  if (job.subscribe !== undefined) {
    return subscribe(session, id(job.subscribe), job.until, job.timeout_ms || 5000);
  }
  if (job.events !== undefined) {
    return events(session, id(job.events), ns, job.count || 1, job.timeout_ms || 10000, out);
  }
  return { status: "Error", message: `unknown step ${JSON.stringify(job)}` };
}

async function subscribe(session, nodeId, until, timeoutMs) {
  const subscription = await session.createSubscription2({
    requestedPublishingInterval: 100,
    requestedLifetimeCount: 100,
    requestedMaxKeepAliveCount: 10,
    publishingEnabled: true,
  });
  const seen = [];
  try {
    const item = await ClientMonitoredItem.create(
      subscription,
      { nodeId, attributeId: AttributeIds.Value },
      { samplingInterval: 100, discardOldest: true, queueSize: 10 },
      TimestampsToReturn.Both,
    );
    await new Promise((resolve) => {
      const timer = setTimeout(resolve, timeoutMs);
      item.on("changed", (value) => {
        seen.push(value.value.value);
        if (value.value.value === until) {
          clearTimeout(timer);
          resolve();
        }
      });
    });
  } finally {
    await subscription.terminate();
  }
  return { status: seen.includes(until) ? "Good" : "BadTimeout", seen };
}

const EVENT_FIELDS = ["EventId", "SourceName", "Message", "Severity", "Time"];
const OWN_FIELDS = ["Kind", "FaultCode", "FaultName"];

async function events(session, nodeId, ns, count, timeoutMs, out) {
  const subscription = await session.createSubscription2({
    requestedPublishingInterval: 100,
    requestedLifetimeCount: 100,
    requestedMaxKeepAliveCount: 10,
    publishingEnabled: true,
  });
  const names = [...EVENT_FIELDS, ...OWN_FIELDS];
  const filter = constructEventFilter([...EVENT_FIELDS, ...OWN_FIELDS.map((f) => `${ns}:${f}`)]);
  const seen = [];
  try {
    const item = await ClientMonitoredItem.create(
      subscription,
      { nodeId, attributeId: AttributeIds.EventNotifier },
      { queueSize: 100, discardOldest: true, filter },
      TimestampsToReturn.Neither,
    );
    out({ listening: true });
    await new Promise((resolve) => {
      const timer = setTimeout(resolve, timeoutMs);
      item.on("changed", (fields) => {
        const event = {};
        names.forEach((name, i) => {
          const value = fields[i].value;
          event[name] = value && value.text !== undefined ? value.text : value;
        });
        event.EventId = Buffer.from(event.EventId || []).toString("hex");
        event.Time = event.Time ? event.Time.toISOString() : null;
        seen.push(event);
        out({ event });
        if (seen.length >= count) {
          clearTimeout(timer);
          resolve();
        }
      });
    });
  } finally {
    await subscription.terminate();
  }
  return { status: seen.length >= count ? "Good" : "BadTimeout", events: seen };
}

async function main() {
  const job = JSON.parse(fs.readFileSync(0, "utf8"));
  const manager = new OPCUACertificateManager({
    rootFolder: job.pki,
    automaticallyAcceptUnknownCertificate: true, // the gateway's own certificate, first seen
  });
  await manager.initialize();
  const client = OPCUAClient.create({
    applicationName: "invt-gateway node-opcua peer",
    applicationUri: "urn:invt-gateway:tests:node-opcua",
    clientCertificateManager: manager,
    securityPolicy: SecurityPolicy[job.policy || "None"],
    securityMode: MessageSecurityMode[job.mode || "None"],
    endpointMustExist: false,
    connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
    requestedSessionTimeout: 10000,
  });
  const out = (answer) => process.stdout.write(JSON.stringify(answer) + "\n");
  const certificate = path.join(job.pki, "own", "certs", "client_certificate.pem");
  let session;
  try {
    await client.connect(job.endpoint);
    const identity = job.user
      ? { type: UserTokenType.UserName, userName: job.user, password: job.password }
      : { type: UserTokenType.Anonymous };
    session = await client.createSession(identity);
  } catch (error) {
    out({ session: answerOf(error), certificate });
    await client.disconnect();
    return;
  }
  out({ session: { status: "Good" }, certificate });
  const ns = (await session.readNamespaceArray()).indexOf(job.namespace);
  for (const each of job.steps || []) {
    try {
      out(await step(session, ns, each, out));
    } catch (error) {
      out(answerOf(error));
    }
  }
  await session.close();
  await client.disconnect();
}

main().catch((error) => {
  process.stdout.write(JSON.stringify({ fatal: String(error && error.stack) }) + "\n");
  process.exit(1);
});
