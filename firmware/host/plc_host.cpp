// The PLC program built for the host: the same core (fabric_plc/src) behind POSIX sockets in
// place of the Ethernet shield, with the regulators simulated (first-order lag from the analog
// output value to the monitor reading) and the outputs written to a state file, so tests see
// what reached an output. A drop-in for mock_plc in the graph tests:
//
//   plc_host --port 1502 [--host 127.0.0.1] [--unit-id 1] [--channels 18]
//            [--p-max-counts 3750] [--watchdog-ms 500] [--scan-ms 10] [--tau-ms 150]
//            [--state FILE] [--names F1,F2,...]
//
// Prints "listening on HOST:PORT" once it accepts connections (port 0: the OS picks one).
// SIGINT/SIGTERM: outputs vented, state file written, exit 0. The state file is JSON with the
// fields of fabric_guidance/plc/records.py plus the outputs (see write_state()).
#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <linux/sockios.h>
#include <sys/ioctl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <string>
#include <vector>

#include "plc_core.h"
#include "plc_link.h"
#include "scaling.h"

namespace {

volatile sig_atomic_t g_stop = 0;
void on_signal(int) { g_stop = 1; }

struct Options {
  std::string host = "127.0.0.1";
  int port = 1502;
  int unit_id = 1;
  int channels = 18;
  long p_max_counts = 3750;
  long watchdog_ms = 500;
  long scan_ms = 10;
  double tau_ms = 150;
  std::string state;
  std::vector<std::string> names;
};

[[noreturn]] void usage(const char* why) {
  fprintf(stderr, "plc_host: %s\n", why);
  exit(2);
}

long number(const char* flag, const char* text, long lo, long hi) {
  char* end = nullptr;
  errno = 0;
  long v = strtol(text, &end, 10);
  if (errno || end == text || *end || v < lo || v > hi) {
    fprintf(stderr, "plc_host: %s must be an integer %ld..%ld, got '%s'\n", flag, lo, hi, text);
    exit(2);
  }
  return v;
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    std::string flag = argv[i];
    if (i + 1 >= argc) usage(("missing value after " + flag).c_str());
    const char* v = argv[++i];
    if (flag == "--host") o.host = v;
    else if (flag == "--port") o.port = static_cast<int>(number("--port", v, 0, 65535));
    else if (flag == "--unit-id") o.unit_id = static_cast<int>(number("--unit-id", v, 1, 247));
    else if (flag == "--channels")
      o.channels = static_cast<int>(number("--channels", v, 1, plc::kMaxChannels));
    else if (flag == "--p-max-counts")
      o.p_max_counts = number("--p-max-counts", v, 0, plc::kFullScaleCounts);
    else if (flag == "--watchdog-ms") o.watchdog_ms = number("--watchdog-ms", v, 1, 600000);
    else if (flag == "--scan-ms") o.scan_ms = number("--scan-ms", v, 1, 1000);
    else if (flag == "--tau-ms") o.tau_ms = static_cast<double>(number("--tau-ms", v, 0, 60000));
    else if (flag == "--state") o.state = v;
    else if (flag == "--names") {
      std::string s = v;
      size_t at = 0;
      while (at <= s.size()) {
        size_t comma = s.find(',', at);
        if (comma == std::string::npos) comma = s.size();
        o.names.push_back(s.substr(at, comma - at));
        at = comma + 1;
      }
    } else usage(("unknown option " + flag).c_str());
  }
  if (!o.names.empty() && o.names.size() != static_cast<size_t>(o.channels)) {
    usage("--names must name every channel (--channels of them)");
  }
  for (int ch = static_cast<int>(o.names.size()); ch < o.channels; ++ch) {
    o.names.push_back("ch" + std::to_string(ch));
  }
  return o;
}

uint32_t now_ms() {
  timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<uint32_t>(ts.tv_sec * 1000u + ts.tv_nsec / 1000000);
}

// The W5500 of the M-Duino has 8 sockets, one of them listening: 7 clients at most. Its
// send buffer is 2 KB per socket; the host's is set to the same, so that a client that stops
// reading fills it as soon as it would fill the device's.
const size_t kMaxClients = 7;
const int kSendBuffer = 2048;

