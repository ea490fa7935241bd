// See plc_io.h.
#include "plc_io.h"

#include "src/scaling.h"
#include "wiring.h"

namespace plc {

void io_begin() {
  for (uint8_t ch = 0; ch < kChannels; ++ch) {
    pinMode(kOutputPins[ch], OUTPUT);
    analogWrite(kOutputPins[ch], 0);
  }
}

void io_vent() {
  for (uint8_t ch = 0; ch < kChannels; ++ch) analogWrite(kOutputPins[ch], 0);
}

void io_scan(Core& core, uint32_t now_ms) {
  core.scan(now_ms);
  for (uint8_t ch = 0; ch < kChannels; ++ch) {
    analogWrite(kOutputPins[ch], counts_to_output(core.output_counts(ch)));
    core.set_measured(ch, input_to_counts(static_cast<uint16_t>(analogRead(kMonitorPins[ch]))));
  }
}

bool io_serve(Core& core, Client& client, Connection& c, uint32_t now_ms) {
  while (client.available() > 0) {
    int byte = client.read();
    if (byte < 0) break;
    if (c.length >= kMaxAdu) return false;
    c.buffer[c.length++] = static_cast<uint8_t>(byte);
    c.last_byte_ms = now_ms;
    if (c.length < kMbapLength) continue;
    const uint16_t total = static_cast<uint16_t>(6 + ((c.buffer[4] << 8) | c.buffer[5]));
    if (total < kMbapLength + 1 || total > kMaxAdu) return false;  // cannot resynchronise
    if (c.length < total) continue;
    uint8_t out[kMaxAdu];
    const size_t n = core.handle(c.buffer, total, out, sizeof(out));
    c.length = 0;
    if (core.bad_frame()) return false;
    if (n > 0 && client.write(out, n) != n) return false;
  }
  // A frame cut short by a dead client must not block the connection forever.
  return c.length == 0 || static_cast<uint32_t>(now_ms - c.last_byte_ms) < 1000;
}

}  // namespace plc
