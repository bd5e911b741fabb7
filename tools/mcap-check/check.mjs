// Reads an MCAP file as Foxglove does, with @mcap/core's indexed reader (chunk indexes,
// zstd/lz4 chunks through @mcap/support, CRCs checked) and its stream reader, and prints a
// JSON summary for tests/backend/test_clinical_exports.py:
//   node tools/mcap-check/check.mjs FILE.mcap
import { readFile } from "node:fs/promises";

import { McapIndexedReader, McapStreamReader } from "@mcap/core";
import { loadDecompressHandlers } from "@mcap/support";

const data = new Uint8Array(await readFile(process.argv[2]));
const decompressHandlers = await loadDecompressHandlers();
const readable = {
  size: async () => BigInt(data.byteLength),
  read: async (offset, size) => data.subarray(Number(offset), Number(offset + size)),
};
const reader = await McapIndexedReader.Initialize({ readable, decompressHandlers });
const utf8 = new TextDecoder();
const topics = {};
let count = 0;
let ordered = true;
let last = -1n;
for await (const msg of reader.readMessages({ validateCrcs: true })) {
  const channel = reader.channelsById.get(msg.channelId);
  const schema = reader.schemasById.get(channel.schemaId);
  if (channel.messageEncoding !== "json" || schema.encoding !== "jsonschema") {
    throw new Error(`${channel.topic}: ${channel.messageEncoding} / ${schema.encoding}`);
  }
  JSON.parse(utf8.decode(msg.data)); // Foxglove decodes every json message
  topics[channel.topic] = (topics[channel.topic] ?? 0) + 1;
  if (msg.logTime < last) ordered = false;
  last = msg.logTime;
  count++;
}
// the stream reader (Foxglove's path for a file without index) sees the same messages
const stream = new McapStreamReader({ decompressHandlers, validateCrcs: true });
stream.append(data);
let streamed = 0;
for (let rec; (rec = stream.nextRecord()); ) {
  if (rec.type === "Message") streamed++;
}
if (!stream.done()) throw new Error("the stream reader did not reach the footer");
const schemas = [...reader.schemasById.values()].map((s) => {
  JSON.parse(utf8.decode(s.data));
  return s.name;
});
console.log(JSON.stringify({
  messages: count,
  streamed,
  ordered,
  topics,
  schemas,
  statistics: Number(reader.statistics?.messageCount ?? -1n),
}));