// A non-blocking POSIX socket with the calls plc_link.h needs (EthernetClient's meanings).
struct PosixLink {
  int fd = -1;
  int available() {
    int n = 0;
    return ioctl(fd, FIONREAD, &n) == 0 ? n : 0;
  }
  int read(uint8_t* buf, size_t n) {
    ssize_t k = recv(fd, buf, n, MSG_DONTWAIT);
    return k > 0 ? static_cast<int>(k) : 0;
  }
  int availableForWrite() {
    // The kernel reports twice the buffer it was given (bookkeeping included); the queue is
    // what is sent and not yet acknowledged, as the W5500's free size counts it.
    int size = 0, queued = 0;
    socklen_t len = sizeof(size);
    if (getsockopt(fd, SOL_SOCKET, SO_SNDBUF, &size, &len) != 0) return 0;
    if (ioctl(fd, SIOCOUTQ, &queued) != 0) return 0;
    int free_bytes = size / 2 - queued;
    return free_bytes > 0 ? free_bytes : 0;
  }
  size_t write(const uint8_t* buf, size_t n) {
    ssize_t k = send(fd, buf, n, MSG_DONTWAIT | MSG_NOSIGNAL);
    return k > 0 ? static_cast<size_t>(k) : 0;
  }
  bool peer_open() {
    uint8_t b;
    ssize_t k = recv(fd, &b, 1, MSG_PEEK | MSG_DONTWAIT);
    return k > 0 || (k < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR));
  }
};

// Connections closed by the program, per plc::Verdict (kKeep unused).
uint32_t reaped[5] = {0, 0, 0, 0, 0};
// The longest time one pass spent on the sockets (accept and every connection) [us]: what a
// blocking call would show, without the scheduler's delays between passes on a busy host.
uint32_t longest_serve_us = 0;

uint64_t now_us() {
  timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<uint64_t>(ts.tv_sec) * 1000000u + static_cast<uint64_t>(ts.tv_nsec) / 1000u;
}

struct Client {
  PosixLink link;
  plc::Connection connection;
};

// The regulators: the pressure follows the analog output's set point as a first-order lag.
struct Regulators {
  std::vector<double> counts;
  double tau_ms;
  void step(const plc::Core& core, double dt_ms) {
    for (size_t ch = 0; ch < counts.size(); ++ch) {
      double target = plc::output_to_counts(
          plc::counts_to_output(core.output_counts(static_cast<uint8_t>(ch))));
      double alpha = tau_ms <= 0 ? 0.0 : exp(-dt_ms / tau_ms);
      counts[ch] = target + (counts[ch] - target) * alpha;
    }
  }
};

void list_json(std::string& s, const uint16_t list[][2], uint32_t count) {
  s += "[";
  for (uint32_t i = 0; i < count && i < plc::kMaxListed; ++i) {
    s += (i ? ", [" : "[") + std::to_string(list[i][0]) + ", " + std::to_string(list[i][1]) + "]";
  }
  s += "]";
}

