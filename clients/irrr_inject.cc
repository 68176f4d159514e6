// irrr-inject: replays pose-graph files as the LCM messages of robots' front ends, for irrrd.
//
//   irrr-inject FILE [FILE ...] [--lcm-url URL] [--rate MSGS_PER_S] [--window N] [--lcmlog OUT]
//               [--sender NAME] [--first-robot R] [--robots R,R,... [--only-robot R]]
//               [--no-flush] [--wait] [--config FILE]
//
// Each file is one robot (robot ids from --first-robot), its sessions inferred as irrr-batch
// does; the files' messages are merged by vertex ordinal. A fleet in one multi-session file:
// --robots names the robot of each session, and a loop hypothesis is sent by the robot of its
// later pose (AssignRobots, replay_messages.h); --only-robot sends just that robot's part, as the
// robot's own front end would (and no FLUSH: the sessions' ENDs close every cluster). Messages go
// out in arrival order (replay_messages.h), then a FLUSH so that every cluster is judged. --rate
// paces them; --rate 0 sends as fast as the daemon absorbs them: at most --window messages ahead of
// what its status reports received and applied. --lcmlog writes an LCM log instead (for
// lcm-logplayer), stamped at --rate. --wait waits, after the last message, until the daemon has
// applied everything. Exit codes follow sysexits.h: 64 usage, 65 bad input data, 66 input missing,
// 69 LCM unavailable or daemon silent, 73 log not written, 78 bad configuration.

#include <sysexits.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <functional>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include <fmt/core.h>
#include <fmt/ranges.h>
#include <CLI/CLI.hpp>
#include <lcm/lcm-cpp.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/progress_line.h"
#include "clients/common/replay_messages.h"
#include "daemon/common/irrr_config.h"
#include "daemon/raw_subscription.h"
#include "daemon/wire.h"
#include "irrr/resync_request_t.hpp"
#include "irrr/status_t.hpp"

namespace irrr {
namespace {

struct Arguments {
  std::vector<std::string> inputs;
  std::string lcm_url;
  double rate = 2000.0;
  int window = 200;
  std::string lcmlog;
  std::string sender = "irrr-inject";
  int first_robot = 0;
  std::vector<int32_t> robots;  // per session of the one file (a fleet)
  int32_t only_robot = -1;
  bool no_flush = false;
  bool skip_invalid_edges = false;
  bool wait = false;
  double timeout_s = 600.0;
  std::string config;
};

// The latest status_t of the daemon, and its counts for each of our senders.
class StatusWatcher {
 public:
  void OnStatus(const lcm::ReceiveBuffer* buffer, const std::string&) {
    if (!DecodeMessage(buffer->data, static_cast<int>(buffer->data_size), &status)) return;
    heard = true;
    if (status.start_utime != start_utime) {
      // A daemon (re)started: only what this run has taken counts; after a crash that is what
      // its journal held, and the rest is sent again.
      counts.clear();
      start_utime = status.start_utime;
    }
    for (const sender_count_t& s : status.senders) counts[s.sender] = s;
  }
  // Sum of `field` over our senders.
  int64_t Total(const SenderFleet& fleet, int64_t sender_count_t::*field) const {
    int64_t total = 0;
    for (const std::string& name : fleet.names()) {
      const auto it = counts.find(name);
      if (it != counts.end()) total += it->second.*field;
    }
    return total;
  }
  // The first seq of `sender` the daemon has not taken (0 if it has not heard of it).
  int64_t NextSeq(const std::string& sender) const {
    const auto it = counts.find(sender);
    return it == counts.end() ? 0 : it->second.next_seq;
  }
  // Messages we sent that the daemon has not taken yet (lost, or on their way).
  int64_t Missing(const SenderFleet& fleet) const {
    int64_t missing = 0;
    for (size_t k = 0; k < fleet.names().size(); ++k) {
      missing += std::max<int64_t>(0, fleet.sender(k).last_seq() + 1 - NextSeq(fleet.names()[k]));
    }
    return missing;
  }

  bool heard = false;
  status_t status{};
  int64_t start_utime = 0;
  std::map<std::string, sender_count_t> counts;
};

// Sends again what the daemon lost: the ranges it asks for (resync_request_t), and, when its
// next_seq for one of our senders has not moved for kStall while we sent more (the last messages
// were lost, or the daemon restarted), the next `window` messages from there.
class Resender {
 public:
  using Send = std::function<void(const MessageSequencer::Encoded&)>;
  Resender(const SenderFleet* fleet, int window, Send send)
      : fleet_(fleet), window_(window), send_(std::move(send)) {}

