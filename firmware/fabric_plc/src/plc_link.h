// One client connection served without ever waiting on the network, for the sketch (W5500
// sockets through the Arduino Ethernet library) and the host build (POSIX sockets) alike.
// Why: the same loop() that answers requests runs the watchdog, so a call that waits for a
// peer (a full send buffer, a graceful close) would hold the outputs past the watchdog. Every
// call made here returns at once; what cannot be done at once closes the connection, and the
// core vents if it held the write claim (docs/plc.md, "Timing").
//
// `Link` is the platform's connection, with these members (EthernetClient's meanings):
//   int available();                    bytes received and not read yet
//   int read(uint8_t* buf, size_t n);   up to n of them
//   int availableForWrite();            bytes that can be sent without waiting
//   size_t write(const uint8_t* buf, size_t n);   only called with n <= availableForWrite()
//   bool peer_open();                   false once the peer closed and nothing is left to read
#ifndef FABRIC_PLC_LINK_H
#define FABRIC_PLC_LINK_H

#include <stddef.h>
#include <stdint.h>

#include "plc_core.h"

namespace plc {

// No byte from a client for this long: its socket is reaped (a half-open link after a cable
// pull, a tool that left without closing). Longer than plc_output's longest pause between two
// tries on a refusing PLC (reconnect_max_s 5 s), which keeps its connection; a reader polling
// more slowly is reconnected by its client library.
const uint32_t kIdleMs = 10000;
// A request begun and not finished for this long: the client is gone mid-frame.
const uint32_t kPartialFrameMs = 1000;

struct Connection {
  ConnectionId id;     // 0: the slot is free
  Peer peer;           // the client's address (shown while it holds the write claim)
  uint32_t last_rx_ms;
  uint16_t length;
  uint8_t buffer[kMaxAdu];
};

enum Verdict : uint8_t {
  kKeep = 0,
  kPeerClosed,     // the client closed its side
  kIdle,           // silent for kIdleMs, or a frame cut short for kPartialFrameMs
  kStalled,        // the client does not read its answers: no room for the next one
  kBadFrame,       // not Modbus TCP: the stream cannot be re-synchronised
};

inline void open_connection(Connection& c, ConnectionId id, uint32_t now_ms,
                            Peer peer = Peer()) {
  c.id = id;
  c.peer = peer;
  c.last_rx_ms = now_ms;
  c.length = 0;
}

// One pass over one connection: reads at most the rest of one request, answers it if it is
// complete. Anything but kKeep: the caller closes the socket without waiting (the sketch:
// a connection timeout of 0) and then calls core.connection_closed(c.id).
template <class Link>
Verdict serve_once(Core& core, Link& link, Connection& c, uint32_t now_ms) {
  const int ready = link.available();
  if (ready <= 0) {
    if (!link.peer_open()) return kPeerClosed;
    const uint32_t quiet = static_cast<uint32_t>(now_ms - c.last_rx_ms);
    if (quiet >= kIdleMs || (c.length > 0 && quiet >= kPartialFrameMs)) return kIdle;
    return kKeep;
  }
  // The header first, then exactly the rest of this frame: the next one waits for the next
  // pass, so one pass handles at most one request per connection.
  size_t want = kMbapLength - (c.length < kMbapLength ? c.length : kMbapLength);
  if (c.length >= kMbapLength) {
    const size_t total = 6u + ((static_cast<size_t>(c.buffer[4]) << 8) | c.buffer[5]);
    want = total - c.length;
  }
  if (want > static_cast<size_t>(ready)) want = static_cast<size_t>(ready);
  const int got = link.read(c.buffer + c.length, want);
  if (got <= 0) return kKeep;
  c.length = static_cast<uint16_t>(c.length + got);
  c.last_rx_ms = now_ms;
  if (c.length < kMbapLength) return kKeep;
  const size_t total = 6u + ((static_cast<size_t>(c.buffer[4]) << 8) | c.buffer[5]);
  if (total < kMbapLength + 1 || total > kMaxAdu) return kBadFrame;
  if (c.length < total) return kKeep;
  uint8_t out[kMaxAdu];
  const size_t n = core.handle(c.id, c.buffer, total, out, sizeof(out), c.peer);
  c.length = 0;
  if (core.bad_frame()) return kBadFrame;
  if (n == 0) return kKeep;
  // A Modbus client reads each answer before it asks again; an answer that does not fit in
  // the send buffer means a peer that stopped reading. Writing would wait for it.
  if (link.availableForWrite() < static_cast<int>(n)) return kStalled;
  if (link.write(out, n) != n) return kStalled;
  return kKeep;
}

}  // namespace plc

#endif  // FABRIC_PLC_LINK_H
