// The /ws/live binary wire format (gcs/server/wire.py says why and lays it out): a message is
// frames back to back, each starting u32 length · u8 kind · u8 version · u16 count, every block
// 8-byte aligned so the arrays are views on the message's buffer, never copies.
"use strict";

const WIRE_VERSION = 1, WIRE_POINTS = 1, WIRE_MESSAGE = 2;

// Calls onFrame for each frame of an ArrayBuffer, in order: {type: "points", seq, server_time,
// points: {source: [t, roll, pitch, yaw]}} (Float64Array, then Float32Array ×3), or the JSON
// object of a control message. Throws on a frame that does not fit or has another version.
function decodeWire(buffer, onFrame) {
  const view = new DataView(buffer), text = new TextDecoder();
  for (let offset = 0; offset < buffer.byteLength;) {
    const size = view.getUint32(offset, true), kind = view.getUint8(offset + 4), version = view.getUint8(offset + 5);
    const count = view.getUint16(offset + 6, true), end = offset + size;
    if (version !== WIRE_VERSION || size < 8 || end > buffer.byteLength) throw new Error(`bad frame at byte ${offset}`);
    let at = offset + 8;
    if (kind === WIRE_POINTS) {
      const frame = { type: "points", seq: view.getUint32(at, true), server_time: view.getFloat64(at + 8, true), points: {} };
      at += 16;
      for (let k = 0; k < count; k++) {
        const nameLen = view.getUint16(at, true), n = view.getUint32(at + 4, true);
        at += 8;
        const name = text.decode(new Uint8Array(buffer, at, nameLen));
        at += nameLen + ((8 - (nameLen % 8)) % 8);
        const t = new Float64Array(buffer, at, n);
        at += 8 * n;
        frame.points[name] = [t, new Float32Array(buffer, at, n), new Float32Array(buffer, at + 4 * n, n), new Float32Array(buffer, at + 8 * n, n)];
        at += 12 * n + ((8 - ((12 * n) % 8)) % 8);
      }
      onFrame(frame);
    } else if (kind === WIRE_MESSAGE) {
      onFrame(JSON.parse(text.decode(new Uint8Array(buffer, at, end - at)).replace(/\0+$/, "")));
    }
    offset = end;
  }
}
