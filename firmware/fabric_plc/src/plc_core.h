// The PLC program's logic, portable: no Arduino header, no socket, no clock of its own.
// Register arrays, the Modbus TCP frame handler (function codes 3, 4, 6, 16 and the exception
// replies), the sequence gate, the clamp to p_max counts and the heartbeat watchdog, exactly as
// docs/plc.md ("The contract") states them. The sketch (fabric_plc.ino) and the host build
// (host/plc_host.cpp) feed it frames and the time and move output_counts() to the outputs.
// C++11 (avr-g++ 5.4 of Debian's gcc-avr); no heap, fixed-size arrays only.
#ifndef FABRIC_PLC_CORE_H
#define FABRIC_PLC_CORE_H

#include <stddef.h>
#include <stdint.h>

namespace plc {

// Channels one endpoint can serve at most (the default map has 18 on one endpoint).
const uint8_t kMaxChannels = 32;
// Largest Modbus TCP frame: 7 bytes MBAP header + 253 bytes PDU.
const size_t kMaxAdu = 260;
const size_t kMbapLength = 7;
// Entries kept per record list (the counts are always complete).
const uint8_t kMaxListed = 8;

enum Exception : uint8_t {
  kIllegalFunction = 0x01,
  kIllegalDataAddress = 0x02,
  kIllegalDataValue = 0x03,
  kServerDeviceBusy = 0x06,  // a write from a connection that does not hold the write claim
};

// A connection as the platform numbers it (never reused while the program runs); 0 is none.
typedef uint32_t ConnectionId;

// The client's address as the platform saw it at accept (IPv4 in host order); 0.0.0.0:0 unknown.
struct Peer {
  uint32_t ip;
  uint16_t port;
};

// The vent register (holding N+2): any connection may write kVentRequest (the vent latch is set,
// every command register 0 and every output 0 V at once, kept at every scan); only the claim's
// holder may write kRearm (the latch released; nothing starts: the commands stay 0 until its
// next write). Any other value: exception 03. It reads 1 while latched, else 0.
const uint16_t kVentRequest = 1;
const uint16_t kRearm = 2;

struct Config {
  uint8_t unit_id;        // Modbus unit id this endpoint answers to (1..247)
  uint8_t channels;       // N: command registers 0..N-1, sequence N, heartbeat N+1
  uint16_t p_max_counts;  // p_max_kpa * counts_per_kpa of the register map
  uint32_t watchdog_ms;   // heartbeat unchanged this long -> vent
};

// True when seq is 1..32767 ahead of last modulo 65536 (fabric_guidance/plc/sequence.py).
inline bool is_newer(uint16_t seq, uint16_t last) {
  uint16_t ahead = static_cast<uint16_t>(seq - last);
  return ahead != 0 && ahead < 0x8000u;
}

// What clients sent, for the records file of the host build and for the unit tests.
struct Records {
  uint32_t writes;               // write requests to holding registers that were in the map
  uint32_t over_limit;           // values above p_max counts written to a command register
  uint32_t out_of_map;           // write requests refused with exception 02
  uint32_t stale;                // sequenced writes refused as not newer
  uint32_t unsequenced;          // command writes without a sequence number, refused
  uint32_t watchdog_trips;       // armed -> tripped transitions (silence, or the holder's close)
  uint32_t busy;                 // writes refused with exception 06: another connection's claim
  uint32_t owner_lost;           // the claim holder's connection closed (vented if armed)
  uint32_t vent_requests;        // kVentRequest written to the vent register (any connection)
  uint32_t rearms;               // kRearm written by the claim's holder
  uint16_t max_written[kMaxChannels];  // largest count ever sent per channel (before the clamp)
  uint16_t over_limit_list[kMaxListed][2];  // (address, value)
  uint16_t out_of_map_list[kMaxListed][2];  // (first address, first value)
  uint16_t stale_list[kMaxListed][2];       // (sequence number, last applied)
};

class Core {
 public:
  explicit Core(const Config& config);

  // Power-up: every register 0, the gate with no reference, the watchdog tripped.
  // The records are kept (a restart of the program is not a new test).
  void power_up();

