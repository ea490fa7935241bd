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

// The W5500 of the M-Duino has 8 sockets; one connection state per socket. One of them must
// stay free to listen, so a client that would take the last one makes the longest-silent
// other client (never the write claim's holder) give up its socket.
const uint8_t kSockets = 8;
EthernetServer server(plc::kModbusPort);
EthernetClient clients[kSockets];
plc::Connection connections[kSockets];
plc::ConnectionId next_id = 1;
plc::Core core(plc::Config{plc::kUnitId, plc::kChannels, plc::kPmaxCounts, plc::kWatchdogMs});
uint32_t last_scan_ms = 0;
// A locally administered MAC derived from the endpoint (set the board's own if it has one).
uint8_t mac[6] = {0x02, 0xFA, 0xB1, 0x00, 0x00, plc::kIp[3]};

// Without waiting: stop() sends a FIN, then with a connection timeout of 0 it looks once
// (about 1 ms) and closes the socket instead of waiting up to 1 s for the peer's answer.
void close_slot(uint8_t i) {
  clients[i].setConnectionTimeout(0);
  clients[i].stop();
  core.connection_closed(connections[i].id);  // vents if it held the write claim
  connections[i].id = 0;
}

void accept_client(uint32_t now) {
  EthernetClient incoming = server.accept();
  if (!incoming) return;
  incoming.setConnectionTimeout(0);
  uint8_t free_slot = kSockets, used = 0;
  for (uint8_t i = 0; i < kSockets; ++i) {
    if (connections[i].id == 0) {
      if (free_slot == kSockets) free_slot = i;
    } else {
      ++used;
    }
  }
  if (free_slot == kSockets) {  // cannot happen with one slot per socket; never block on it
    incoming.stop();
    return;
  }
  clients[free_slot] = incoming;
  const IPAddress ip = incoming.remoteIP();
  const plc::Peer peer = {(static_cast<uint32_t>(ip[0]) << 24) | (static_cast<uint32_t>(ip[1]) << 16) |
                              (static_cast<uint32_t>(ip[2]) << 8) | ip[3],
                          incoming.remotePort()};
  plc::open_connection(connections[free_slot], next_id++, now, peer);
  if (next_id == 0) next_id = 1;
  if (used + 1 < kSockets - 1) return;
  uint8_t idlest = kSockets;
  for (uint8_t i = 0; i < kSockets; ++i) {
    if (connections[i].id == 0 || connections[i].id == core.owner() || i == free_slot) continue;
    if (idlest == kSockets || static_cast<uint32_t>(now - connections[i].last_rx_ms) >
                                  static_cast<uint32_t>(now - connections[idlest].last_rx_ms)) {
      idlest = i;
    }
  }
  if (idlest != kSockets) close_slot(idlest);
}

}  // namespace

void setup() {
  plc::io_begin();  // outputs vented before anything else
  Ethernet.begin(mac, IPAddress(plc::kIp[0], plc::kIp[1], plc::kIp[2], plc::kIp[3]));
  // Short W5500 retries (wiring.h): a dead peer's socket and a failed send end in well under
  // the watchdog's time instead of the chip's default 31.8 s (its datasheet's TCP timeout).
  Ethernet.setRetransmissionTimeout(plc::kRetransmitMs);
  Ethernet.setRetransmissionCount(plc::kRetransmitCount);
  server.begin();
  last_scan_ms = millis();
}

// One pass: the scan when due, at most one new client, at most one request per client; no
// call waits on the network (plc_link.h), so a pass stays within the scan budget (docs/plc.md).
void loop() {
  const uint32_t now = millis();
  if (static_cast<uint32_t>(now - last_scan_ms) >= plc::kScanMs) {
    last_scan_ms = now;
    plc::io_scan(core, now);
  }
  accept_client(now);
  for (uint8_t i = 0; i < kSockets; ++i) {
    if (connections[i].id == 0) continue;
    plc::ClientLink link{clients[i]};
    if (plc::serve_once(core, link, connections[i], now) != plc::kKeep) close_slot(i);
  }
}
