// OpenIGTLink server for device input and force feedback.
//
// Sockets are plain POSIX here rather than igtl::ServerSocket, for three reasons: the library
// binds to every interface (we listen on loopback by default), it cannot bind port 0 (tests need
// a free port), and its blocking calls cannot be woken for a clean shutdown. Framing is checked
// by hand so that a hostile header (a body size of 2^63, a truncated field) cannot reach the
// library (igtl_stream.cpp, which frames and decodes without a socket); outgoing messages use
// libopenigtlink.
#include <arpa/inet.h>
#include <fcntl.h>
#include <igtlSensorMessage.h>
#include <igtlStringMessage.h>
#include <igtlTimeStamp.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <deque>
#include <iostream>
#include <mutex>
#include <span>
#include <sstream>
#include <thread>

#include "igtl_stream.h"
#include "json_fields.h"
#include "vcsim/core.h"
#include "vcsim/haptics.h"
#include "vcsim/units.h"

namespace vcsim {

using internal::cat;

namespace {

using Clock = std::chrono::steady_clock;

// Connections the kernel holds for accept(): a burst of clients is each answered (one adopted,
// the others refused) instead of some left retrying their SYN.
constexpr int kListenBacklog = 128;
// A connected client whose sent data stay unacknowledged this long is gone (a device that lost
// power or its cable): dropped, so that it can connect again (TCP_USER_TIMEOUT).
constexpr unsigned kClientTimeoutMs = 3000;
// A position command's speed is its change over at least this long (messages may come in
// bursts; a device's rate is 100-1000 Hz).
constexpr double kSpeedWindow = 0.02;  // s
constexpr int kMaxLogLinesPerSecond = 20;

std::string num(double v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

bool valid_instrument_name(const std::string& s) {
  if (s.empty() || s.size() > 14) return false;  // "force_" + name fits the 20-byte field
  for (char c : s) {
    if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') || c == '_' ||
          c == '-'))
      return false;
  }
  return s != "balloon" && s != "syringe" && s != "buttons" && s != "exchange" &&
         s.rfind("vel_", 0) != 0 && s.rfind("force_", 0) != 0;
}

}  // namespace

struct IgtlServer::Impl {
  IgtlServerOptions opt;
  int listen_fd = -1;
  int client_fd = -1;
  int bound_port = 0;
  std::thread thread;
  std::atomic<bool> stopping{false};

  // Hand-over to the physics thread: the latest accepted commands, as the device sent them
  // (operator units; poll() converts them).
  struct Latest {
    std::vector<InstrumentCommand> instruments;  // in IgtlServerOptions::instruments' order
    double balloon_pressure_atm = 0.0;
    double syringe_flow_ml_s = 0.0;
    std::uint32_t buttons = 0;
    std::uint64_t commanded = 0;  // bit i: instrument i has had a command accepted
  };
  mutable std::mutex cmd_mu;
  Latest latest;                           // and, under the same lock:
  std::deque<InstrumentChange> exchanges;  // asked for by the client, for poll_exchange
  std::vector<std::string> replies;        // answers to the client on "exchange", to send
  std::vector<std::string> physics_log;    // lines the physics thread wants logged

  // Hand-over from the physics thread: the hub forces since the last message, one per instrument.
  std::mutex fb_mu;
  FeedbackDecimator feedback;
  std::vector<std::string> fb_names;  // the instruments `feedback` is by (the scene's)

  std::atomic<std::uint64_t> n_connections{0}, n_disconnections{0}, n_accepted{0}, n_dropped{0},
      n_feedback{0}, n_exchanges{0}, n_refused{0};
  std::atomic<bool> connected{false};

  // Server thread only.
  internal::IgtlStream stream;    // bytes received, framed into messages
  std::vector<double> values;     // a SENSOR's, reused
  std::vector<unsigned char> tx;  // bytes to send (whole messages)
  std::size_t tx_sent = 0;
  std::vector<igtl::SensorMessage::Pointer> out_msgs;  // one per instrument, reused
  std::vector<std::string> out_names;                  // the instruments of out_msgs
  std::vector<HandFeedback> fb_copy;
  Clock::time_point log_window;
  int log_lines = 0;
  int log_suppressed = 0;

