// Which register channel drives which analog output and reads which monitor input, per PLC
// endpoint. ASSUMPTION (docs/plc.md, "Wiring"): three Industrial Shields M-Duino 58+ (8 analog
// outputs 0-10 V each, analog inputs 0-10 V); change these tables to the lab's wiring.
// Build one endpoint with -DFABRIC_PLC_ENDPOINT=1, 2 or 3 (the Arduino IDE: edit the default
// below). The register map (config/plc_register_map.yaml) must give that endpoint the same
// channels in the same order.
#ifndef FABRIC_PLC_WIRING_H
#define FABRIC_PLC_WIRING_H

#include <stdint.h>

#ifndef FABRIC_PLC_ENDPOINT
#define FABRIC_PLC_ENDPOINT 1
#endif

#if defined(FABRIC_PLC_GENERIC_MEGA_PINS)
// Compile check without Industrial Shields' board package (Debian's arduino-core-avr in CI):
// plain Arduino Mega PWM and analog pins. NOT the M-Duino's wiring; never flash this.
#define OUT_1 2
#define OUT_2 3
#define OUT_3 4
#define OUT_4 5
#define OUT_5 6
#define OUT_6 7
#define OUT_7 8
#define OUT_8 9
#define IN_1 A0
#define IN_2 A1
#define IN_3 A2
#define IN_4 A3
#define IN_5 A4
#define IN_6 A5
#define IN_7 A6
#define IN_8 A7
#else
// Industrial Shields' board package names (M-Duino 58+): analog outputs and inputs.
#define OUT_1 A0_5
#define OUT_2 A0_6
#define OUT_3 A0_7
#define OUT_4 A1_5
#define OUT_5 A1_6
#define OUT_6 A1_7
#define OUT_7 A2_5
#define OUT_8 A2_6
#define IN_1 I0_7
#define IN_2 I0_8
#define IN_3 I0_9
#define IN_4 I0_10
#define IN_5 I0_11
#define IN_6 I0_12
#define IN_7 I1_7
#define IN_8 I1_8
#endif

namespace plc {

#if FABRIC_PLC_ENDPOINT == 1
// F1 F2 F3 F4 B1 B2 B3 B4 (front and back muscles); unit id 1, 192.168.1.11
const uint8_t kUnitId = 1;
const uint8_t kIp[4] = {192, 168, 1, 11};
const uint8_t kOutputPins[] = {OUT_1, OUT_2, OUT_3, OUT_4, OUT_5, OUT_6, OUT_7, OUT_8};
const uint8_t kMonitorPins[] = {IN_1, IN_2, IN_3, IN_4, IN_5, IN_6, IN_7, IN_8};
#elif FABRIC_PLC_ENDPOINT == 2
// L1 L2 R1 R2 (sides) arm_i arm_ii arm_iii arm_iv; unit id 1, 192.168.1.12
const uint8_t kUnitId = 1;
const uint8_t kIp[4] = {192, 168, 1, 12};
const uint8_t kOutputPins[] = {OUT_1, OUT_2, OUT_3, OUT_4, OUT_5, OUT_6, OUT_7, OUT_8};
const uint8_t kMonitorPins[] = {IN_1, IN_2, IN_3, IN_4, IN_5, IN_6, IN_7, IN_8};
#elif FABRIC_PLC_ENDPOINT == 3
// arm_v arm_vi; unit id 1, 192.168.1.13
const uint8_t kUnitId = 1;
const uint8_t kIp[4] = {192, 168, 1, 13};
const uint8_t kOutputPins[] = {OUT_1, OUT_2};
const uint8_t kMonitorPins[] = {IN_1, IN_2};
#else
#error "FABRIC_PLC_ENDPOINT must be 1, 2 or 3"
#endif

const uint8_t kChannels = sizeof(kOutputPins);
static_assert(sizeof(kMonitorPins) == sizeof(kOutputPins), "one monitor input per output");
const uint16_t kModbusPort = 502;
const uint16_t kPmaxCounts = 3750;   // p_max_kpa 375 * counts_per_kpa 10 (the register map)
const uint32_t kWatchdogMs = 500;    // the register map's watchdog (mock_plc watchdog_s 0.5)
const uint32_t kScanMs = 10;
// W5500 retransmission: 20 ms, 3 retries. Its datasheet's timeouts then: ARP 20 x (3 + 1) =
// 80 ms; TCP 20 x (1 + 2 + 4 + 8) = 300 ms (the defaults, 200 ms and 8: 1.8 s and 31.8 s).
// A lab LAN answers in well under 1 ms.
const uint16_t kRetransmitMs = 20;
const uint8_t kRetransmitCount = 3;

}  // namespace plc

#endif  // FABRIC_PLC_WIRING_H
