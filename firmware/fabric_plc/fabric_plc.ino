// fabric_guidance PLC program: Modbus TCP in, 0-10 V set points to the electro-pneumatic
// regulators out, their monitors back into input registers; the heartbeat watchdog vents.
// The logic is the portable core in src/ (tested on the host); this sketch only wires it to
// the Ethernet shield and the analog I/O. The contract and how to flash: docs/plc.md.
// Build one endpoint per PLC: FABRIC_PLC_ENDPOINT in wiring.h.
#include <SPI.h>
#include <Ethernet.h>

#include "plc_io.h"
#include "src/plc_core.h"
#include "wiring.h"

namespace {

// The W5500 of the M-Duino has 8 sockets; one connection state per socket.
const uint8_t kSockets = 8;
EthernetServer server(plc::kModbusPort);
EthernetClient clients[kSockets];
plc::Connection connections[kSockets];
plc::Core core(plc::Config{plc::kUnitId, plc::kChannels, plc::kPmaxCounts, plc::kWatchdogMs});
uint32_t last_scan_ms = 0;
// A locally administered MAC derived from the endpoint (set the board's own if it has one).
uint8_t mac[6] = {0x02, 0xFA, 0xB1, 0x00, 0x00, plc::kIp[3]};

}  // namespace

void setup() {
  plc::io_begin();  // outputs vented before anything else
  Ethernet.begin(mac, IPAddress(plc::kIp[0], plc::kIp[1], plc::kIp[2], plc::kIp[3]));
  server.begin();
  last_scan_ms = millis();
}

void loop() {
  const uint32_t now = millis();
  // New connections go to a free slot; a full table refuses them (the client retries).
  EthernetClient incoming = server.accept();
  if (incoming) {
    bool placed = false;
    for (uint8_t i = 0; i < kSockets && !placed; ++i) {
      if (!clients[i]) {
        clients[i] = incoming;
        connections[i].length = 0;
        connections[i].last_byte_ms = now;
        placed = true;
      }
    }
    if (!placed) incoming.stop();
  }
  for (uint8_t i = 0; i < kSockets; ++i) {
    if (!clients[i]) continue;
    if (!clients[i].connected() && clients[i].available() == 0) {
      clients[i].stop();
      continue;
    }
    if (!plc::io_serve(core, clients[i], connections[i], now)) clients[i].stop();
  }
  if (static_cast<uint32_t>(now - last_scan_ms) >= plc::kScanMs) {
    last_scan_ms = now;
    plc::io_scan(core, now);
  }
}