  // Per instrument name (under cmd_mu): the last position command's reference for its speed,
  // and whether a speed or spin beyond the drive was reported (once each).
  struct Follow {
    std::string name;
    bool has = false;
    Clock::time_point t;
    double translation = 0.0, rotation = 0.0;
    bool said_speed = false, said_spin = false;
  };
  std::vector<Follow> follow;
  std::atomic<std::uint64_t> n_refused_clients{0}, n_skipped{0}, n_beyond{0};

  void log(const std::string& line) {
    const auto now = Clock::now();
    if (now - log_window > std::chrono::seconds(1)) {
      if (log_suppressed > 0) {
        emit(cat(std::to_string(log_suppressed), " similar lines suppressed"));
      }
      log_window = now;
      log_lines = 0;
      log_suppressed = 0;
    }
    // A flood of bad messages must not flood the terminal.
    if (++log_lines > kMaxLogLinesPerSecond) {
      ++log_suppressed;
      return;
    }
    emit(line);
  }
  void emit(const std::string& line) {
    if (opt.log) {
      opt.log(line);
    } else {
      std::cerr << "vcsim igtl: " << line << "\n";
    }
  }

  void drop(const std::string& device, const std::string& why) {
    n_dropped.fetch_add(1);
    log(cat("dropped message '", device, "': ", why));
  }

  // The instrument's index in the scene (under cmd_mu: an exchange changes them), or -1.
  int index_of(std::string_view name) const {
    for (std::size_t i = 0; i < latest.instruments.size(); ++i) {
      if (latest.instruments[i].name == name) return static_cast<int>(i);
    }
    return -1;
  }

  void reply(const std::string& text) {
    std::lock_guard lock(cmd_mu);
    replies.push_back(text);
  }

  // ---- connection ----