// Records (records.py fields) + what reached the outputs. Written atomically (rename).
void write_state(const Options& o, const plc::Core& core, const std::vector<uint16_t>& max_out,
                 uint32_t scans, uint32_t longest_scan_ms) {
  if (o.state.empty()) return;
  const plc::Records& r = core.records();
  std::string s = "{";
  s += "\"p_max_kpa\": " +
       std::to_string(static_cast<double>(o.p_max_counts) / plc::kCountsPerKpa);
  s += ", \"p_max_counts\": " + std::to_string(o.p_max_counts);
  s += ", \"counts_per_kpa\": " + std::to_string(plc::kCountsPerKpa);
  s += ", \"writes\": " + std::to_string(r.writes);
  s += ", \"max_written_counts\": {";
  for (int ch = 0; ch < o.channels; ++ch) {
    s += (ch ? ", \"" : "\"") + o.names[ch] + "\": " + std::to_string(r.max_written[ch]);
  }
  s += "}, \"over_limit_count\": " + std::to_string(r.over_limit) + ", \"over_limit_writes\": ";
  list_json(s, r.over_limit_list, r.over_limit);
  s += ", \"out_of_map_count\": " + std::to_string(r.out_of_map) + ", \"out_of_map_writes\": ";
  list_json(s, r.out_of_map_list, r.out_of_map);
  s += ", \"stale_count\": " + std::to_string(r.stale) + ", \"stale_writes\": ";
  list_json(s, r.stale_list, r.stale);
  s += ", \"unsequenced_count\": " + std::to_string(r.unsequenced);
  s += ", \"watchdog_trips\": " + std::to_string(r.watchdog_trips);
  s += ", \"busy_count\": " + std::to_string(r.busy);
  s += ", \"owner_lost_count\": " + std::to_string(r.owner_lost);
  s += ", \"vent_request_count\": " + std::to_string(r.vent_requests);
  s += ", \"rearm_count\": " + std::to_string(r.rearms);
  s += ", \"vent_latched\": " + std::string(core.vent_latched() ? "true" : "false");
  s += ", \"owner\": " + std::to_string(core.owner());
  s += ", \"closed\": {\"peer_closed\": " + std::to_string(reaped[plc::kPeerClosed]) +
       ", \"idle\": " + std::to_string(reaped[plc::kIdle]) +
       ", \"stalled\": " + std::to_string(reaped[plc::kStalled]) +
       ", \"bad_frame\": " + std::to_string(reaped[plc::kBadFrame]) + "}";
  s += ", \"vented\": " + std::string(core.vented() ? "true" : "false");
  s += ", \"scans\": " + std::to_string(scans);
  s += ", \"longest_scan_ms\": " + std::to_string(longest_scan_ms);
  s += ", \"longest_serve_us\": " + std::to_string(longest_serve_us);
  s += ", \"output_counts\": [";
  for (int ch = 0; ch < o.channels; ++ch) {
    s += (ch ? ", " : "") + std::to_string(core.output_counts(static_cast<uint8_t>(ch)));
  }
  s += "], \"max_output_counts\": [";
  for (int ch = 0; ch < o.channels; ++ch) s += (ch ? ", " : "") + std::to_string(max_out[ch]);
  s += "]}\n";
  std::string tmp = o.state + ".tmp";
  FILE* f = fopen(tmp.c_str(), "w");
  if (!f) {
    fprintf(stderr, "plc_host: cannot write %s: %s\n", tmp.c_str(), strerror(errno));
    return;
  }
  fwrite(s.data(), 1, s.size(), f);
  fclose(f);
  if (rename(tmp.c_str(), o.state.c_str()) != 0) {
    fprintf(stderr, "plc_host: cannot rename to %s: %s\n", o.state.c_str(), strerror(errno));
  }
}

}  // namespace

