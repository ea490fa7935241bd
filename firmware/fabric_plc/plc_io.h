// The sketch's side of the hardware, on the Arduino API only (no Ethernet header): the core's
// outputs to the analog outputs, the regulators' monitors to the input registers, and Modbus
// TCP frames from an Arduino Client (EthernetClient is one) through the core.
#ifndef FABRIC_PLC_IO_H
#define FABRIC_PLC_IO_H

#include <Arduino.h>
#include <Client.h>

#include "src/plc_core.h"
#include "src/plc_link.h"

namespace plc {

// Pins to outputs and vents them: called first thing in setup().
void io_begin();
// One scan: watchdog, outputs written, monitors read into the input registers.
void io_scan(Core& core, uint32_t now_ms);
// Every outputs to 0 V (vent), whatever the core says.
void io_vent();

// An Arduino Client (EthernetClient) as plc_link.h's Link: serve_once() through it never
// waits on the network. A Client without availableForWrite() (Print's default: 0) is never
// written to: its connection is closed as stalled, never a blocking write.
struct ClientLink {
  Client& client;
  int available() { return client.available(); }
  int read(uint8_t* buf, size_t n) { return client.read(buf, n); }
  int availableForWrite() { return client.availableForWrite(); }
  size_t write(const uint8_t* buf, size_t n) { return client.write(buf, n); }
  // EthernetClient::connected() is false once the peer closed and nothing is left to read.
  bool peer_open() { return client.connected() != 0; }
};

}  // namespace plc

#endif  // FABRIC_PLC_IO_H