  void OnRequest(const lcm::ReceiveBuffer* buffer, const std::string&) {
    resync_request_t request;
    if (!DecodeMessage(buffer->data, static_cast<int>(buffer->data_size), &request)) return;
    const MessageSequencer* sender = fleet_->Find(request.sender);
    if (sender == nullptr) return;
    ++requests;
    // At most kMaxPerRequest at once: the daemon asks again for what stays missing.
    constexpr int64_t kMaxPerRequest = 1000;
    int64_t budget = kMaxPerRequest;
    for (int32_t r = 0; r < request.n_ranges && budget > 0; ++r) {
      const int64_t first = std::max<int64_t>(0, request.first_seq[r]);
      const int64_t last = std::min(request.last_seq[r], sender->last_seq());
      for (int64_t seq = first; seq <= last && budget > 0; ++seq, --budget) {
        send_(sender->Sent(seq));
        ++resent;
      }
    }
  }

  void ResendStalled(const StatusWatcher& watcher) {
    using Clock = std::chrono::steady_clock;
    constexpr auto kStall = std::chrono::milliseconds(500);
    const auto now = Clock::now();
    for (size_t k = 0; k < fleet_->names().size(); ++k) {
      const MessageSequencer& sender = fleet_->sender(k);
      const int64_t next = watcher.NextSeq(sender.name());
      Progress& p = progress_[sender.name()];
      if (next != p.next_seq) p = {next, now, now};
      if (next > sender.last_seq() || now - p.moved < kStall || now - p.resent < kStall) continue;
      const int64_t last = std::min(sender.last_seq(), next + window_ - 1);
      for (int64_t seq = next; seq <= last; ++seq) send_(sender.Sent(seq));
      resent += last - next + 1;
      p.resent = now;
    }
  }

  int64_t requests = 0;  // resync requests for our senders
  int64_t resent = 0;    // messages sent again

 private:
  struct Progress {
    int64_t next_seq = -1;
    std::chrono::steady_clock::time_point moved{};
    std::chrono::steady_clock::time_point resent{};
  };
  const SenderFleet* fleet_;
  int window_;
  Send send_;
  std::map<std::string, Progress> progress_;
};

// The messages sent so far, as a bar that redraws in place on a terminal (ProgressLine); the
// last state is printed as a line of its own, on a terminal or not.
class SendProgress {
 public:
  explicit SendProgress(size_t total) : total_(total) {}
  void Show(size_t done, double seconds, bool last = false) {
    if (!last) {
      if (line_.Due()) line_.Update(Text(done, seconds));
      return;
    }
    if (line_.enabled()) {
      line_.Finish(Text(done, seconds));
    } else {
      fmt::print(stderr, "{}\n", Text(done, seconds));
    }
  }

 private:
  std::string Text(size_t done, double seconds) const {
    constexpr int kWidth = 30;
    return fmt::format("{} {}/{} messages, {:.1f} s, {:.0f} msg/s",
                       ProgressBar(done, total_, kWidth),
                       done,
                       total_,
                       seconds,
                       seconds > 0 ? done / seconds : 0.0);
  }