  void adopt(int fd, const std::string& peer) {
    const int flags = fcntl(fd, F_GETFL, 0);
    fcntl(fd, F_SETFL, flags | O_NONBLOCK);
    int one = 1;
    setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);  // small messages, low latency
    // A client that vanished without closing (we send forces all the time) is dropped.
    const unsigned timeout = kClientTimeoutMs;
    setsockopt(fd, IPPROTO_TCP, TCP_USER_TIMEOUT, &timeout, sizeof timeout);
    setsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &one, sizeof one);
    client_fd = fd;
    stream.reset();
    tx.clear();
    tx_sent = 0;
    n_connections.fetch_add(1);
    connected = true;
    log(cat("client connected from ", peer));
  }

  void disconnect(const std::string& why) {
    if (client_fd < 0) return;
    ::close(client_fd);
    client_fd = -1;
    stream.reset();
    tx.clear();
    tx_sent = 0;
    n_disconnections.fetch_add(1);
    connected = false;
    log(cat("client disconnected (", why, ")"));
    // Positions stay where the client left them; nothing keeps moving without a hand on it.
    std::lock_guard lock(cmd_mu);
    for (auto& c : latest.instruments) {
      if (c.mode == InstrumentCommand::Mode::kVelocity) {
        c.translation_mm = 0.0;
        c.rotation_deg = 0.0;
      }
    }
    latest.syringe_flow_ml_s = 0.0;
  }

  // Every connection waiting (a burst): the first adopted when none is connected, the others
  // refused (closed at once) with a log line: a second client must not take over a live session.
  void accept_pending() {
    for (;;) {
      sockaddr_in peer{};
      socklen_t len = sizeof peer;
      const int fd = ::accept4(listen_fd, reinterpret_cast<sockaddr*>(&peer), &len, SOCK_CLOEXEC);
      if (fd < 0) return;
      char ip[INET_ADDRSTRLEN] = "?";
      inet_ntop(AF_INET, &peer.sin_addr, ip, sizeof ip);
      const std::string who = cat(ip, ":", std::to_string(ntohs(peer.sin_port)));
      if (client_fd < 0) {
        adopt(fd, who);
        continue;
      }
      ::close(fd);
      n_refused_clients.fetch_add(1);
      log(cat("refused a connection from ", who,
              ": a client is connected (one at a time; docs/devices.md)"));
    }
  }

  // ---- receiving ----

  void read_client() {
    unsigned char buf[16384];
    for (int rounds = 0; rounds < 64; ++rounds) {  // bounded: keep feedback on time
      const ssize_t n = ::recv(client_fd, buf, sizeof buf, 0);
      if (n > 0) {
        const bool framed = stream.feed({buf, static_cast<std::size_t>(n)},
                                        [this](const internal::IgtlFrame& f) { on_frame(f); });
        // After a bad header there is no way to find the next message boundary.
        if (!framed) return disconnect("garbage on the stream");
        continue;
      }
      if (n == 0) {
        disconnect("closed by the client");
      } else if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
        disconnect(cat("receive failed: ", std::strerror(errno)));
      }
      return;
    }
  }

  void on_frame(const internal::IgtlFrame& f) {
    using Kind = internal::IgtlFrame::Kind;
    switch (f.kind) {
      case Kind::kGarbage:
        n_dropped.fetch_add(1);
        log(cat(f.error, ": dropping the connection"));
        return;
      case Kind::kSkipped:
        // Well-formed but more than we read (an IMAGE): skipped, the connection kept.
        n_dropped.fetch_add(1);
        n_skipped.fetch_add(1);
        log(cat("skipped ", f.type, " message '", f.device, "' of ", std::to_string(f.body_size),
                " bytes (messages over ", std::to_string(internal::kIgtlMaxBody),
                " bytes are not read)"));
        return;
      case Kind::kBadMessage:
        return drop(f.device, f.error);
      case Kind::kMessage:
        break;
    }
    if (f.type == "SENSOR") return handle_sensor(f.device, f.content);
    if (f.type == "TRANSFORM") return handle_transform(f.device, f.content);
    if (f.type == "STRING") return handle_string(f.device, f.content);
    drop(f.device,
         cat("unsupported message type ", f.type, " (expected SENSOR, TRANSFORM or STRING)"));
  }

  // STRING "exchange": a change of the scene's instruments, queued for the physics thread, which
  // applies or refuses it (exchanged, exchange_refused) before its next step. A request that
  // does not parse is dropped and answered at once.
  void handle_string(const std::string& device, std::span<const unsigned char> content) {
    if (device != "exchange") return drop(device, "expected STRING on device exchange only");
    std::string text;
    if (std::string why = internal::decode_igtl_string(content, text); !why.empty())
      return drop(device, why);
    InstrumentChange change;
    std::string why = parse_exchange_request(text, change);
    if (why.empty() && change.kind == InstrumentChange::Kind::kAdd &&
        !valid_instrument_name(change.name))
      why =
          cat("expected a name of 1-14 characters from A-Z a-z 0-9 _ -, not balloon, syringe, "
              "buttons, exchange or a vel_/force_ prefix; got \"",
              change.name, "\"");
    change.source = "igtl";
    change.field = "exchange";
    if (!why.empty()) {
      drop(device, why);
      reply(cat("refused: ", text, ": ", why));
      return;
    }
    n_accepted.fetch_add(1);
    log(cat("exchange asked for: ", text));
    std::lock_guard lock(cmd_mu);
    exchanges.push_back(std::move(change));
  }

  void handle_sensor(const std::string& device, std::span<const unsigned char> content) {
    if (std::string why = internal::decode_igtl_sensor(content, values); !why.empty())
      return drop(device, why);
    const std::size_t n = values.size();
    const double* v = values.data();
    const CommandLimits& lim = opt.limits;
    auto want = [&](std::size_t k) {
      if (n == k) return true;
      drop(device, cat("expected ", std::to_string(k), " values, got ", std::to_string(n)));
      return false;
    };

    if (device == "balloon") {
      if (!want(1)) return;
      if (v[0] < 0 || v[0] > lim.max_balloon_atm) {
        return drop(device, cat("pressure ", num(v[0]), " atm outside [0, ",
                                num(lim.max_balloon_atm), "]"));
      }
      std::lock_guard lock(cmd_mu);
      latest.balloon_pressure_atm = v[0];
    } else if (device == "syringe") {
      if (!want(1)) return;
      if (std::abs(v[0]) > lim.max_syringe_ml_s) {
        return drop(device, cat("flow ", num(v[0]), " ml/s beyond +-", num(lim.max_syringe_ml_s)));
      }
      std::lock_guard lock(cmd_mu);
      latest.syringe_flow_ml_s = v[0];
    } else if (device == "buttons") {
      if (!want(1)) return;
      if (v[0] < 0 || v[0] > 4294967295.0 || v[0] != std::floor(v[0])) {
        return drop(device, "expected an integer bit mask in [0, 2^32 - 1]");
      }
      std::lock_guard lock(cmd_mu);
      latest.buttons = static_cast<std::uint32_t>(v[0]);
    } else {
      const bool vel = device.rfind("vel_", 0) == 0;
      const std::string_view name = vel ? std::string_view(device).substr(4) : device;
      if (!want(2)) return;
      set_instrument(name, device,
                     vel ? InstrumentCommand::Mode::kVelocity : InstrumentCommand::Mode::kPosition,
                     v[0], v[1], false);
      return;
    }
    n_accepted.fetch_add(1);
  }

  // TRANSFORM: the pose of the instrument's hub in the device frame, whose z axis is the
  // insertion axis. Depth = the translation's z component; angle = rotation about z.
  void handle_transform(const std::string& device, std::span<const unsigned char> content) {
    double depth_mm = 0.0, angle_deg = 0.0;
    if (std::string why = internal::decode_igtl_transform(content, depth_mm, angle_deg);
        !why.empty())
      return drop(device, why);
    set_instrument(device, device, InstrumentCommand::Mode::kPosition, depth_mm, angle_deg, true);
  }

  void set_instrument(std::string_view name, const std::string& device,
                      InstrumentCommand::Mode mode, double translation, double rotation,
                      bool unwrap) {
    std::unique_lock lock(cmd_mu);
    const int idx = index_of(name);
    if (idx < 0) {
      lock.unlock();
      return drop(device, "unknown device name (see docs/devices.md)");
    }
    InstrumentCommand& c = latest.instruments[static_cast<std::size_t>(idx)];
    if (unwrap && c.mode == InstrumentCommand::Mode::kPosition) {
      // A matrix knows the angle only modulo a turn; take the turn nearest the last command so
      // that several turns of a wire add up.
      rotation += 360.0 * std::round((c.rotation_deg - rotation) / 360.0);
    }
    const InstrumentCommand next{c.name, mode, translation, rotation};
    const std::string why = opt.limits.check(next);
    if (!why.empty()) {
      lock.unlock();
      return drop(device, why);
    }
    c.mode = mode;
    c.translation_mm = translation;
    c.rotation_deg = rotation;
    if (idx < 64) latest.commanded |= std::uint64_t{1} << idx;
    n_accepted.fetch_add(1);
    const std::string beyond = check_drive(name, mode, translation, rotation);
    lock.unlock();
    if (!beyond.empty()) log(beyond);
  }

  // A command faster than the drive follows (IgtlServerOptions::drive_max_*): the drive goes at
  // its limit, and says so once per instrument for speed and once for spin. Under cmd_mu.
  std::string check_drive(std::string_view name, InstrumentCommand::Mode mode, double translation,
                          double rotation) {
    const double max_speed = opt.drive_max_speed_mm_s, max_spin = opt.drive_max_spin_deg_s;
    if (max_speed <= 0.0 && max_spin <= 0.0) return {};
    auto it =
        std::find_if(follow.begin(), follow.end(), [&](const Follow& f) { return f.name == name; });
    if (it == follow.end()) {
      Follow f;
      f.name = std::string(name);
      follow.push_back(std::move(f));
      it = follow.end() - 1;
    }
    Follow& f = *it;
    double speed = 0.0, spin = 0.0;
    if (mode == InstrumentCommand::Mode::kVelocity) {
      speed = std::abs(translation);
      spin = std::abs(rotation);
      f.has = false;
    } else {
      const auto now = Clock::now();
      if (!f.has) {
        f.has = true;
        f.t = now;
        f.translation = translation;
        f.rotation = rotation;
        return {};
      }
      const double dt = std::chrono::duration<double>(now - f.t).count();
      if (dt < kSpeedWindow) return {};
      speed = std::abs(translation - f.translation) / dt;
      spin = std::abs(rotation - f.rotation) / dt;
      f.t = now;
      f.translation = translation;
      f.rotation = rotation;
    }
    std::string out;
    if (max_speed > 0.0 && speed > max_speed && !f.said_speed) {
      f.said_speed = true;
      n_beyond.fetch_add(1);
      out = cat("'", f.name, "' moves at ", num(std::round(speed)),
                " mm/s, faster than the drive follows: it follows at ", num(max_speed), " mm/s");
    } else if (max_spin > 0.0 && spin > max_spin && !f.said_spin) {
      f.said_spin = true;
      n_beyond.fetch_add(1);
      out = cat("'", f.name, "' turns at ", num(std::round(spin)),
                " deg/s, faster than the drive follows: it turns at ", num(std::round(max_spin)),
                " deg/s");
    }
    return out;
  }

  // ---- sending ----

  void flush() {
    while (client_fd >= 0 && tx_sent < tx.size()) {
      const ssize_t n = ::send(client_fd, tx.data() + tx_sent, tx.size() - tx_sent, MSG_NOSIGNAL);
      if (n > 0) {
        tx_sent += static_cast<std::size_t>(n);
      } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) {
        return;  // the client is slow; try again next round
      } else {
        disconnect(cat("send failed: ", std::strerror(errno)));
        return;
      }
    }
    tx.clear();
    tx_sent = 0;
  }

  // The answers to exchange requests, as STRING messages on "exchange".
  void send_replies() {
    std::vector<std::string> texts, lines;
    {
      std::lock_guard lock(cmd_mu);
      texts.swap(replies);
      lines.swap(physics_log);
    }
    for (const std::string& l : lines) log(l);
    if (client_fd < 0) return;  // nobody asked (a client that left is not answered)
    for (const std::string& t : texts) {
      auto msg = igtl::StringMessage::New();
      msg->SetDeviceName("exchange");
      msg->SetString(t.c_str());
      msg->Pack();
      const auto* p = static_cast<const unsigned char*>(msg->GetPackPointer());
      tx.insert(tx.end(), p, p + msg->GetPackSize());
    }
    if (!texts.empty()) flush();
  }

  // Takes each instrument's mean force since the last take into fb_copy; after an exchange, one
  // force message per instrument of the scene now. Under fb_mu: the physics thread resizes both.
  void take_feedback() {
    std::lock_guard lock(fb_mu);
    if (out_names != fb_names) {
      out_names = fb_names;
      out_msgs.clear();
      for (const std::string& n : out_names) {
        auto msg = igtl::SensorMessage::New();
        msg->SetDeviceName(cat("force_", n).c_str());
        msg->SetLength(2);
        out_msgs.push_back(msg);
      }
      fb_copy.assign(out_names.size(), HandFeedback{});
    }
    for (std::size_t i = 0; i < fb_copy.size(); ++i)
      feedback.take(i, fb_copy[i].axial_force, fb_copy[i].torque);
  }

  void send_feedback() {
    if (client_fd < 0) {
      // Nobody to send to: start each instrument's mean afresh, so that a client connecting later
      // is not sent the mean over the time without one.
      take_feedback();
      return;
    }
    if (!tx.empty()) return flush();  // still sending the last batch: forces are latest-value
    take_feedback();
    igtl::TimeStamp::Pointer ts = igtl::TimeStamp::New();
    ts->GetTime();
    for (std::size_t i = 0; i < out_msgs.size(); ++i) {
      auto& msg = out_msgs[i];
      msg->SetValue(0, fb_copy[i].axial_force);
      msg->SetValue(1, fb_copy[i].torque);
      msg->SetTimeStamp(ts);
      msg->Pack();
      const auto* p = static_cast<const unsigned char*>(msg->GetPackPointer());
      tx.insert(tx.end(), p, p + msg->GetPackSize());
    }
    n_feedback.fetch_add(out_msgs.size());
    flush();
  }

  // ---- thread ----

  void run() {
    const auto period = std::chrono::duration_cast<Clock::duration>(
        std::chrono::duration<double>(1.0 / opt.feedback_rate_hz));
    auto next_send = Clock::now() + period;
    while (!stopping.load()) {
      // Wake for the next feedback message, and at least every 10 ms to notice stop().
      const auto now = Clock::now();
      auto wait = std::chrono::duration_cast<std::chrono::milliseconds>(next_send - now);
      int timeout = static_cast<int>(std::clamp<long long>(wait.count(), 0, 10));
      pollfd fds[2] = {{listen_fd, POLLIN, 0}, {client_fd, POLLIN, 0}};
      const nfds_t nfds = client_fd >= 0 ? 2 : 1;
      const int r = ::poll(fds, nfds, timeout);
      if (r < 0 && errno != EINTR) {
        log(cat("poll failed: ", std::strerror(errno)));
        std::this_thread::sleep_for(std::chrono::milliseconds(10));
      }
      if (r > 0) {
        if (nfds == 2 && (fds[1].revents & (POLLIN | POLLHUP | POLLERR))) read_client();
        if (fds[0].revents & POLLIN) accept_pending();
      }
      if (client_fd >= 0 && !tx.empty()) flush();
      send_replies();
      if (Clock::now() >= next_send) {
        send_feedback();
        next_send += period;
        // After a stall, resume the rate instead of sending a burst to catch up.
        if (next_send < Clock::now()) next_send = Clock::now() + period;
      }
    }
    disconnect("server stopping");
  }
};

