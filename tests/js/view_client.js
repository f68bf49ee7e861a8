// A Foxglove WebSocket client built on the published @foxglove/ws-protocol library (what Foxglove's own example
// clients use), for tests/test_view.py: it connects offering the library's subprotocol (foxglove.websocket.v1),
// subscribes to every advertised channel whose topic matches PATTERN, decodes each message with the schema the
// server advertised (@foxglove/rosmsg parses the ros2msg text, @foxglove/rosmsg2-serialization reads the CDR, as
// Foxglove and Lichtblick do) and prints one JSON line per event:
//   {"serverInfo": {...}, "protocol": "..."}   once, on connect
//   {"subscribed": [topic, ...]}                after each advertise
//   {"topic": "...", "logTime": "<ns>", "msg": {...}}   per message (integers past 2^53 and times as strings)
//   {"status": {...}}                           per status message of the server
// It exits when the server closes the connection. Usage: node view_client.js ws://127.0.0.1:PORT [PATTERN]
"use strict";
const { FoxgloveClient } = require("@foxglove/ws-protocol");
const { parse } = require("@foxglove/rosmsg");
const { MessageReader } = require("@foxglove/rosmsg2-serialization");
const WebSocket = require("ws");

const [url, pattern = "."] = process.argv.slice(2);
const wanted = new RegExp(pattern);
const ws = new WebSocket(url, [FoxgloveClient.SUPPORTED_SUBPROTOCOL]);
const client = new FoxgloveClient({ ws });
const subscriptions = new Map();

function out(event) {
  process.stdout.write(
    JSON.stringify(event, (_key, v) =>
      typeof v === "bigint" ? v.toString() : ArrayBuffer.isView(v) ? Array.from(v) : v,
    ) + "\n",
  );
}

client.on("serverInfo", (info) => out({ serverInfo: info, protocol: ws.protocol }));
client.on("status", (status) => out({ status }));
client.on("advertise", (channels) => {
  const topics = [];
  for (const ch of channels) {
    if (!wanted.test(ch.topic)) continue;
    const reader = new MessageReader(parse(ch.schema, { ros2: true }));
    subscriptions.set(client.subscribe(ch.id), { topic: ch.topic, reader });
    topics.push(ch.topic);
  }
  out({ subscribed: topics });
});
client.on("message", ({ subscriptionId, timestamp, data }) => {
  const sub = subscriptions.get(subscriptionId);
  const msg = sub.reader.readMessage(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  out({ topic: sub.topic, logTime: timestamp.toString(), msg });
});
client.on("error", (err) => {
  process.stderr.write(`view_client: ${err}\n`);
  process.exitCode = 1;
});
