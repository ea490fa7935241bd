// Host unit tests of the portable core (plc_core, scaling): a tiny test main, no framework.
// Built and run by `make -C firmware unit` (test/test_plc_firmware.py runs that in `make test`).
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <vector>

#include "plc_core.h"
#include "plc_link.h"
#include "scaling.h"

namespace {

int failures = 0;
int checks = 0;

#define CHECK(cond)                                                             \
  do {                                                                          \
    ++checks;                                                                   \
    if (!(cond)) {                                                              \
      ++failures;                                                               \
      fprintf(stderr, "%s:%d: %s: CHECK(%s) failed\n", __FILE__, __LINE__,      \
              current_test, #cond);                                             \
    }                                                                           \
  } while (0)

const char* current_test = "";
const uint8_t kUnit = 1;
const uint8_t kN = 18;
const uint16_t kPmax = 3750;
const plc::ConnectionId kConn = 1;  // the one client of most tests

plc::Config config() { return plc::Config{kUnit, kN, kPmax, 500}; }

typedef std::vector<uint8_t> Bytes;

Bytes adu(const Bytes& pdu, uint8_t unit = kUnit, uint16_t tid = 0x1234) {
  Bytes f = {static_cast<uint8_t>(tid >> 8), static_cast<uint8_t>(tid & 0xff), 0, 0,
             static_cast<uint8_t>((pdu.size() + 1) >> 8),
             static_cast<uint8_t>((pdu.size() + 1) & 0xff), unit};
  f.insert(f.end(), pdu.begin(), pdu.end());
  return f;
}

void put(Bytes& b, uint16_t v) {
  b.push_back(static_cast<uint8_t>(v >> 8));
  b.push_back(static_cast<uint8_t>(v & 0xff));
}

Bytes read_pdu(uint8_t fc, uint16_t start, uint16_t quantity) {
  Bytes p = {fc};
  put(p, start);
  put(p, quantity);
  return p;
}

Bytes write16_pdu(uint16_t start, const std::vector<uint16_t>& values) {
  Bytes p = {16};
  put(p, start);
  put(p, static_cast<uint16_t>(values.size()));
  p.push_back(static_cast<uint8_t>(2 * values.size()));
  for (uint16_t v : values) put(p, v);
  return p;
}

Bytes write6_pdu(uint16_t address, uint16_t value) {
  Bytes p = {6};
  put(p, address);
  put(p, value);
  return p;
}

// The PDU of the answer (empty: no answer).
Bytes ask(plc::Core& core, const Bytes& frame) {
  uint8_t out[plc::kMaxAdu];
  size_t n = core.handle(kConn, frame.data(), frame.size(), out, sizeof(out));
  if (n == 0) return Bytes();
  return Bytes(out + plc::kMbapLength, out + n);
}

Bytes ask_pdu(plc::Core& core, const Bytes& pdu) { return ask(core, adu(pdu)); }

// Commands for every channel plus a sequence number, one FC 16 request.
Bytes command_pdu(const std::vector<uint16_t>& commands, uint16_t seq) {
  std::vector<uint16_t> values(commands);
  values.resize(kN, 0);
  values.push_back(seq);
  return write16_pdu(0, values);
}

bool is_exception(const Bytes& answer, uint8_t fc, uint8_t code) {
  return answer.size() == 2 && answer[0] == (fc | 0x80) && answer[1] == code;
}

// Brings the watchdog to armed: baseline at t, heartbeat change at t + 1.
uint32_t arm(plc::Core& core, uint32_t t) {
  core.scan(t);
  ask_pdu(core, write6_pdu(kN + 1, static_cast<uint16_t>(core.holding(kN + 1) + 1)));
  core.scan(t + 1);
  return t + 1;
}

void test_mbap_echo_and_read_holding() {
  plc::Core core(config());
  uint8_t out[plc::kMaxAdu];
  Bytes f = adu(read_pdu(3, 0, kN + 2), kUnit, 0xbeef);
  size_t n = core.handle(kConn, f.data(), f.size(), out, sizeof(out));
  CHECK(n == plc::kMbapLength + 2 + 2 * (kN + 2));
  CHECK(out[0] == 0xbe && out[1] == 0xef && out[2] == 0 && out[3] == 0);
  CHECK(((out[4] << 8) | out[5]) == static_cast<int>(n - 6));
  CHECK(out[6] == kUnit && out[7] == 3 && out[8] == 2 * (kN + 2));
}

void test_out_of_map_answers_02() {
  plc::Core core(config());
  CHECK(is_exception(ask_pdu(core, read_pdu(3, 0, kN + 4)), 3, 2));   // one past the vent register
  CHECK(is_exception(ask_pdu(core, read_pdu(3, 100, 1)), 3, 2));      // the old heartbeat address
  CHECK(is_exception(ask_pdu(core, read_pdu(4, kN + 2, 2)), 4, 2));   // inputs: N + 3
  CHECK(ask_pdu(core, read_pdu(4, 0, kN + 3)).size() == 2 + 2 * (kN + 3));
  CHECK(is_exception(ask_pdu(core, write6_pdu(kN + 3, 1)), 6, 2));
  CHECK(is_exception(ask_pdu(core, write16_pdu(kN + 1, {1, 2, 3})), 16, 2));
  CHECK(is_exception(ask_pdu(core, read_pdu(3, 0xffff, 2)), 3, 2));   // no 16-bit wrap-around
  CHECK(core.records().out_of_map == 2);
  CHECK(core.holding(kN) == 0 && core.holding(kN + 1) == 0);          // nothing written
}

void test_unknown_function_answers_01() {
  plc::Core core(config());
  const uint8_t fcs[] = {1, 2, 5, 15, 23, 43, 0x7f};
  for (uint8_t fc : fcs) CHECK(is_exception(ask_pdu(core, read_pdu(fc, 0, 1)), fc, 1));
}

void test_bad_quantity_answers_03() {
  plc::Core core(config());
  CHECK(is_exception(ask_pdu(core, read_pdu(3, 0, 0)), 3, 3));
  CHECK(is_exception(ask_pdu(core, read_pdu(3, 0, 126)), 3, 3));
  CHECK(is_exception(ask_pdu(core, read_pdu(4, 0, 0)), 4, 3));
  CHECK(is_exception(ask_pdu(core, read_pdu(3, 0, 125)), 3, 2));  // quantity fine, range not
  Bytes p = write16_pdu(0, {1, 2});
  p[5] = 3;  // byte count != 2 * quantity
  CHECK(is_exception(ask_pdu(core, p), 16, 3));
  std::vector<uint16_t> many(124, 0);
  CHECK(is_exception(ask_pdu(core, write16_pdu(0, many)), 16, 3));
  Bytes zero = {16, 0, 0, 0, 0, 0};
  CHECK(is_exception(ask_pdu(core, zero), 16, 3));
}

void test_other_unit_id_is_silent() {
  plc::Core core(config());
  CHECK(ask(core, adu(read_pdu(3, 0, 1), 2)).empty());
  CHECK(ask(core, adu(read_pdu(3, 0, 1), 0)).empty());
  CHECK(!core.bad_frame());
  CHECK(ask(core, adu(write16_pdu(0, {5}), 2)).empty());
  CHECK(core.records().writes == 0);
}

void test_broken_mbap_is_flagged() {
  plc::Core core(config());
  Bytes f = adu(read_pdu(3, 0, 1));
  f[2] = 1;  // protocol id 0x0100
  CHECK(ask(core, f).empty() && core.bad_frame());
  Bytes g = adu(read_pdu(3, 0, 1));
  g[5] = 9;  // length field disagrees with the frame
  CHECK(ask(core, g).empty() && core.bad_frame());
}

void test_sequenced_write_applies_and_answers_normally() {
  plc::Core core(config());
  Bytes answer = ask_pdu(core, command_pdu({100, 200}, 7));
  CHECK(answer.size() == 5 && answer[0] == 16 && answer[4] == kN + 1);
  CHECK(core.holding(0) == 100 && core.holding(1) == 200 && core.holding(kN) == 7);
  ask_pdu(core, command_pdu({300}, 8));
  CHECK(core.holding(0) == 300 && core.holding(kN) == 8);
}

void test_stale_write_is_undone_with_a_normal_answer() {
  plc::Core core(config());
  ask_pdu(core, command_pdu({100}, 1000));
  Bytes answer = ask_pdu(core, command_pdu({999}, 999));      // older
  CHECK(answer.size() == 5 && answer[0] == 16);
  CHECK(core.holding(0) == 100 && core.holding(kN) == 1000);
  ask_pdu(core, command_pdu({999}, 1000));                     // the same number again
  CHECK(core.holding(0) == 100);
  ask_pdu(core, command_pdu({999}, 1000 + 0x8000));            // half the ring: not newer
  CHECK(core.holding(0) == 100);
  CHECK(core.records().stale == 3 && core.rejected_writes() == 3);
  CHECK(core.records().stale_list[0][0] == 999 && core.records().stale_list[0][1] == 1000);
  ask_pdu(core, command_pdu({555}, 1000 + 0x7fff));            // farthest ahead still newer
  CHECK(core.holding(0) == 555);
}

void test_sequence_wraps_modulo_65536() {
  plc::Core core(config());
  ask_pdu(core, command_pdu({1}, 65535));
  ask_pdu(core, command_pdu({2}, 0));
  CHECK(core.holding(0) == 2 && core.holding(kN) == 0);
  ask_pdu(core, command_pdu({3}, 65535));
  CHECK(core.holding(0) == 2);
}

void test_unsequenced_command_writes_are_undone() {
  plc::Core core(config());
  ask_pdu(core, command_pdu({100, 100}, 5));
  Bytes a6 = ask_pdu(core, write6_pdu(1, 3000));
  CHECK(a6 == write6_pdu(1, 3000));  // normal echo
  Bytes a16 = ask_pdu(core, write16_pdu(0, {7, 7, 7}));
  CHECK(a16.size() == 5 && a16[0] == 16);
  // The heartbeat alone needs no number.
  Bytes hb_only = write16_pdu(kN + 1, {42});
  ask_pdu(core, hb_only);
  CHECK(core.holding(0) == 100 && core.holding(1) == 100 && core.holding(2) == 0);
  CHECK(core.holding(kN) == 5 && core.holding(kN + 1) == 42);
  CHECK(core.records().unsequenced == 2 && core.records().stale == 0);
}

void test_stale_write_with_heartbeat_keeps_the_heartbeat() {
  plc::Core core(config());
  ask_pdu(core, command_pdu({100}, 50));
  std::vector<uint16_t> values(kN, 0);
  values[0] = 777;
  values.push_back(49);   // stale sequence number
  values.push_back(321);  // heartbeat
  ask_pdu(core, write16_pdu(0, values));
  CHECK(core.holding(0) == 100 && core.holding(kN) == 50 && core.holding(kN + 1) == 321);
}

void test_sequence_register_alone() {
  plc::Core core(config());
  ask_pdu(core, command_pdu({100}, 10));
  ask_pdu(core, write6_pdu(kN, 20));   // newer: moves the gate, changes no command
  CHECK(core.holding(kN) == 20 && core.holding(0) == 100);
  ask_pdu(core, command_pdu({200}, 15));
  CHECK(core.holding(0) == 100);
  ask_pdu(core, write6_pdu(kN, 3));    // stale
  CHECK(core.holding(kN) == 20 && core.records().stale == 2);
}

void test_first_write_after_power_up_is_accepted() {
  plc::Core core(config());
  ask_pdu(core, command_pdu({100}, 40000));
  CHECK(core.holding(0) == 100);
  core.power_up();
  CHECK(core.holding(0) == 0 && core.holding(kN) == 0);
  ask_pdu(core, command_pdu({200}, 3));   // behind 40000 but the gate has no reference
  CHECK(core.holding(0) == 200 && core.holding(kN) == 3);
}

void test_over_limit_is_clamped_and_recorded() {
  plc::Core core(config());
  uint32_t t = arm(core, 0);
  ask_pdu(core, command_pdu({kPmax + 1, 65535, kPmax}, 1));
  CHECK(core.holding(0) == kPmax && core.holding(1) == kPmax && core.holding(2) == kPmax);
  Bytes r = ask_pdu(core, read_pdu(3, 0, 2));
  CHECK(r.size() == 6 && ((r[2] << 8) | r[3]) == kPmax && ((r[4] << 8) | r[5]) == kPmax);
  CHECK(core.records().over_limit == 2 && core.records().max_written[1] == 65535);
  CHECK(core.records().over_limit_list[0][0] == 0 &&
        core.records().over_limit_list[0][1] == kPmax + 1);
  ask_pdu(core, write6_pdu(kN + 1, 77));
  core.scan(t + 1);
  for (uint8_t ch = 0; ch < kN; ++ch) CHECK(core.output_counts(ch) <= kPmax);
  CHECK(core.output_counts(1) == kPmax);
}

void test_watchdog_starts_vented() {
  plc::Core core(config());
  CHECK(core.vented());
  ask_pdu(core, command_pdu({1000}, 1));
  core.scan(0);
  CHECK(core.vented() && core.output_counts(0) == 0 && core.holding(0) == 0);
  core.scan(10000);  // no heartbeat change: still vented, no trip counted
  CHECK(core.vented() && core.records().watchdog_trips == 0);
  // A heartbeat that is written but never changes does not arm it either.
  ask_pdu(core, write6_pdu(kN + 1, 0));
  core.scan(10010);
  CHECK(core.vented());
}

void test_watchdog_arms_on_change_and_trips() {
  plc::Core core(config());
  uint32_t t = arm(core, 100);
  CHECK(!core.vented());
  ask_pdu(core, command_pdu({1000, 2000}, 1));
  core.scan(t + 10);
  CHECK(core.output_counts(0) == 1000 && core.output_counts(1) == 2000);
  core.scan(t + 499);
  CHECK(!core.vented() && core.output_counts(0) == 1000);
  core.scan(t + 500);
  CHECK(core.vented() && core.output_counts(0) == 0 && core.holding(0) == 0 &&
        core.holding(1) == 0);
  CHECK(core.records().watchdog_trips == 1);
  // Re-arms at the next change; the commands were zeroed, so the client must send them again.
  ask_pdu(core, write6_pdu(kN + 1, 999));
  core.scan(t + 600);
  CHECK(!core.vented() && core.output_counts(0) == 0);
}

void test_watchdog_across_clock_wrap() {
  plc::Core core(config());
  uint32_t t = arm(core, 0xffffff00u);
  ask_pdu(core, command_pdu({1000}, 1));
  core.scan(t + 0x80);  // wrapped past zero, 127 ms later
  CHECK(!core.vented() && core.output_counts(0) == 1000);
  core.scan(t + 500);
  CHECK(core.vented());
}

void test_writes_while_vented_never_reach_an_output() {
  plc::Core core(config());
  for (uint32_t t = 0; t < 100; ++t) {
    ask_pdu(core, command_pdu({3000}, static_cast<uint16_t>(t + 1)));
    core.scan(t * 10);
    CHECK(core.output_counts(0) == 0);
  }
}

void test_input_registers_carry_measured() {
  plc::Core core(config());
  core.set_measured(3, 1234);
  Bytes r = ask_pdu(core, read_pdu(4, 3, 1));
  CHECK(r.size() == 4 && ((r[2] << 8) | r[3]) == 1234);
  core.set_measured(kN, 1);  // out of range: ignored
  CHECK(core.input(kN) == 0);
}

void test_scaling() {
  CHECK(plc::counts_to_output(0) == 0);
  CHECK(plc::counts_to_output(plc::kFullScaleCounts) == plc::kOutputMax);
  CHECK(plc::counts_to_output(65535) == plc::kOutputMax);
  // Rounded down: the regulator is never asked for more than the command, p_max included.
  for (uint32_t c = 0; c <= plc::kFullScaleCounts; ++c) {
    CHECK(plc::output_to_counts(plc::counts_to_output(static_cast<uint16_t>(c))) <= c);
  }
  CHECK(plc::output_to_counts(plc::counts_to_output(kPmax)) > kPmax - 20);  // within 2 kPa
  CHECK(plc::input_to_counts(0) == 0 && plc::input_to_counts(plc::kInputMax) ==
                                             plc::kFullScaleCounts);
  for (uint32_t c = 0; c <= plc::kFullScaleCounts; c += 7) {
    int back = plc::input_to_counts(plc::counts_to_input(static_cast<uint16_t>(c)));
    CHECK(abs(back - static_cast<int>(c)) <= 3);  // one 10-bit step is 4.9 counts
  }
}

void test_fuzzed_frames_stay_in_bounds() {
  // Random frames (fixed seed): never an answer longer than the buffer, never a command above
  // p_max in a register or at an output.
  plc::Core core(config());
  arm(core, 0);
  unsigned state = 12345;
  for (int i = 0; i < 200000; ++i) {
    state = state * 1103515245u + 12345u;
    size_t len = 7 + (state >> 16) % 40;
    uint8_t frame[64];
    for (size_t k = 0; k < len; ++k) {
      state = state * 1103515245u + 12345u;
      frame[k] = static_cast<uint8_t>(state >> 16);
    }
    frame[2] = frame[3] = 0;
    frame[4] = 0;
    frame[5] = static_cast<uint8_t>(len - 6);
    frame[6] = kUnit;
    frame[7] = (i % 3 == 0) ? 16 : frame[7];
    uint8_t out[plc::kMaxAdu];
    size_t n = core.handle(kConn, frame, len, out, sizeof(out));
    CHECK(n <= plc::kMaxAdu);
    core.scan(static_cast<uint32_t>(i));
    for (uint8_t ch = 0; ch < kN; ++ch) {
      if (core.holding(ch) > kPmax || core.output_counts(ch) > kPmax) {
        CHECK(false);
        return;
      }
    }
  }
}

Bytes ask_from(plc::Core& core, plc::ConnectionId connection, const Bytes& pdu) {
  uint8_t out[plc::kMaxAdu];
  Bytes f = adu(pdu);
  size_t n = core.handle(connection, f.data(), f.size(), out, sizeof(out));
  if (n == 0) return Bytes();
  return Bytes(out + plc::kMbapLength, out + n);
}

void test_a_second_connection_is_refused_with_06_whole() {
  plc::Core core(config());
  uint32_t t = arm(core, 0);  // kConn holds the claim
  ask_pdu(core, command_pdu({500}, 10));
  CHECK(is_exception(ask_from(core, 2, command_pdu({3000}, 2000)), 16, 6));
  CHECK(is_exception(ask_from(core, 2, write6_pdu(kN + 1, 4242)), 6, 6));
  CHECK(is_exception(ask_from(core, 2, write6_pdu(kN + 3, 1)), 6, 2));  // 02 before 06
  CHECK(ask_from(core, 2, read_pdu(3, 0, 1)).size() == 4);               // reads are anyone's
  core.scan(t + 10);
  CHECK(core.holding(0) == 500 && core.holding(kN + 1) != 4242 && core.records().busy == 2);
}

void test_the_holder_s_close_vents_and_frees_the_claim() {
  plc::Core core(config());
  uint32_t t = arm(core, 0);
  ask_pdu(core, command_pdu({2000}, 40000));
  core.scan(t + 10);
  CHECK(core.output_counts(0) == 2000);
  core.connection_closed(2);  // not the holder: nothing
  CHECK(core.output_counts(0) == 2000 && core.owner() == kConn);
  core.connection_closed(kConn);
  CHECK(core.vented() && core.output_counts(0) == 0 && core.holding(0) == 0 &&
        core.owner() == 0 && core.records().owner_lost == 1);
  // The next writer claims; its first number is taken though far behind the last one.
  CHECK(ask_from(core, 2, command_pdu({700}, 5)).size() == 5 && core.holding(kN) == 5);
  CHECK(core.owner() == 2);
  ask_from(core, 2, write6_pdu(kN + 1, static_cast<uint16_t>(core.holding(kN + 1) + 1)));
  ask_from(core, 2, command_pdu({700}, 6));
  core.scan(t + 20);
  CHECK(!core.vented() && core.output_counts(0) == 700);
}

void test_a_silent_holder_loses_the_claim_with_the_watchdog() {
  plc::Core core(config());
  uint32_t t = arm(core, 0);
  ask_pdu(core, command_pdu({2000}, 1));
  for (uint32_t k = 1; k < 60; ++k) {  // another client's heartbeats, refused, every 10 ms
    ask_from(core, 2, write6_pdu(kN + 1, static_cast<uint16_t>(1000 + k)));
    core.scan(t + 10 * k);
    if (10 * k < 500) CHECK(core.owner() == kConn && core.output_counts(0) == 2000);
    // Vented and free at the watchdog's time; then the other client's next write claims it,
    // and its heartbeat arms a watchdog whose commands were zeroed: nothing reaches an output.
    if (10 * k >= 500) CHECK(core.owner() != kConn && core.output_counts(0) == 0);
    if (10 * k == 500) CHECK(core.owner() == 0 && core.vented());
  }
  CHECK(core.records().watchdog_trips == 1 && core.owner() == 2);
}

void test_a_claim_without_a_heartbeat_expires() {
  plc::Core core(config());
  core.scan(0);
  ask_pdu(core, command_pdu({1000}, 1));  // claims, never beats
  core.scan(100);
  CHECK(core.owner() == kConn && core.vented());
  core.scan(599);
  CHECK(core.owner() == kConn);
  core.scan(600);
  CHECK(core.owner() == 0);
  CHECK(ask_from(core, 2, write6_pdu(kN + 1, 9)).size() == 5 && core.owner() == 2);
}

Bytes ask_from_peer(plc::Core& core, plc::ConnectionId connection, plc::Peer peer,
                    const Bytes& pdu) {
  uint8_t out[plc::kMaxAdu];
  Bytes f = adu(pdu);
  size_t n = core.handle(connection, f.data(), f.size(), out, sizeof(out), peer);
  if (n == 0) return Bytes();
  return Bytes(out + plc::kMbapLength, out + n);
}

void test_a_vent_request_from_any_connection_holds_until_the_holder_rearms() {
  plc::Core core(config());
  uint32_t t = arm(core, 0);  // kConn holds the claim
  ask_pdu(core, command_pdu({2000, 2000}, 10));
  core.scan(t + 10);
  CHECK(core.output_counts(0) == 2000);
  // Another connection's vent request: a normal answer, every command 0 at once.
  CHECK(ask_from(core, 2, write6_pdu(kN + 2, plc::kVentRequest)).size() == 5);
  CHECK(core.vent_latched() && core.holding(0) == 0 && core.output_counts(1) == 0);
  CHECK(core.holding(kN + 2) == 1 && core.owner() == kConn);
  // The holder's ordinary writes (commands, heartbeat) do not lift it.
  for (uint32_t k = 1; k < 100; ++k) {
    ask_pdu(core, command_pdu({3000}, static_cast<uint16_t>(10 + k)));
    ask_pdu(core, write6_pdu(kN + 1, static_cast<uint16_t>(core.holding(kN + 1) + 1)));
    CHECK(core.holding(0) == 0);
    core.scan(t + 10 + 10 * k);
    CHECK(core.output_counts(0) == 0 && core.holding(kN) == 10 + k);
  }
  t += 1000;
  // Nobody but the holder re-arms; a value other than the two is refused with 03.
  CHECK(is_exception(ask_from(core, 2, write6_pdu(kN + 2, plc::kRearm)), 6, 6));
  CHECK(is_exception(ask_from(core, 2, write6_pdu(kN + 2, 0)), 6, 3));
  CHECK(is_exception(ask_pdu(core, write6_pdu(kN + 2, 0)), 6, 3));
  CHECK(is_exception(ask_pdu(core, write16_pdu(kN, {200, 1, 7})), 16, 3));
  CHECK(core.vent_latched());
  // The holder's re-arm starts nothing: the commands stay 0 until its next command write.
  CHECK(ask_pdu(core, write6_pdu(kN + 2, plc::kRearm)).size() == 5);
  ask_pdu(core, write6_pdu(kN + 1, static_cast<uint16_t>(core.holding(kN + 1) + 1)));
  core.scan(t + 10);
  CHECK(!core.vent_latched() && core.holding(kN + 2) == 0 && core.output_counts(0) == 0);
  ask_pdu(core, command_pdu({700}, 500));
  core.scan(t + 20);
  CHECK(core.output_counts(0) == 700);
  CHECK(core.records().vent_requests == 1 && core.records().rearms == 1);
}

void test_a_vent_request_takes_no_claim_and_outlives_the_holder() {
  plc::Core core(config());
  core.scan(0);
  CHECK(ask_from(core, 3, write16_pdu(kN + 2, {plc::kVentRequest})).size() == 5);
  CHECK(core.owner() == 0 && core.vent_latched());
  uint32_t t = arm(core, 10);  // kConn claims with its heartbeat
  ask_pdu(core, command_pdu({900}, 1));
  core.scan(t + 10);
  CHECK(core.owner() == kConn && core.output_counts(0) == 0);
  core.connection_closed(kConn);
  CHECK(core.vent_latched());  // a new holder must re-arm explicitly
}

void test_the_claim_holder_s_address_is_in_the_input_registers() {
  plc::Core core(config());
  Bytes r = ask_pdu(core, read_pdu(4, kN, 3));
  CHECK(r.size() == 8 && r[2] == 0 && r[3] == 0 && r[6] == 0 && r[7] == 0);  // free: 0
  const plc::Peer peer = {0x0a000105u, 40312};  // 10.0.1.5:40312
  ask_from_peer(core, 4, peer, write6_pdu(kN + 1, 1));
  r = ask_from(core, 5, read_pdu(4, kN, 3));
  CHECK(r.size() == 8 && ((r[2] << 8) | r[3]) == 0x0a00 && ((r[4] << 8) | r[5]) == 0x0105 &&
        ((r[6] << 8) | r[7]) == 40312);
  core.connection_closed(4);
  CHECK(core.input(kN) == 0 && core.input(kN + 1) == 0 && core.input(kN + 2) == 0);
}

// A platform connection for serve_once: what arrived, room to send, the peer's state.
struct FakeLink {
  Bytes in;
  Bytes sent;
  int room = 2048;
  bool open = true;
  int writes = 0;
  int available() { return static_cast<int>(in.size()); }
  int read(uint8_t* buf, size_t n) {
    if (n > in.size()) n = in.size();
    memcpy(buf, in.data(), n);
    in.erase(in.begin(), in.begin() + static_cast<long>(n));
    return static_cast<int>(n);
  }
  int availableForWrite() { return room; }
  size_t write(const uint8_t* buf, size_t n) {
    ++writes;
    sent.insert(sent.end(), buf, buf + n);
    return n;
  }
  bool peer_open() { return open || !in.empty(); }
};

void test_serve_once_answers_one_request_per_pass() {
  plc::Core core(config());
  plc::Connection c;
  plc::open_connection(c, kConn, 0);
  FakeLink link;
  Bytes two = adu(read_pdu(3, 0, 1));
  Bytes second = adu(read_pdu(3, 0, 2));
  two.insert(two.end(), second.begin(), second.end());
  link.in = two;
  CHECK(plc::serve_once(core, link, c, 1) == plc::kKeep);   // the header
  CHECK(plc::serve_once(core, link, c, 1) == plc::kKeep);   // the rest: answered
  CHECK(link.writes == 1 && link.in.size() == second.size());
  CHECK(plc::serve_once(core, link, c, 2) == plc::kKeep);
  CHECK(plc::serve_once(core, link, c, 2) == plc::kKeep);
  CHECK(link.writes == 2 && link.in.empty());
}

void test_serve_once_never_writes_what_does_not_fit() {
  plc::Core core(config());
  plc::Connection c;
  plc::open_connection(c, kConn, 0);
  FakeLink link;
  link.room = 10;  // an answer of 7 + 2 + 2 * 20 bytes does not fit: the peer stopped reading
  link.in = adu(read_pdu(3, 0, kN + 2));
  CHECK(plc::serve_once(core, link, c, 1) == plc::kKeep);
  CHECK(plc::serve_once(core, link, c, 1) == plc::kStalled && link.writes == 0);
}

void test_serve_once_reaps_dead_and_idle_connections() {
  plc::Core core(config());
  plc::Connection c;
  plc::open_connection(c, kConn, 0);
  FakeLink link;
  CHECK(plc::serve_once(core, link, c, plc::kIdleMs - 1) == plc::kKeep);
  CHECK(plc::serve_once(core, link, c, plc::kIdleMs) == plc::kIdle);
  plc::open_connection(c, kConn, 0);
  link.in = Bytes(5, 0);  // half a header, then nothing
  CHECK(plc::serve_once(core, link, c, 0) == plc::kKeep);
  CHECK(plc::serve_once(core, link, c, plc::kPartialFrameMs - 1) == plc::kKeep);
  CHECK(plc::serve_once(core, link, c, plc::kPartialFrameMs) == plc::kIdle);
  plc::open_connection(c, kConn, 0);
  link.open = false;
  CHECK(plc::serve_once(core, link, c, 1) == plc::kPeerClosed);
  plc::open_connection(c, kConn, 0);
  link.open = true;
  link.in = {0, 1, 0, 0, 0x40, 0, 1};  // a length no Modbus TCP frame has
  CHECK(plc::serve_once(core, link, c, 1) == plc::kBadFrame);
}

}  // namespace

#define RUN(test)             \
  do {                        \
    current_test = #test;     \
    test();                   \
  } while (0)

int main() {
  RUN(test_mbap_echo_and_read_holding);
  RUN(test_out_of_map_answers_02);
  RUN(test_unknown_function_answers_01);
  RUN(test_bad_quantity_answers_03);
  RUN(test_other_unit_id_is_silent);
  RUN(test_broken_mbap_is_flagged);
  RUN(test_sequenced_write_applies_and_answers_normally);
  RUN(test_stale_write_is_undone_with_a_normal_answer);
  RUN(test_sequence_wraps_modulo_65536);
  RUN(test_unsequenced_command_writes_are_undone);
  RUN(test_stale_write_with_heartbeat_keeps_the_heartbeat);
  RUN(test_sequence_register_alone);
  RUN(test_first_write_after_power_up_is_accepted);
  RUN(test_over_limit_is_clamped_and_recorded);
  RUN(test_watchdog_starts_vented);
  RUN(test_watchdog_arms_on_change_and_trips);
  RUN(test_watchdog_across_clock_wrap);
  RUN(test_writes_while_vented_never_reach_an_output);
  RUN(test_input_registers_carry_measured);
  RUN(test_scaling);
  RUN(test_fuzzed_frames_stay_in_bounds);
  RUN(test_a_second_connection_is_refused_with_06_whole);
  RUN(test_the_holder_s_close_vents_and_frees_the_claim);
  RUN(test_a_silent_holder_loses_the_claim_with_the_watchdog);
  RUN(test_a_claim_without_a_heartbeat_expires);
  RUN(test_a_vent_request_from_any_connection_holds_until_the_holder_rearms);
  RUN(test_a_vent_request_takes_no_claim_and_outlives_the_holder);
  RUN(test_the_claim_holder_s_address_is_in_the_input_registers);
  RUN(test_serve_once_answers_one_request_per_pass);
  RUN(test_serve_once_never_writes_what_does_not_fit);
  RUN(test_serve_once_reaps_dead_and_idle_connections);
  printf("core_tests: %d checks, %d failed\n", checks, failures);
  return failures == 0 ? 0 : 1;
}
