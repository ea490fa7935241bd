// The sketch's side of the hardware, on the Arduino API only (no Ethernet header): the core's
// outputs to the analog outputs, the regulators' monitors to the input registers, and Modbus
// TCP frames from an Arduino Client (EthernetClient is one) through the core.
#ifndef FABRIC_PLC_IO_H
#define FABRIC_PLC_IO_H

#include <Arduino.h>
#include <Client.h>

#include "src/plc_core.h"

namespace plc {

// Pins to outputs and vents them: called first thing in setup().
void io_begin();
// One scan: watchdog, outputs written, monitors read into the input registers.
void io_scan(Core& core, uint32_t now_ms);
// Every outputs to 0 V (vent), whatever the core says.
void io_vent();

// Per-connection frame assembly (the W5500 has 8 sockets; the sketch keeps one per socket).
struct Connection {
  uint8_t buffer[kMaxAdu];
  uint16_t length;
  uint32_t last_byte_ms;
};
// Reads what the client has, answers each complete frame; false: drop the connection
// (broken frame, or a partial frame older than 1 s).
bool io_serve(Core& core, Client& client, Connection& connection, uint32_t now_ms);

}  // namespace plc

#endif  // FABRIC_PLC_IO_H
