// Register counts <-> the regulators' analog signals. Portable (no Arduino header).
//
// The hardware numbers below are ASSUMPTIONS until checked against the devices on the bench
// (docs/plc.md, "Scaling"); change them here and nowhere else:
// - The paper's regulators are KOGANEI CRCB-0135W/0136W electro-pneumatic regulators. We take
//   their set-point input as 0-10 V for 0..kRegulatorFullScaleKpa and their monitor output as
//   0-10 V over the same range. Full scale 500 kPa is an assumption (it must be >= p_max, 375
//   kPa in the paper); read it off the regulator's label or datasheet.
// - The PLC is an Industrial Shields M-Duino (ATmega2560 family, part 007001001100 in the
//   paper). Its analog outputs give 0-10 V; we take analogWrite() as 8-bit (0..255) and its
//   analog inputs as 0-10 V read by a 10-bit analogRead() (0..1023). Both are assumptions
//   about the board variant.
#ifndef FABRIC_PLC_SCALING_H
#define FABRIC_PLC_SCALING_H

#include <stdint.h>

namespace plc {

const uint32_t kCountsPerKpa = 10;             // the register map's counts_per_kpa
const uint32_t kRegulatorFullScaleKpa = 500;   // ASSUMPTION, see above
const uint32_t kOutputMax = 255;               // analogWrite() full scale (= 10 V), ASSUMPTION
const uint32_t kInputMax = 1023;               // analogRead() full scale (= 10 V), ASSUMPTION
const uint32_t kFullScaleCounts = kRegulatorFullScaleKpa * kCountsPerKpa;

// Command counts -> analog output value. Rounded DOWN: the regulator is never asked for more
// than the command (with 8 bits one step is 500/255 ~ 2 kPa, so rounding to nearest could
// exceed p_max by up to half a step).
inline uint16_t counts_to_output(uint16_t counts) {
  uint32_t c = counts > kFullScaleCounts ? kFullScaleCounts : counts;
  return static_cast<uint16_t>(c * kOutputMax / kFullScaleCounts);
}

// Analog output value -> the pressure (counts) the regulator sets for it.
inline uint16_t output_to_counts(uint16_t output) {
  uint32_t o = output > kOutputMax ? kOutputMax : output;
  return static_cast<uint16_t>(o * kFullScaleCounts / kOutputMax);
}

// Monitor reading (analogRead) -> measured pressure in counts, rounded to nearest.
inline uint16_t input_to_counts(uint16_t input) {
  uint32_t i = input > kInputMax ? kInputMax : input;
  return static_cast<uint16_t>((i * kFullScaleCounts + kInputMax / 2) / kInputMax);
}

// Pressure in counts -> the monitor reading a regulator at that pressure gives (host
// simulation and tests), rounded to nearest.
inline uint16_t counts_to_input(uint16_t counts) {
  uint32_t c = counts > kFullScaleCounts ? kFullScaleCounts : counts;
  return static_cast<uint16_t>((c * kInputMax + kFullScaleCounts / 2) / kFullScaleCounts);
}

}  // namespace plc

#endif  // FABRIC_PLC_SCALING_H
