// See plc_core.h; the contract is docs/plc.md.
#include "plc_core.h"

#include <string.h>

namespace plc {
namespace {

uint16_t be16(const uint8_t* p) { return static_cast<uint16_t>((p[0] << 8) | p[1]); }

void put_be16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v >> 8);
  p[1] = static_cast<uint8_t>(v & 0xff);
}

void keep(uint16_t list[][2], uint32_t count_before, uint16_t a, uint16_t b) {
  if (count_before < kMaxListed) {
    list[count_before][0] = a;
    list[count_before][1] = b;
  }
}

const uint8_t kReadHolding = 3;
const uint8_t kReadInput = 4;
const uint8_t kWriteSingle = 6;
const uint8_t kWriteMultiple = 16;
const uint16_t kMaxReadQuantity = 125;   // Modbus spec: 125 registers per read
const uint16_t kMaxWriteQuantity = 123;  // Modbus spec: 123 registers per FC 16

}  // namespace

Core::Core(const Config& config) : config_(config) {
  if (config_.channels > kMaxChannels) config_.channels = kMaxChannels;
  memset(&records_, 0, sizeof(records_));
  power_up();
}

void Core::power_up() {
  memset(holding_, 0, sizeof(holding_));
  memset(input_, 0, sizeof(input_));
  memset(outputs_, 0, sizeof(outputs_));
  has_reference_ = false;
  last_seq_ = 0;
  // Vented until a live client proves itself by changing the heartbeat: registers left from
  // an earlier session must not pressurise the suit with nobody supervising it.
  armed_ = false;
  has_baseline_ = false;
  last_heartbeat_ = 0;
  last_change_ms_ = 0;
  bad_frame_ = false;
  owner_ = 0;
  owner_peer_ = Peer();
  // A power cycle releases the vent latch (it is not kept in EEPROM); the suit is vented at
  // power-up anyway until a client's heartbeat arms the watchdog (docs/plc.md).
  latched_ = false;
  claim_pending_ = false;
  owner_heard_ms_ = 0;
  handling_ = 0;
  handling_peer_ = Peer();
}

size_t Core::handle(ConnectionId connection, const uint8_t* req, size_t len, uint8_t* out,
                    size_t cap, Peer peer) {
  bad_frame_ = false;
  handling_ = connection;
  handling_peer_ = peer;
  if (cap < kMaxAdu) return 0;
  // MBAP: transaction id (2), protocol id (2, always 0), length (2: unit id + PDU), unit id.
  if (len < kMbapLength + 1 || be16(req + 2) != 0 || be16(req + 4) != len - 6) {
    bad_frame_ = true;
    return 0;
  }
  if (req[6] != config_.unit_id) return 0;  // silence: another unit's request
  const uint8_t* pdu = req + kMbapLength;
  const size_t pdu_len = len - kMbapLength;
  uint8_t* pdu_out = out + kMbapLength;
  const size_t pdu_cap = cap - kMbapLength;
  size_t n;
  switch (pdu[0]) {
    case kReadHolding: n = read_registers(pdu, pdu_len, pdu_out, pdu_cap, true); break;
    case kReadInput: n = read_registers(pdu, pdu_len, pdu_out, pdu_cap, false); break;
    case kWriteSingle: n = write_single(pdu, pdu_len, pdu_out); break;
    case kWriteMultiple: n = write_multiple(pdu, pdu_len, pdu_out); break;
    default: n = exception(pdu[0], kIllegalFunction, pdu_out); break;
  }
  memcpy(out, req, 4);  // transaction and protocol id echoed
  put_be16(out + 4, static_cast<uint16_t>(n + 1));
  out[6] = req[6];
  return kMbapLength + n;
}

size_t Core::exception(uint8_t function, uint8_t code, uint8_t* pdu_out) {
  pdu_out[0] = static_cast<uint8_t>(function | 0x80);
  pdu_out[1] = code;
  return 2;
}

size_t Core::read_registers(const uint8_t* pdu, size_t len, uint8_t* pdu_out, size_t cap,
                            bool holding) {
  if (len != 5) return exception(pdu[0], kIllegalDataValue, pdu_out);
  const uint16_t start = be16(pdu + 1);
  const uint16_t quantity = be16(pdu + 3);
  if (quantity == 0 || quantity > kMaxReadQuantity) {
    return exception(pdu[0], kIllegalDataValue, pdu_out);
  }
  const uint32_t size = holding ? holding_count() : input_count();
  if (static_cast<uint32_t>(start) + quantity > size) {
    return exception(pdu[0], kIllegalDataAddress, pdu_out);
  }
  if (2u + 2u * quantity > cap) return exception(pdu[0], kIllegalDataValue, pdu_out);
  pdu_out[0] = pdu[0];
  pdu_out[1] = static_cast<uint8_t>(2 * quantity);
  for (uint16_t i = 0; i < quantity; ++i) {
    put_be16(pdu_out + 2 + 2 * i, holding ? holding_[start + i] : input(start + i));
  }
  return 2 + 2 * quantity;
}