int main(int argc, char** argv) {
  Options o = parse(argc, argv);
  struct sigaction sa;
  memset(&sa, 0, sizeof(sa));
  sa.sa_handler = on_signal;
  sigaction(SIGINT, &sa, nullptr);
  sigaction(SIGTERM, &sa, nullptr);

  int listener = socket(AF_INET, SOCK_STREAM, 0);
  int one = 1;
  setsockopt(listener, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  sockaddr_in addr;
  memset(&addr, 0, sizeof(addr));
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(o.port));
  if (inet_pton(AF_INET, o.host.c_str(), &addr.sin_addr) != 1) {
    usage("--host: not an IPv4 address");
  }
  if (bind(listener, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0 ||
      listen(listener, 8) != 0) {
    fprintf(stderr, "plc_host: cannot listen on %s:%d: %s\n", o.host.c_str(), o.port,
            strerror(errno));
    return 1;
  }
  socklen_t alen = sizeof(addr);
  getsockname(listener, reinterpret_cast<sockaddr*>(&addr), &alen);

  plc::Core core(plc::Config{static_cast<uint8_t>(o.unit_id), static_cast<uint8_t>(o.channels),
                             static_cast<uint16_t>(o.p_max_counts),
                             static_cast<uint32_t>(o.watchdog_ms)});
  Regulators regs{std::vector<double>(o.channels, 0.0), o.tau_ms};
  std::vector<uint16_t> max_out(o.channels, 0);
  std::vector<Client> clients;
  uint32_t scans = 0, last_scan = now_ms(), last_state = last_scan;
  // The longest time between two scans: how long the watchdog could not run.
  uint32_t longest_scan_ms = 0;
  std::string written;  // the state's outputs + counters last written: rewrite only on change
  core.scan(last_scan);
  write_state(o, core, max_out, scans, longest_scan_ms);
  printf("listening on %s:%d\n", o.host.c_str(), ntohs(addr.sin_port));
  fflush(stdout);

  plc::ConnectionId next_id = 1;
  auto drop = [&](std::vector<Client>::iterator it, plc::Verdict why) {
    close(it->link.fd);  // no linger: returns at once
    core.connection_closed(it->connection.id);
    ++reaped[why];
    return clients.erase(it);
  };
  while (!g_stop) {
    std::vector<pollfd> fds;
    fds.push_back(pollfd{listener, POLLIN, 0});
    for (const Client& c : clients) fds.push_back(pollfd{c.link.fd, POLLIN, 0});
    uint32_t t = now_ms();
    long wait = static_cast<long>(o.scan_ms) - static_cast<long>(t - last_scan);
    int ready = poll(fds.data(), fds.size(), wait > 0 ? static_cast<int>(wait) : 0);
    if (ready < 0 && errno != EINTR) {
      perror("plc_host: poll");
      break;
    }
    t = now_ms();
    const uint64_t serve_start_us = now_us();
    if (ready > 0 && (fds[0].revents & POLLIN)) {
      sockaddr_in from;
      socklen_t from_len = sizeof(from);
      memset(&from, 0, sizeof(from));
      int fd = accept4(listener, reinterpret_cast<sockaddr*>(&from), &from_len, SOCK_NONBLOCK);
      if (fd >= 0) {
        setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
        setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &kSendBuffer, sizeof(kSendBuffer));
        if (clients.size() >= kMaxClients) {
          // Every socket taken: the longest-silent one that does not hold the write claim
          // makes room (a dead peer's socket must not lock the next client out).
          auto idlest = clients.end();
          for (auto it = clients.begin(); it != clients.end(); ++it) {
            if (it->connection.id == core.owner()) continue;
            if (idlest == clients.end() ||
                static_cast<uint32_t>(t - it->connection.last_rx_ms) >
                    static_cast<uint32_t>(t - idlest->connection.last_rx_ms)) {
              idlest = it;
            }
          }
          if (idlest != clients.end()) drop(idlest, plc::kIdle);
        }
        Client c;
        c.link.fd = fd;
        plc::open_connection(c.connection, next_id++, t,
                             plc::Peer{ntohl(from.sin_addr.s_addr), ntohs(from.sin_port)});
        clients.push_back(c);
      }
    }
    // Every connection every pass (also the silent ones: their idle time is checked).
    for (auto it = clients.begin(); it != clients.end();) {
      plc::Verdict v = plc::serve_once(core, it->link, it->connection, t);
      it = v == plc::kKeep ? it + 1 : drop(it, v);
    }
    const uint64_t served_us = now_us() - serve_start_us;
    if (served_us > longest_serve_us) longest_serve_us = static_cast<uint32_t>(served_us);
    t = now_ms();
    if (static_cast<uint32_t>(t - last_scan) >= static_cast<uint32_t>(o.scan_ms)) {
      double dt = static_cast<double>(t - last_scan);
      if (t - last_scan > longest_scan_ms) longest_scan_ms = t - last_scan;
      last_scan = t;
      core.scan(t);
      ++scans;
      regs.step(core, dt);
      std::string now_state;
      for (int ch = 0; ch < o.channels; ++ch) {
        uint16_t out = core.output_counts(static_cast<uint8_t>(ch));
        if (out > max_out[ch]) max_out[ch] = out;
        now_state += std::to_string(out) + ",";
        // The monitor reading, as the PLC's analog input would give it.
        uint16_t p = static_cast<uint16_t>(lround(regs.counts[ch]));
        core.set_measured(static_cast<uint8_t>(ch), plc::input_to_counts(plc::counts_to_input(p)));
      }
      const plc::Records& r = core.records();
      now_state += std::to_string(r.busy) + "," + std::to_string(r.owner_lost) + "," +
                   std::to_string(core.owner()) + ",";
      now_state += std::to_string(r.stale + r.unsequenced) + "," +
                   std::to_string(r.watchdog_trips) + "," +
                   std::to_string(r.out_of_map) + "," + std::to_string(r.over_limit) + "," +
                   std::to_string(r.vent_requests) + "," + std::to_string(r.rearms);
      // Outputs and counters on every change; the rest (write counts) at most every 100 ms.
      if (now_state != written || static_cast<uint32_t>(t - last_state) >= 100) {
        written = now_state;
        last_state = t;
        write_state(o, core, max_out, scans, longest_scan_ms);
      }
    }
  }
  // Shutdown: the outputs vent (the device loses power the same way).
  core.power_up();
  core.scan(now_ms());
  for (const Client& c : clients) close(c.link.fd);
  close(listener);
  write_state(o, core, max_out, scans, longest_scan_ms);
  return 0;
}
