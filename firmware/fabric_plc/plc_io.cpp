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

}  // namespace plc
