// The tests' independent Sparkplug B codec: Eclipse Tahu's JavaScript one (npm
// sparkplug-payload, on protobufjs), neither our protobuf runtime nor our .proto.
// One request per line on stdin, one JSON line per answer on stdout:
//   decode <base64 payload> [<{alias: datatype name} as JSON>]
//                             → the payload as Tahu decodes it; each metric says whether its
//                               datatype was on the wire (`datatypeOnWire`). A metric that came
//                               without one (DDATA: the specification's
//                               payloads-metric-datatype-not-req) is given the datatype its alias
//                               had in the birth, as a host application does (Tahu's Java decoder
//                               takes the same map, its MetricDataTypeMap): Tahu's JavaScript
//                               codec reads a value only by its datatype.
//   encode <payload as JSON>  → {"base64": ...}, Tahu's encoding of it (a host's NCMD, DCMD)
// 64-bit values (Long) are written as numbers when a double holds them exactly, else as text.
"use strict";
const readline = require("readline");
const Long = require("long");
const sparkplug = require("sparkplug-payload").get("spBv1.0");
const proto = require("sparkplug-payload/lib/sparkplugPayloadProto").org.eclipse.tahu.protobuf;
const ProtoPayload = proto.Payload;

function decode(data, birthTypes) {
  const raw = ProtoPayload.decode(data);
  const onWire = raw.metrics.map((metric) => Object.prototype.hasOwnProperty.call(metric, "datatype"));
  raw.metrics.forEach((metric, i) => {
    const alias = metric.alias === undefined || metric.alias === null ? null : String(metric.alias);
    if (!onWire[i] && alias !== null && birthTypes[alias] !== undefined) {
      metric.datatype = proto.DataType[birthTypes[alias]];
    }
  });
  const decoded = sparkplug.decodePayload(ProtoPayload.encode(raw).finish());
  (decoded.metrics || []).forEach((metric, i) => {
    metric.datatypeOnWire = onWire[i];
  });
  return decoded;
}

function plain(key, value) {
  if (value !== null && typeof value === "object" && "low" in value && "high" in value) {
    const long = Long.fromValue(value);
    return Number.isSafeInteger(long.toNumber()) ? long.toNumber() : long.toString();
  }
  return value;
}

function answer(line) {
  const space = line.indexOf(" ");
  const verb = line.slice(0, space);
  const argument = line.slice(space + 1);
  if (verb === "decode") {
    const [data, types] = argument.split(" ");
    return decode(Buffer.from(data, "base64"), types ? JSON.parse(types) : {});
  }
  if (verb === "encode") {
    return { base64: Buffer.from(sparkplug.encodePayload(JSON.parse(argument))).toString("base64") };
  }
  return { error: `unknown request ${verb}` };
}

readline.createInterface({ input: process.stdin }).on("line", (line) => {
  let out;
  try {
    out = answer(line.trim());
  } catch (error) {
    out = { error: String(error) };
  }
  process.stdout.write(JSON.stringify(out, plain) + "\n");
});