size_t Core::write_single(const uint8_t* pdu, size_t len, uint8_t* pdu_out) {
  if (len != 5) return exception(pdu[0], kIllegalDataValue, pdu_out);
  const uint16_t address = be16(pdu + 1);
  if (address >= holding_count()) {
    keep(records_.out_of_map_list, records_.out_of_map, address, be16(pdu + 3));
    ++records_.out_of_map;
    return exception(pdu[0], kIllegalDataAddress, pdu_out);
  }
  bool vent_only = false;
  const uint8_t refused = vent_register_check(address, pdu + 3, 1, &vent_only);
  if (refused) return exception(pdu[0], refused, pdu_out);
  if (!vent_only && !may_write(handling_, handling_peer_)) {
    return exception(pdu[0], kServerDeviceBusy, pdu_out);
  }
  apply_write(address, pdu + 3, 1);
  memcpy(pdu_out, pdu, 5);  // the normal answer echoes the request, also when it was undone
  return 5;
}

size_t Core::write_multiple(const uint8_t* pdu, size_t len, uint8_t* pdu_out) {
  if (len < 6) return exception(pdu[0], kIllegalDataValue, pdu_out);
  const uint16_t start = be16(pdu + 1);
  const uint16_t quantity = be16(pdu + 3);
  const uint8_t byte_count = pdu[5];
  if (quantity == 0 || quantity > kMaxWriteQuantity || byte_count != 2 * quantity ||
      len != 6u + byte_count) {
    return exception(pdu[0], kIllegalDataValue, pdu_out);
  }
  if (static_cast<uint32_t>(start) + quantity > holding_count()) {
    keep(records_.out_of_map_list, records_.out_of_map, start, be16(pdu + 6));
    ++records_.out_of_map;
    return exception(pdu[0], kIllegalDataAddress, pdu_out);
  }
  bool vent_only = false;
  const uint8_t refused = vent_register_check(start, pdu + 6, quantity, &vent_only);
  if (refused) return exception(pdu[0], refused, pdu_out);
  if (!vent_only && !may_write(handling_, handling_peer_)) {
    return exception(pdu[0], kServerDeviceBusy, pdu_out);
  }
  apply_write(start, pdu + 6, quantity);
  memcpy(pdu_out, pdu, 5);
  return 5;
}

uint8_t Core::vent_register_check(uint16_t start, const uint8_t* be_values, uint16_t count,
                                  bool* vent_only) {
  const uint16_t vent_at = static_cast<uint16_t>(config_.channels + 2);
  *vent_only = false;
  if (!(start <= vent_at && vent_at < static_cast<uint32_t>(start) + count)) return 0;
  const uint16_t v = be16(be_values + 2 * (vent_at - start));
  if (v != kVentRequest && v != kRearm) return kIllegalDataValue;
  // A vent request alone is anyone's: a stop must reach the suit from every connection, the
  // write claim's holder or not. It takes no claim.
  *vent_only = count == 1 && v == kVentRequest;
  // Only the holder re-arms; the claim check after this refuses anyone else with 06.
  return 0;
}

bool Core::may_write(ConnectionId connection, Peer peer) {
  if (owner_ != 0 && owner_ != connection) {
    // Refused whole, heartbeat included: another client's heartbeat must never keep the
    // watchdog armed for commands it did not write.
    ++records_.busy;
    return false;
  }
  if (owner_ == 0 && connection != 0) {
    owner_ = connection;
    owner_peer_ = peer;
    claim_pending_ = true;
    // A new writer's numbers have no relation to the last one's: its first is taken, as after
    // power-up. Writes of an earlier connection are refused above, so none can overtake it.
    has_reference_ = false;
  }
  return true;
}

void Core::connection_closed(ConnectionId connection) {
  if (connection == 0 || connection != owner_) return;
  owner_ = 0;
  owner_peer_ = Peer();
  claim_pending_ = false;
  ++records_.owner_lost;
  if (armed_) ++records_.watchdog_trips;  // tripped by the close, not by the time
  vent_now();
}

void Core::vent_now() {
  armed_ = false;
  zero_commands();
}

void Core::zero_commands() {
  for (uint8_t ch = 0; ch < config_.channels; ++ch) {
    holding_[ch] = 0;
    outputs_[ch] = 0;
  }
}

