// irrr-view: a live map of what irrrd publishes, in a web browser.
//
//   irrr-view [--config FILE] [--lcm-url URL] [--port N] [--address A]
//
// It hears the daemon's pose chunks (solution_t) and verdicts (verdicts_t), keeps the newest pose
// of every key and the newest verdict of every hypothesis, and serves on http://A:N/ (default
// 127.0.0.1:8765: loopback only) a page that draws the map: one path per session, accepted loops
// green, rejected red, reversed orange. The page holds a server-sent-event stream (/events) and
// redraws whenever the map changes (at most 5 times a second); /state.json is the same map as one
// document. It asks the daemon for its whole solution when it starts. Exit codes follow
// sysexits.h: 64 usage, 69 LCM unavailable or port taken, 78 bad configuration.

#include <poll.h>
#include <signal.h>
#include <sys/signalfd.h>
#include <sysexits.h>
#include <unistd.h>

#include <chrono>
#include <condition_variable>
#include <csignal>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include <fmt/core.h>
#include <CLI/CLI.hpp>
#include <lcm/lcm-cpp.hpp>
#include <nlohmann/json.hpp>

#include "daemon/common/irrr_config.h"
#include "daemon/raw_subscription.h"
#include "daemon/wire.h"
#include "irrr/solution_request_t.hpp"
#include "irrr/solution_t.hpp"
#include "irrr/verdicts_t.hpp"

// Last: it includes <resolv.h>, whose macro _res would rename a parameter of Eigen's templates.
#include <httplib.h>

