// The tests' independent Sparkplug B codec: Eclipse Tahu's JavaScript one (npm
// sparkplug-payload, on protobufjs), neither our protobuf runtime nor our .proto.
// One request per line on stdin, one JSON line per answer on stdout:
//   decode <base64 payload>   → the payload as Tahu decodes it
//   encode <payload as JSON>  → {"base64": ...}, Tahu's encoding of it (a host's NCMD, DCMD)
// 64-bit values (Long) are written as numbers when a double holds them exactly, else as text.
"use strict";
const readline = require("readline");
const Long = require("long");
const sparkplug = require("sparkplug-payload").get("spBv1.0");

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
    return sparkplug.decodePayload(Buffer.from(argument, "base64"));
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