  size_t total_;
  ProgressLine line_;
};

template <class Pose>
int LoadMessages(const std::string& path,
                 FileFormat format,
                 const ReadOptions& read_options,
                 int32_t robot_id,
                 std::vector<ReplayMessage>* messages) {
  GraphFile<Pose> file;
  PoseGraph<Pose> graph;
  std::vector<int> graph_edge_of_file_edge;
  if (Status s = LoadPoseGraph(path, format, read_options, &file, &graph, &graph_edge_of_file_edge);
      !s.ok()) {
    fmt::print(stderr, "irrr-inject: {}\n", s.message());
    return EX_DATAERR;
  }
  PrintSkippedLines(stderr, "irrr-inject", path, file.skipped);
  *messages = ReplayMessages(graph, graph_edge_of_file_edge, robot_id);
  int loops = 0;
  for (const ReplayMessage& m : *messages) loops += m.kind == ReplayMessage::Kind::kLoop ? 1 : 0;
  fmt::print("input     {}: robot {}, {} {} poses in {} session(s), {} loop hypotheses\n",
             path,
             robot_id,
             Pose::kName,
             graph.num_vertices(),
             graph.num_sessions(),
             loops);
  return EX_OK;
}

int WriteLog(const Arguments& args,
             const std::vector<ReplayMessage>& messages,
             SenderFleet* fleet) {
  lcm::LogFile log(args.lcmlog, "w");
  if (!log.good()) {
    fmt::print(stderr, "irrr-inject: {}: cannot create\n", args.lcmlog);
    return EX_CANTCREAT;
  }
  const double rate = args.rate > 0 ? args.rate : 2000.0;
  const int64_t start = NowUtime();
  for (size_t k = 0; k < messages.size(); ++k) {
    const int64_t utime = start + static_cast<int64_t>(1e6 * k / rate);
    auto [channel, bytes] = fleet->Encode(messages[k], utime);
    lcm::LogEvent event{};
    event.timestamp = utime;
    event.channel = channel;
    event.datalen = static_cast<int32_t>(bytes.size());
    event.data = bytes.data();
    if (log.writeEvent(&event) != 0) {
      fmt::print(stderr, "irrr-inject: {}: write failed\n", args.lcmlog);
      return EX_CANTCREAT;
    }
  }
  fmt::print("lcmlog    {}: {} messages over {:.1f} s (replay: lcm-logplayer {})\n",
             args.lcmlog,
             messages.size(),
             messages.size() / rate,
             args.lcmlog);
  return EX_OK;
}

int Publish(const Arguments& args,
            const DaemonChannels& channels,
            const std::vector<ReplayMessage>& messages,
            SenderFleet* fleet) {
  lcm::LCM lcm(args.lcm_url);
  if (!lcm.good()) {
    fmt::print(stderr,
               "irrr-inject: cannot open LCM at \"{}\" (for udpm://, is there a multicast "
               "route?)\n",
               args.lcm_url);
    return EX_UNAVAILABLE;
  }
  StatusWatcher watcher;
  const RawSubscription status_subscription(
      &lcm,
      channels.status,
      [&watcher](const lcm::ReceiveBuffer& b, const std::string& c) { watcher.OnStatus(&b, c); },
      /*queue_capacity=*/100);
  auto send = [&](const MessageSequencer::Encoded& encoded) {
    lcm.publish(encoded.first, encoded.second.data(), static_cast<unsigned>(encoded.second.size()));
  };
  Resender resender(fleet, args.window, send);
  const RawSubscription resync_subscription(
      &lcm,
      channels.resync,
      [&resender](const lcm::ReceiveBuffer& b, const std::string& c) { resender.OnRequest(&b, c); },
      /*queue_capacity=*/1000);
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const auto deadline = start + std::chrono::duration<double>(args.timeout_s);
  auto seconds = [&] { return std::chrono::duration<double>(Clock::now() - start).count(); };
  // Asks for a status, handles messages and resends what stalls until `done` holds or the
  // deadline passes.
  auto wait_for = [&](auto done) {
    auto asked = Clock::now() - std::chrono::seconds(1);
    while (!done()) {
      if (Clock::now() > deadline) return false;
      if (Clock::now() - asked > std::chrono::milliseconds(100)) {
        send(fleet->Progress(NowUtime()));
        asked = Clock::now();
      }
      lcm.handleTimeout(20);
      resender.ResendStalled(watcher);
    }
    return true;
  };

  SendProgress bar(messages.size());
  // --rate 0 still spaces messages by 1 / kMaxRate: bursts faster than that overflow a busy
  // receiver's socket buffer on loopback before any status could slow them down.
  constexpr double kMaxRate = 10000.0;
  const auto spacing = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(1.0 / (args.rate > 0 ? args.rate : kMaxRate)));
  auto next_send = start;
  for (size_t k = 0; k < messages.size(); ++k) {
    if (args.rate == 0 &&
        (watcher.Missing(*fleet) >= args.window || watcher.status.queue_depth >= args.window)) {
      if (!wait_for([&] {
            return watcher.Missing(*fleet) < args.window / 2 &&
                   watcher.status.queue_depth < args.window / 2;
          })) {
        fmt::print(stderr,
                   "\nirrr-inject: the daemon did not catch up within --timeout {} s\n",
                   args.timeout_s);
        return EX_UNAVAILABLE;
      }
    }
    next_send = std::max(next_send + spacing, args.rate > 0 ? next_send : Clock::now());
    std::this_thread::sleep_until(next_send);
    send(fleet->Encode(messages[k], NowUtime()));
    while (lcm.handleTimeout(0) > 0) {
    }
    bar.Show(k + 1, seconds());
  }
  bar.Show(messages.size(), seconds(), true);
  const double send_s = seconds();
  // Until the daemon has taken everything (what it lost is resent). A daemon never heard from
  // within a few seconds is not there.
  const auto silent_deadline = Clock::now() + std::chrono::seconds(3);
  const bool all = wait_for([&] {
                     return (watcher.heard && watcher.Missing(*fleet) == 0) ||
                            (!watcher.heard && Clock::now() > silent_deadline);
                   }) &&
                   watcher.heard;
  fmt::print(
      "sent      {} messages in {:.2f} s ({:.0f} per second); resent {} ({} requests from the "
      "daemon); the daemon is missing {}\n",
      messages.size(),
      send_s,
      messages.size() / std::max(send_s, 1e-9),
      resender.resent,
      resender.requests,
      watcher.Missing(*fleet));
  if (!all) {
    fmt::print(stderr,
               "irrr-inject: {}\n",
               watcher.heard ? "the daemon did not take every message"
                             : "no status from the daemon (is irrrd running on this LCM URL?)");
    return EX_UNAVAILABLE;
  }
  if (!args.wait) return EX_OK;
  // ... and applied.
  const bool done =
      wait_for([&] { return watcher.Missing(*fleet) == 0 && watcher.status.queue_depth == 0; });
  if (!done) {
    fmt::print(stderr,
               "irrr-inject: the daemon did not finish within {} s (its latest status: {} of our "
               "messages missing, {} inputs queued)\n",
               args.timeout_s,
               watcher.Missing(*fleet),
               watcher.status.queue_depth);
    return EX_UNAVAILABLE;
  }
  const status_t& st = watcher.status;
  fmt::print(
      "daemon    took all {} messages (inputs and progress requests) from {} sender(s) ({} "
      "rejected, {} duplicates ignored), {} "
      "steps, {} loops accepted, {} rejected or reversed, {} component(s), latest solution {}, "
      "variance factor {:.4g}{}\n",
      watcher.Total(*fleet, &sender_count_t::next_seq),
      fleet->names().size(),
      watcher.Total(*fleet, &sender_count_t::rejected),
      watcher.Total(*fleet, &sender_count_t::duplicates),
      st.n_steps,
      st.n_accepted,
      st.n_rejected,
      st.n_components,
      st.solution_id,
      st.variance_factor,
      // The estimate only when the tests used another factor (bounded, or fixed by the config).
      st.variance_estimate != st.variance_factor
          ? fmt::format(" (the data's estimate {:.4g})", st.variance_estimate)
          : std::string());
  return EX_OK;
}

int Run(Arguments args) {
  DaemonOptions daemon;
  if (Status s = LoadClientConfig(args.config, &daemon, &args.lcm_url); !s.ok()) {
    fmt::print(stderr, "irrr-inject: {}\n", s.message());
    return EX_CONFIG;
  }
  const DaemonChannels& channels = daemon.channels;
  std::vector<std::vector<ReplayMessage>> robots;
  for (size_t k = 0; k < args.inputs.size(); ++k) {
    const std::string& path = args.inputs[k];
    if (!std::ifstream(path)) {
      fmt::print(stderr, "irrr-inject: {}: cannot open\n", path);
      return EX_NOINPUT;
    }
    FileFormat format;
    int dimension = 0;
    if (Status s = InspectGraphFile(path, &format, &dimension); !s.ok()) {
      fmt::print(stderr, "irrr-inject: {}\n", s.message());
      return EX_DATAERR;
    }
    std::vector<ReplayMessage> messages;
    const int32_t robot = args.first_robot + static_cast<int32_t>(k);
    ReadOptions read_options;
    read_options.skip_invalid_edges = args.skip_invalid_edges;
    const int code = dimension == 2
                         ? LoadMessages<Pose2>(path, format, read_options, robot, &messages)
                         : LoadMessages<Pose3>(path, format, read_options, robot, &messages);
    if (code != EX_OK) return code;
    robots.push_back(std::move(messages));
  }
  std::vector<ReplayMessage> messages = MergeByStamp(robots);
  int32_t first_robot = args.first_robot;
  int num_robots = static_cast<int>(robots.size());
  if (!args.robots.empty()) {
    if (!AssignRobots(args.robots, args.only_robot, &messages)) {
      fmt::print(stderr,
                 "irrr-inject: --robots names {} robot(s), the file has more sessions\n",
                 args.robots.size());
      return EX_USAGE;
    }
    first_robot = *std::min_element(args.robots.begin(), args.robots.end());
    num_robots = *std::max_element(args.robots.begin(), args.robots.end()) - first_robot + 1;
    if (args.only_robot >= 0) {
      first_robot = args.only_robot;
      num_robots = 1;
    }
    fmt::print("fleet     sessions' robots {}; sending {} message(s){}\n",
               fmt::join(args.robots, ","),
               messages.size(),
               args.only_robot >= 0 ? " of robot " + std::to_string(args.only_robot) : "");
  }
  if (!args.no_flush && args.only_robot < 0) messages.push_back(FlushMessage());
  SenderFleet fleet(args.sender, channels, first_robot, num_robots);
  return args.lcmlog.empty() ? Publish(args, channels, messages, &fleet)
                             : WriteLog(args, messages, &fleet);
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  irrr::Arguments args;
  CLI::App app{"irrr-inject: replay pose-graph files as LCM messages for irrrd"};
  app.add_option("inputs", args.inputs, "g2o or TORO files, one robot each")->required();
  app.add_option(
      "--lcm-url",
      args.lcm_url,
      "LCM URL (default: the --config file's daemon.lcm_url, else LCM_DEFAULT_URL or LCM's)");
  app.add_option("--rate", args.rate, "messages per second; 0: as fast as the daemon absorbs them")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--window", args.window, "--rate 0: messages sent ahead of the daemon")
      ->check(CLI::Range(10, 1000000))
      ->capture_default_str();
  app.add_option("--lcmlog", args.lcmlog, "write an LCM log here instead of publishing");
  app.add_option("--sender", args.sender, "header.sender of the messages")->capture_default_str();
  app.add_option("--first-robot", args.first_robot, "robot id of the first file")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  auto* robots_option =
      app.add_option("--robots",
                     args.robots,
                     "a fleet in one file: the robot id of each of its sessions (comma separated)")
          ->delimiter(',')
          ->check(CLI::NonNegativeNumber);
  app.add_option("--only-robot",
                 args.only_robot,
                 "send only this robot's keyframes, session ENDs and the loops it recognised "
                 "(no FLUSH)")
      ->needs(robots_option)
      ->check(CLI::NonNegativeNumber);
  app.add_flag("--no-flush", args.no_flush, "do not send a FLUSH after the last message");
  app.add_flag("--skip-invalid-edges",
               args.skip_invalid_edges,
               "leave out edge lines that are well formed but invalid (self-loop, non-finite "
               "number, information not positive definite, undeclared vertex), each named on "
               "stderr, instead of failing");
  app.add_flag(
      "--wait", args.wait, "wait until the daemon has applied everything, print its counts");
  app.add_option("--timeout", args.timeout_s, "seconds to wait for the daemon")
      ->capture_default_str();
  app.add_option("--config", args.config, "the daemon's JSON configuration (for channel names)");
  app.footer(
      "Exit codes: 0 ok, 64 usage, 65 bad input data, 66 input missing, 69 LCM unavailable "
      "or daemon silent, 73 log not written, 78 bad configuration.");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }
  if (args.sender.empty() || args.sender.size() > 64) {
    fmt::print(stderr, "irrr-inject: --sender: must have 1 to 64 characters\n");
    return EX_USAGE;
  }
  if (!args.robots.empty() && args.inputs.size() != 1) {
    fmt::print(stderr, "irrr-inject: --robots: give one multi-session file\n");
    return EX_USAGE;
  }
  if (args.only_robot >= 0 &&
      std::find(args.robots.begin(), args.robots.end(), args.only_robot) == args.robots.end()) {
    fmt::print(stderr, "irrr-inject: --only-robot {}: not in --robots\n", args.only_robot);
    return EX_USAGE;
  }
  return irrr::Run(args);
}