IgtlServer::IgtlServer(IgtlServerOptions options) : impl_(std::make_unique<Impl>()) {
  Impl& s = *impl_;
  s.opt = std::move(options);
  const std::string src = "igtl";
  if (s.opt.port < 0 || s.opt.port > 65535) {
    throw InputError(src, "port", cat("expected 0-65535, got ", std::to_string(s.opt.port)));
  }
  require_positive(s.opt.feedback_rate_hz, src, "feedback_rate_hz");
  if (s.opt.feedback_rate_hz > 10000) {
    throw InputError(src, "feedback_rate_hz", "expected at most 10000 messages per second");
  }
  if (s.opt.instruments.empty()) throw InputError(src, "instruments", "expected at least one");
  for (std::size_t i = 0; i < s.opt.instruments.size(); ++i) {
    const std::string& n = s.opt.instruments[i];
    const std::string field = internal::index_path("instruments", i);
    if (!valid_instrument_name(n)) {
      throw InputError(src, field,
                       cat("expected 1-14 characters from A-Z a-z 0-9 _ -, not balloon, syringe, "
                           "buttons, exchange or a vel_/force_ prefix; got \"",
                           n, "\""));
    }
    for (std::size_t j = 0; j < i; ++j) {
      if (s.opt.instruments[j] == n) throw InputError(src, field, cat("duplicate name ", n));
    }
  }

  // Listening socket.
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(s.opt.port));
  if (inet_pton(AF_INET, s.opt.address.c_str(), &addr.sin_addr) != 1) {
    throw InputError(
        src, "address",
        cat("expected an IPv4 address such as 127.0.0.1, got \"", s.opt.address, "\""));
  }
  s.listen_fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (s.listen_fd < 0) throw std::runtime_error(cat("igtl: socket: ", std::strerror(errno)));
  int one = 1;
  setsockopt(s.listen_fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  if (::bind(s.listen_fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0 ||
      ::listen(s.listen_fd, kListenBacklog) != 0) {
    const std::string err = std::strerror(errno);
    ::close(s.listen_fd);
    throw InputError(src, "port",
                     cat("expected a free port on ", s.opt.address, ", got ",
                         std::to_string(s.opt.port), " (", err, ")"));
  }
  socklen_t len = sizeof addr;
  getsockname(s.listen_fd, reinterpret_cast<sockaddr*>(&addr), &len);
  s.bound_port = ntohs(addr.sin_port);
  fcntl(s.listen_fd, F_SETFL, fcntl(s.listen_fd, F_GETFL, 0) | O_NONBLOCK);

  // Commands start at rest: depth 0, angle 0, no pressure, no flow.
  for (const auto& n : s.opt.instruments) {
    s.latest.instruments.push_back({n, InstrumentCommand::Mode::kPosition, 0.0, 0.0});
  }
  s.fb_names = s.opt.instruments;  // the force messages are made by the server thread
  s.feedback.resize(s.fb_names.size());
  s.log_window = Clock::now();
  // Beyond loopback anyone who reaches this machine can drive the instruments.
  if ((ntohl(addr.sin_addr.s_addr) >> 24) != 127)
    s.emit(cat("warning: listening on ", s.opt.address,
               ": any machine that can reach this one can drive the instruments (OpenIGTLink "
               "has no authentication); use it on a trusted network only"));
  s.thread = std::thread([&s] { s.run(); });
}

IgtlServer::~IgtlServer() {
  stop();
}

void IgtlServer::stop() {
  if (!impl_) return;
  impl_->stopping = true;
  if (impl_->thread.joinable()) impl_->thread.join();
  if (impl_->listen_fd >= 0) {
    ::close(impl_->listen_fd);
    impl_->listen_fd = -1;
  }
}

int IgtlServer::port() const {
  return impl_->bound_port;
}

void IgtlServer::poll(double, StepCommands& out) {
  const Impl& s = *impl_;
  std::lock_guard lock(s.cmd_mu);
  out.drive.resize(s.latest.instruments.size());
  for (std::size_t i = 0; i < out.drive.size(); ++i)
    out.drive[i] = to_drive_command(s.latest.instruments[i]);
  out.balloon_pressure = s.latest.balloon_pressure_atm * kAtm;
  out.syringe_flow = s.latest.syringe_flow_ml_s * kMl;
  out.buttons = s.latest.buttons;
}

bool IgtlServer::poll_exchange(double, InstrumentChange& out) {
  Impl& s = *impl_;
  std::lock_guard lock(s.cmd_mu);
  if (s.exchanges.empty()) return false;
  out = std::move(s.exchanges.front());
  s.exchanges.pop_front();
  return true;
}

void IgtlServer::exchanged(const InstrumentChange& change,
                           std::span<const std::string> instruments) {
  Impl& s = *impl_;
  {
    // Commands by the scene's new order: a kept instrument's as the device left it, an added one
    // at rest at depth 0 until a command names it.
    std::lock_guard lock(s.cmd_mu);
    std::vector<InstrumentCommand> next;
    std::uint64_t mask = 0;
    for (std::size_t j = 0; j < instruments.size(); ++j) {
      const int i = s.index_of(instruments[j]);
      next.push_back(
          i >= 0 ? s.latest.instruments[static_cast<std::size_t>(i)]
                 : InstrumentCommand{instruments[j], InstrumentCommand::Mode::kPosition, 0.0, 0.0});
      if (i >= 0 && i < 64 && j < 64 && ((s.latest.commanded >> i) & 1u))
        mask |= std::uint64_t{1} << j;
    }
    s.latest.instruments = std::move(next);
    s.latest.commanded = mask;
    s.opt.instruments.assign(instruments.begin(), instruments.end());
    s.replies.push_back(cat("done: ", describe(change)));
    s.physics_log.push_back(cat("exchange done: ", describe(change)));
  }
  {
    std::lock_guard lock(s.fb_mu);
    s.fb_names.assign(instruments.begin(), instruments.end());
    s.feedback.resize(s.fb_names.size());
  }
  s.n_exchanges.fetch_add(1);
}

void IgtlServer::exchange_refused(const InstrumentChange& change, const InputError& why) {
  Impl& s = *impl_;
  s.n_refused.fetch_add(1);
  std::lock_guard lock(s.cmd_mu);
  s.physics_log.push_back(cat("exchange refused: ", describe(change), ": ", why.what()));
  s.replies.push_back(cat("refused: ", describe(change), ": ", why.what()));
}

void IgtlServer::publish(std::span<const HandFeedback> feedback) {
  Impl& s = *impl_;
  std::lock_guard lock(s.fb_mu);
  // By index: the scene's instruments are the device's, in the same order.
  const std::size_t n = std::min(feedback.size(), s.fb_names.size());
  for (std::size_t i = 0; i < n; ++i) {
    const HandFeedback& f = feedback[i];
    // A non-finite force must not reach a motor.
    s.feedback.add(i, std::isfinite(f.axial_force) ? f.axial_force : 0.0,
                   std::isfinite(f.torque) ? f.torque : 0.0);
  }
}

std::uint64_t IgtlServer::commanded_mask() const {
  std::lock_guard lock(impl_->cmd_mu);
  return impl_->latest.commanded;
}

IgtlStats IgtlServer::stats() const {
  const Impl& s = *impl_;
  IgtlStats st;
  st.connections = s.n_connections.load();
  st.disconnections = s.n_disconnections.load();
  st.messages_accepted = s.n_accepted.load();
  st.messages_dropped = s.n_dropped.load();
  st.feedback_sent = s.n_feedback.load();
  st.exchanges = s.n_exchanges.load();
  st.exchanges_refused = s.n_refused.load();
  st.clients_refused = s.n_refused_clients.load();
  st.messages_skipped = s.n_skipped.load();
  st.beyond_drive = s.n_beyond.load();
  st.connected = s.connected.load();
  return st;
}

}  // namespace vcsim