  // One Modbus TCP request (MBAP header + PDU, `len` bytes) from `connection` -> the answer in
  // `out` (capacity `cap`, at least kMaxAdu). A write is taken only from the connection that
  // holds the write claim (the first to write while it is free claims it); any other gets
  // exception 06 and changes nothing. Returns the answer's length; 0 means no answer at all: another
  // unit id, or a frame that is not Modbus TCP (the caller then drops the connection if
  // bad_frame() says so). `peer` is the connection's address, shown in the claim holder's input
  // registers (N..N+2) while it holds the claim.
  size_t handle(ConnectionId connection, const uint8_t* req, size_t len, uint8_t* out,
                size_t cap, Peer peer = Peer());
  // The platform closed `connection` (the peer left, or it was reaped). If it held the write
  // claim: every command register to 0 and the outputs vented now, the claim free.
  void connection_closed(ConnectionId connection);
  ConnectionId owner() const { return owner_; }
  // True when the last handle() saw a broken MBAP header (protocol id, length): the stream
  // cannot be re-synchronised, the connection should be closed.
  bool bad_frame() const { return bad_frame_; }

  // One PLC scan at monotonic time now_ms (wraps every 49 days; unsigned differences are used).
  // Feeds the watchdog the heartbeat register; while it is tripped the command registers are
  // zeroed. After scan(), output_counts() is what the outputs must show.
  void scan(uint32_t now_ms);
  uint16_t output_counts(uint8_t channel) const;
  bool vented() const { return !armed_ || latched_; }
  bool vent_latched() const { return latched_; }

  // The regulators' monitor, already scaled to counts (scaling.h), into input register ch.
  void set_measured(uint8_t channel, uint16_t counts);

  uint16_t holding(uint16_t address) const;
  uint16_t input(uint16_t address) const;
  // Holding: commands 0..N-1, sequence N, heartbeat N+1, vent register N+2. Input: measured
  // 0..N-1, then the claim holder's IPv4 address (N: high, N+1: low 16 bits) and port (N+2).
  uint16_t holding_count() const { return static_cast<uint16_t>(config_.channels + 3); }
  uint16_t input_count() const { return static_cast<uint16_t>(config_.channels + 3); }
  const Config& config() const { return config_; }
  const Records& records() const { return records_; }
  uint32_t rejected_writes() const { return records_.stale + records_.unsequenced; }

 private:
  size_t exception(uint8_t function, uint8_t code, uint8_t* pdu_out);
  size_t read_registers(const uint8_t* pdu, size_t len, uint8_t* pdu_out, size_t cap,
                        bool holding);
  size_t write_single(const uint8_t* pdu, size_t len, uint8_t* pdu_out);
  size_t write_multiple(const uint8_t* pdu, size_t len, uint8_t* pdu_out);
  // False (and exception 06 in pdu_out) when `connection` may not write now; claims a free
  // claim for it.
  bool may_write(ConnectionId connection, Peer peer);
  // 0 when the values a write puts into the vent register (if it covers it) are allowed for
  // `connection`, else the exception code (03 a value that is neither, 06 a re-arm by another
  // connection than the holder's). *vent_only: the request writes the vent register alone.
  uint8_t vent_register_check(uint16_t start, const uint8_t* be_values, uint16_t count,
                              bool* vent_only);
  // Applies a write that lies inside the holding registers: the gate, the clamp, the records.
  void apply_write(uint16_t start, const uint8_t* be_values, uint16_t count);
  void vent_now();       // the watchdog tripped by a close: vented until a heartbeat change
  void zero_commands();  // every command register and output 0

  Config config_;
  uint16_t holding_[kMaxChannels + 3];
  uint16_t input_[kMaxChannels];
  uint16_t outputs_[kMaxChannels];
  bool has_reference_;   // the gate has applied a sequence number since power-up
  uint16_t last_seq_;
  bool armed_;
  bool has_baseline_;
  uint16_t last_heartbeat_;
  uint32_t last_change_ms_;
  bool bad_frame_;
  ConnectionId owner_;       // holds the write claim; 0: free
  Peer owner_peer_;          // its address
  bool latched_;             // the vent latch (vent register): set by anyone, reset by the holder
  bool claim_pending_;       // claimed since the last scan (its time is taken there)
  uint32_t owner_heard_ms_;  // the claim, or the owner's last heartbeat change
  ConnectionId handling_;    // the connection of the request being handled
  Peer handling_peer_;       // and its address
  Records records_;
};

}  // namespace plc

#endif  // FABRIC_PLC_CORE_H