namespace irrr {
namespace {

// The page: an SVG redrawn from each event of /events.
constexpr const char* kPage = R"html(<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>irrrd: live map</title>
<style>
 body { font-family: sans-serif; margin: 12px; }
 #status { margin-bottom: 8px; }
 svg { border: 1px solid #ccc; background: white; }
 .session { fill: none; stroke-width: 1.5; vector-effect: non-scaling-stroke; }
 .loop { stroke-width: 1; vector-effect: non-scaling-stroke; }
 .loop.accepted { stroke: #2ca02c; }
 .loop.rejected { stroke: #d62728; stroke-dasharray: 5 3; }
 .loop.reversed { stroke: #ff7f0e; stroke-dasharray: 2 2; }
 .loop.pending { stroke: #aaa; stroke-dasharray: 1 3; }
</style></head>
<body data-solution="0" data-updates="0">
<div id="status">waiting for irrrd ...</div>
<svg id="map" width="800" height="800" viewBox="0 0 800 800"></svg>
<script>
const colours = ["#1f77b4", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#393b79", "#bcbd22"];
function draw(state) {
  let xs = [], ys = [];
  for (const s of state.sessions) for (const p of s.xy) { xs.push(p[0]); ys.push(p[1]); }
  const svg = document.getElementById("map");
  if (xs.length === 0) return;
  const minX = Math.min(...xs), maxX = Math.max(...xs), minY = Math.min(...ys), maxY = Math.max(...ys);
  const scale = 760 / Math.max(maxX - minX, maxY - minY, 1e-9);
  const X = x => 20 + (x - minX) * scale, Y = y => 780 - (y - minY) * scale;
  let body = "";
  state.sessions.forEach((s, i) => {
    const d = s.xy.map((p, k) => (k ? "L" : "M") + X(p[0]).toFixed(1) + "," + Y(p[1]).toFixed(1)).join(" ");
    body += `<path class="session" data-session="${s.robot}/${s.session}" stroke="${colours[i % colours.length]}" d="${d}"/>`;
  });
  for (const l of state.loops) {
    body += `<line class="loop ${l.state}" x1="${X(l.from[0]).toFixed(1)}" y1="${Y(l.from[1]).toFixed(1)}" x2="${X(l.to[0]).toFixed(1)}" y2="${Y(l.to[1]).toFixed(1)}"/>`;
  }
  svg.innerHTML = body;
  const c = state.counts;
  document.getElementById("status").textContent =
    `solution ${state.solution} of ${state.daemon}: ${state.sessions.length} session(s), ` +
    `${c.accepted} accepted, ${c.rejected} rejected, ${c.reversed} reversed, ${c.pending} pending`;
  document.body.dataset.solution = state.solution;
}
// ?events=N: close the stream after N maps (a test's headless browser then dumps the page).
const limit = Number(new URLSearchParams(location.search).get("events")) || 0;
let updates = 0;
const events = new EventSource("/events");
events.onmessage = e => {
  draw(JSON.parse(e.data));
  document.body.dataset.updates = ++updates;
  if (limit && updates >= limit) events.close();
};
</script></body></html>
)html";

struct Arguments {
  std::string config;
  std::string lcm_url;
  std::string address = "127.0.0.1";
  int port = 8765;
};

// What the daemon has published, newest first; shared by the LCM thread and the HTTP threads.
class LiveMap {
 public:
  void OnSolution(const solution_t& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    Session& s = sessions_[{m.robot_id, m.session_id}];
    for (int32_t k = 0; k < m.n_poses; ++k) {
      Key& key = s.keys[m.first_key + k];
      if (key.solution > m.solution_id) continue;
      key.solution = m.solution_id;
      key.x = m.poses[k].t[0];
      key.y = m.poses[k].t[1];
    }
    Changed(m.solution_id, m.header.sender);
  }
  void OnVerdicts(const verdicts_t& m) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const verdict_t& v : m.verdicts) {
      auto& [solution, verdict] = verdicts_[{v.sender, v.hypothesis_id}];
      if (solution > m.solution_id) continue;
      solution = m.solution_id;
      verdict = v;
    }
    Changed(m.solution_id, m.header.sender);
  }

  // The map as JSON (the page's state).
  std::string Json() const {
    std::lock_guard<std::mutex> lock(mutex_);
    nlohmann::json j;
    j["solution"] = solution_;
    j["daemon"] = daemon_;
    j["sessions"] = nlohmann::json::array();
    for (const auto& [name, s] : sessions_) {
      nlohmann::json xy = nlohmann::json::array();
      for (const auto& [key, p] : s.keys) xy.push_back({p.x, p.y});
      j["sessions"].push_back({{"robot", name.first}, {"session", name.second}, {"xy", xy}});
    }
    j["loops"] = nlohmann::json::array();
    std::map<std::string, int> counts = {
        {"accepted", 0}, {"rejected", 0}, {"reversed", 0}, {"pending", 0}};
    for (const auto& [name, entry] : verdicts_) {
      const verdict_t& v = entry.second;
      const char* state = v.state == verdict_t::ACCEPTED   ? "accepted"
                          : v.state == verdict_t::REVERSED ? "reversed"
                          : v.state == verdict_t::PENDING  ? "pending"
                                                           : "rejected";
      ++counts[state];
      const Key* from = Find(v.robot_from, v.session_from, v.key_from);
      const Key* to = Find(v.robot_to, v.session_to, v.key_to);
      if (from == nullptr || to == nullptr) continue;
      j["loops"].push_back(
          {{"from", {from->x, from->y}}, {"to", {to->x, to->y}}, {"state", state}});
    }
    j["counts"] = counts;
    return j.dump();
  }

  // Whether a verdict names a pose the map has not got (its solution message was lost or is
  // still on its way).
  bool MissingPoses() const {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& [name, entry] : verdicts_) {
      const verdict_t& v = entry.second;
      if (Find(v.robot_from, v.session_from, v.key_from) == nullptr ||
          Find(v.robot_to, v.session_to, v.key_to) == nullptr) {
        return true;
      }
    }
    return false;
  }

  // Waits up to `timeout` for a version newer than `seen`; returns the current version.
  int64_t WaitForChange(int64_t seen, std::chrono::milliseconds timeout) {
    std::unique_lock<std::mutex> lock(mutex_);
    changed_.wait_for(lock, timeout, [&] { return version_ != seen || stopping_; });
    return version_;
  }
  void Stop() {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
    changed_.notify_all();
  }
  bool stopping() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return stopping_;
  }

 private:
  struct Key {
    int64_t solution = 0;
    double x = 0.0;
    double y = 0.0;
  };
  struct Session {
    std::map<int64_t, Key> keys;
  };

  void Changed(int64_t solution, const std::string& daemon) {
    solution_ = std::max(solution_, solution);
    daemon_ = daemon;
    ++version_;
    changed_.notify_all();
  }
  const Key* Find(int32_t robot, int32_t session, int64_t key) const {
    const auto s = sessions_.find({robot, session});
    if (s == sessions_.end()) return nullptr;
    const auto k = s->second.keys.find(key);
    return k == s->second.keys.end() ? nullptr : &k->second;
  }

  mutable std::mutex mutex_;
  std::condition_variable changed_;
  std::map<std::pair<int32_t, int32_t>, Session> sessions_;
  std::map<std::pair<std::string, int64_t>, std::pair<int64_t, verdict_t>> verdicts_;
  int64_t solution_ = 0;
  std::string daemon_;
  int64_t version_ = 0;
  bool stopping_ = false;
};

int Run(Arguments args) {
  DaemonOptions daemon;
  if (Status s = LoadClientConfig(args.config, &daemon, &args.lcm_url); !s.ok()) {
    fmt::print(stderr, "irrr-view: {}\n", s.message());
    return EX_CONFIG;
  }
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  for (int signal_number : {SIGTERM, SIGINT}) std::signal(signal_number, SIG_DFL);
  sigprocmask(SIG_BLOCK, &signals, nullptr);  // before any thread starts: they inherit it
  const int signal_fd = signalfd(-1, &signals, SFD_CLOEXEC);

  lcm::LCM lcm(args.lcm_url);
  if (!lcm.good()) {
    fmt::print(stderr, "irrr-view: cannot open LCM at \"{}\"\n", args.lcm_url);
    return EX_UNAVAILABLE;
  }
  LiveMap map;
  std::vector<std::unique_ptr<RawSubscription>> subscriptions;
  subscriptions.push_back(std::make_unique<RawSubscription>(
      &lcm,
      daemon.channels.solution,
      [&map](const lcm::ReceiveBuffer& b, const std::string&) {
        solution_t m;
        if (DecodeMessage(b.data, static_cast<int>(b.data_size), &m)) map.OnSolution(m);
      },
      100000));
  subscriptions.push_back(std::make_unique<RawSubscription>(
      &lcm,
      daemon.channels.verdicts,
      [&map](const lcm::ReceiveBuffer& b, const std::string&) {
        verdicts_t m;
        if (DecodeMessage(b.data, static_cast<int>(b.data_size), &m)) map.OnVerdicts(m);
      },
      100000));

  httplib::Server server;
  server.Get("/", [](const httplib::Request&, httplib::Response& res) {
    res.set_content(kPage, "text/html; charset=utf-8");
  });
  server.Get("/state.json", [&map](const httplib::Request&, httplib::Response& res) {
    res.set_content(map.Json(), "application/json");
  });
  server.Get("/events", [&map](const httplib::Request& req, httplib::Response& res) {
    fmt::print("irrr-view: a page connected from {}\n", req.remote_addr);
    std::fflush(stdout);
    res.set_header("Cache-Control", "no-cache");
    res.set_chunked_content_provider(
        "text/event-stream", [&map, seen = int64_t{0}](size_t, httplib::DataSink& sink) mutable {
          // The map as soon as there is one, then whenever it changes (at most 5 times a
          // second), with a comment as a keep-alive every few seconds.
          int64_t version = map.WaitForChange(seen, std::chrono::seconds(5));
          // One step's messages (a solution per session, then the verdicts) make one event:
          // wait until they stop coming for 100 ms, for at most a second.
          for (int i = 0; i < 10 && version != seen; ++i) {
            const int64_t later = map.WaitForChange(version, std::chrono::milliseconds(100));
            if (later == version) break;
            version = later;
          }
          if (map.stopping()) return false;
          const std::string event =
              version == seen ? std::string(": alive\n\n") : "data: " + map.Json() + "\n\n";
          seen = version;
          if (!sink.write(event.data(), event.size())) return false;
          std::this_thread::sleep_for(std::chrono::milliseconds(200));
          return true;
        });
  });
  if (!server.bind_to_port(args.address, args.port)) {
    fmt::print(stderr, "irrr-view: cannot listen on {}:{}\n", args.address, args.port);
    return EX_UNAVAILABLE;
  }
  std::thread http([&server] { server.listen_after_bind(); });
  fmt::print("irrr-view: the live map is on http://{}:{}/ (LCM {})\n",
             args.address,
             args.port,
             args.lcm_url.empty() ? "default URL" : args.lcm_url);
  std::fflush(stdout);

  // The whole solution, at start and again whenever poses stay missing for a second (UDP loses
  // datagrams; the daemon answers a request with every pose and verdict).
  int64_t request_seq = 0;
  const auto request_solution = [&](const char* reason) {
    solution_request_t request{};
    request.header = {NowUtime(), request_seq++, "irrr-view"};
    request.reason = reason;
    const std::vector<uint8_t> bytes = EncodeMessage(request);
    lcm.publish(
        daemon.channels.solution_request, bytes.data(), static_cast<unsigned>(bytes.size()));
  };
  request_solution("irrr-view started");
  using Clock = std::chrono::steady_clock;
  Clock::time_point next_check = Clock::now() + std::chrono::seconds(1);
  bool missing = false;  // at the last check
  for (;;) {
    pollfd fds[2] = {{lcm.getFileno(), POLLIN, 0}, {signal_fd, POLLIN, 0}};
    poll(fds, 2, 200);
    if (fds[1].revents & POLLIN) break;
    if (fds[0].revents & POLLIN) lcm.handle();
    // Once a second (the check reads every verdict): poses missing at two checks in a row are
    // not just on their way.
    const Clock::time_point now = Clock::now();
    if (now < next_check) continue;
    next_check = now + std::chrono::seconds(1);
    const bool missing_now = map.MissingPoses();
    if (missing && missing_now) {
      fmt::print("irrr-view: verdicts name poses not received; asking for the whole solution\n");
      std::fflush(stdout);
      request_solution("irrr-view: poses missing");
    }
    missing = missing_now;
  }
  map.Stop();
  server.stop();
  http.join();
  close(signal_fd);
  return EX_OK;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  irrr::Arguments args;
  CLI::App app{"irrr-view: irrrd's map, live in a web browser"};
  app.add_option("--config", args.config, "the daemon's JSON configuration (channels, LCM URL)");
  app.add_option("--lcm-url", args.lcm_url, "LCM URL (default: the configuration's, else LCM's)");
  app.add_option("--port", args.port, "HTTP port")
      ->check(CLI::Range(1, 65535))
      ->capture_default_str();
  app.add_option("--address",
                 args.address,
                 "address to serve on (default loopback only; another address exposes the map "
                 "to that network)")
      ->capture_default_str();
  app.footer("Exit codes: 0 ok, 64 usage, 69 LCM unavailable or port taken, 78 bad configuration.");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }
  return irrr::Run(args);
}