void Core::apply_write(uint16_t start, const uint8_t* be_values, uint16_t count) {
  const uint16_t n = config_.channels;
  const uint16_t seq_at = n, heartbeat_at = static_cast<uint16_t>(n + 1);
  const uint16_t vent_at = static_cast<uint16_t>(n + 2);
  const uint32_t end = static_cast<uint32_t>(start) + count;
  ++records_.writes;
  // The vent register first (its value was checked): a request that re-arms and commands
  // applies its commands; one that requests the vent does not.
  if (start <= vent_at && vent_at < end) {
    if (be16(be_values + 2 * (vent_at - start)) == kVentRequest) {
      ++records_.vent_requests;
      latched_ = true;
      zero_commands();  // at once, and at every scan while latched
    } else {
      ++records_.rearms;
      latched_ = false;
    }
    holding_[vent_at] = latched_ ? 1 : 0;
  }
  // Recorded before the gate: the records are about what was sent.
  for (uint16_t a = start; a < end && a < n; ++a) {
    const uint16_t v = be16(be_values + 2 * (a - start));
    if (v > records_.max_written[a]) records_.max_written[a] = v;
    if (v > config_.p_max_counts) {
      keep(records_.over_limit_list, records_.over_limit, a, v);
      ++records_.over_limit;
    }
  }
  const bool has_commands = start < n;
  const bool has_seq = start <= seq_at && seq_at < end;
  bool accept = false;
  if (has_seq) {
    const uint16_t seq = be16(be_values + 2 * (seq_at - start));
    if (!has_reference_ || is_newer(seq, last_seq_)) {
      accept = true;
      has_reference_ = true;
      last_seq_ = seq;
      holding_[seq_at] = seq;
    } else {
      keep(records_.stale_list, records_.stale, seq, last_seq_);
      ++records_.stale;
    }
  } else if (has_commands) {
    ++records_.unsequenced;  // no number: cannot be told from a late write, so undone
  }
  if (accept) {
    for (uint16_t a = start; a < end && a < n; ++a) {
      const uint16_t v = be16(be_values + 2 * (a - start));
      // Latched: the gate moves, the commands are stored as 0 (a read-back never shows one).
      holding_[a] = latched_ ? 0 : (v > config_.p_max_counts ? config_.p_max_counts : v);
    }
  }
  if (start <= heartbeat_at && heartbeat_at < end) {
    holding_[heartbeat_at] = be16(be_values + 2 * (heartbeat_at - start));
  }
}

void Core::scan(uint32_t now_ms) {
  const uint16_t heartbeat = holding_[config_.channels + 1];
  if (!has_baseline_) {
    has_baseline_ = true;
    last_heartbeat_ = heartbeat;
    last_change_ms_ = now_ms;
  } else if (heartbeat != last_heartbeat_) {
    last_heartbeat_ = heartbeat;
    last_change_ms_ = now_ms;
    // Only the claim holder can write the heartbeat, so a change is its proof of life.
    armed_ = owner_ != 0;
    owner_heard_ms_ = now_ms;
  } else if (armed_ && static_cast<uint32_t>(now_ms - last_change_ms_) >= config_.watchdog_ms) {
    armed_ = false;
    ++records_.watchdog_trips;
  }
  if (claim_pending_) {  // the claim's time: the first scan that sees it
    claim_pending_ = false;
    owner_heard_ms_ = now_ms;
  }
  // An owner silent for the watchdog's time (a half-open link, a client that stopped) loses
  // the claim: another client may then write. The watchdog has vented by then.
  if (owner_ != 0 && static_cast<uint32_t>(now_ms - owner_heard_ms_) >= config_.watchdog_ms) {
    owner_ = 0;
    owner_peer_ = Peer();
  }
  const bool live = armed_ && !latched_;
  for (uint8_t ch = 0; ch < config_.channels; ++ch) {
    if (!live) holding_[ch] = 0;
    // The clamp again on the way out: nothing above p_max reaches an output, whatever the
    // registers hold.
    const uint16_t v = holding_[ch];
    outputs_[ch] = live ? (v > config_.p_max_counts ? config_.p_max_counts : v) : 0;
  }
}

uint16_t Core::output_counts(uint8_t channel) const {
  return channel < config_.channels ? outputs_[channel] : 0;
}

void Core::set_measured(uint8_t channel, uint16_t counts) {
  if (channel < config_.channels) input_[channel] = counts;
}

uint16_t Core::holding(uint16_t address) const {
  return address < holding_count() ? holding_[address] : 0;
}

uint16_t Core::input(uint16_t address) const {
  const uint16_t n = config_.channels;
  if (address < n) return input_[address];
  // The claim holder's address (0 while the claim is free): who keeps a refused client out.
  if (address == n) return static_cast<uint16_t>(owner_peer_.ip >> 16);
  if (address == n + 1) return static_cast<uint16_t>(owner_peer_.ip & 0xffff);
  if (address == n + 2) return owner_peer_.port;
  return 0;
}

}  // namespace plc
