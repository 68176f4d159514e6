// irrrd, the process: sysexits codes and signals, and, hidden behind [udpm] and run inside a
// private network namespace by tools/netns-run, the processes end to end over UDP multicast and
// through an LCM log.

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <fmt/core.h>
#include <spdlog/spdlog.h>
#include <catch2/catch.hpp>
#include <lcm/lcm-cpp.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/loop_csv.h"
#include "clients/common/replay_messages.h"
#include "core/irrr.h"
#include "daemon/common/irrr_config.h"
#include "daemon/journal.h"
#include "daemon/raw_subscription.h"
#include "daemon/sequencer.h"
#include "daemon/service.h"
#include "daemon/snapshot.h"
#include "daemon/stamp_merger.h"
#include "daemon/wire.h"
#include "irrr/correction_t.hpp"
#include "irrr/error_t.hpp"
#include "irrr/resync_request_t.hpp"
#include "irrr/solution_request_t.hpp"
#include "irrr/solution_t.hpp"
#include "irrr/verdicts_t.hpp"
#include "tests/processes.h"
#include "tests/recording_sink.h"
#include "tests/service_helpers.h"
#include "tests/test_files.h"

namespace irrr {
namespace {

using Catch::Matchers::Contains;
using Clock = std::chrono::steady_clock;

TEST_CASE("irrrd: sysexits codes, SIGHUP reloads what can change live, SIGTERM exits 0",
          "[daemon]") {
  // memq:// keeps this test off every network.
  const std::string dir = TestDirectory("daemon_signals");
  const std::string log = dir + "/irrrd.log";
  const std::string irrrd = std::string(IRRRD) + " --config ";
  WriteText(dir + "/bad.json", R"({"daemon": {"status_hz": "often"}})");
  CHECK(RunTool(irrrd + Quoted(dir + "/bad.json"), log) == 78);
  CHECK_THAT(ReadText(log), Contains("daemon.status_hz: expected a number"));
  CHECK(RunTool(irrrd + Quoted(dir + "/missing.json"), log) == 66);
  CHECK(RunTool(std::string(IRRRD) + " --no-such-option", log) == 64);
  CHECK(RunTool(std::string(IRRRD) + " --lcm-url 'bogus://x'", log) == 69);

  const std::string config = dir + "/irrrd.json";
  WriteText(config, R"({"daemon": {"lcm_url": "memq://", "log_level": "info"}})");
  CHECK(RunTool(irrrd + Quoted(config) + " --print-config", log) == 0);
  CHECK_THAT(ReadText(log), Contains("\"lcm_url\": \"memq://\""));

  Background daemon(irrrd + Quoted(config), log);
  REQUIRE(WaitForText(log, "listening on memq://", 10));
  WriteText(config, R"({"daemon": {"lcm_url": "memq://", "log_level": "debug", "status_hz": 4}})");
  daemon.Signal(SIGHUP);
  CHECK(WaitForText(log, "SIGHUP: log_level info -> debug", 10));
  CHECK(WaitForText(log, "SIGHUP: status_hz 1 -> 4", 10));
  WriteText(config, R"({"daemon": {"lcm_url": "memq://", "daemon_id": "other"}})");
  daemon.Signal(SIGHUP);
  CHECK(WaitForText(log, "need a restart", 10));
  WriteText(config, "{ not json");
  daemon.Signal(SIGHUP);
  CHECK(WaitForText(log, "configuration not reloaded, keeping the running one", 10));
  CHECK(daemon.Stop(SIGTERM) == 0);
  CHECK_THAT(ReadText(log), Contains("stopped: 0 keyframes"));
}

// LCM 1.3.1 keeps the kernel's default receive buffer (~208 kB) unless the URL asks for more.
const char* const kUdpmUrl = "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=2097152";

// `daemon_keys`: more keys of the "daemon" object (JSON, starting with a comma).
std::string WriteDaemonConfig(const std::string& dir, const std::string& daemon_keys = "") {
  const std::string config = dir + "/irrrd.json";
  WriteText(config,
            std::string("{\"daemon\": {\"lcm_url\": \"") + kUdpmUrl + "\", \"status_hz\": 5" +
                daemon_keys + "}, \"irrr\": {\"cluster_gap\": 10}}\n");
  return config;
}

TEST_CASE("udpm: irrrd fed by irrr-inject decides as irrr-batch", "[.][udpm]") {
  const std::string dir = TestDirectory("daemon_udpm");
  const std::string input = MakeTwoSessionIntel(dir);
  const std::string config = WriteDaemonConfig(dir);
  RunBatch(dir, input, config);

  Background daemon(std::string(IRRRD) + " --config " + Quoted(config), dir + "/daemon.log");
  Background listener(std::string(IRRR_LISTEN) + " --config " + Quoted(config) + " --decisions " +
                          Quoted(dir + "/listen.csv") + " --output " + Quoted(dir + "/listen.g2o"),
                      dir + "/listen.log");
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  const std::string inject = std::string(IRRR_INJECT) + " " + Quoted(input) + " --config " +
                             Quoted(config) + " --lcm-url '" + kUdpmUrl +
                             "' --rate 0 --wait --timeout 300";
  const int code = RunTool(inject, dir + "/inject.log");
  INFO(inject << "\n" << ReadText(dir + "/inject.log") << "\n" << ReadText(dir + "/daemon.log"));
  REQUIRE(code == 0);
  // The listener first: before writing, it asks the daemon for its whole solution.
  CHECK(listener.Stop(SIGINT) == 0);
  CHECK(daemon.Stop() == 0);
  CHECK_THAT(ReadText(dir + "/daemon.log"), Contains("0 input(s) rejected"));
  CheckSameAsBatch(dir);
}

TEST_CASE(
    "udpm: irrrd killed with SIGKILL at 12 random points while a dataset streams in "
    "restarts from its journal, and ends as irrr-batch",
    "[.][udpm]") {
  const std::string dir = TestDirectory("daemon_kill");
  const std::string input = MakeTwoSessionIntel(dir);
  // A snapshot every 50 inputs: most restarts restore one and replay only what followed it.
  const std::string config = WriteDaemonConfig(dir, ", \"journal\": {\"snapshot_every\": 50}");
  RunBatch(dir, input, config);
  const std::string irrrd =
      std::string(IRRRD) + " --config " + Quoted(config) + " --journal " + Quoted(dir + "/journal");
  Background listener(std::string(IRRR_LISTEN) + " --config " + Quoted(config) + " --decisions " +
                          Quoted(dir + "/listen.csv") + " --output " + Quoted(dir + "/listen.g2o"),
                      dir + "/listen.log");
  std::unique_ptr<Background> daemon = StartDaemon(irrrd, dir + "/daemon0.log");
  // At 40 messages per second the stream lasts about 17 s; the kills spread over 6 to 13 s of
  // it, so that later restarts rebuild a state with steps in it.
  Background inject(std::string(IRRR_INJECT) + " " + Quoted(input) + " --config " + Quoted(config) +
                        " --rate 40 --wait --timeout 300",
                    dir + "/inject.log");
  const unsigned seed = std::random_device()();
  std::mt19937 random(seed);
  std::uniform_int_distribution<int> pause_ms(500, 1100);
  constexpr int kKills = 12;
  std::string kills;
  const auto start = std::chrono::steady_clock::now();
  for (int k = 1; k <= kKills; ++k) {
    std::this_thread::sleep_for(std::chrono::milliseconds(pause_ms(random)));
    kills += fmt::format(
        " {:.2f}", std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    CHECK(inject.Running());  // the stream is still coming in
    CHECK(daemon->Stop(SIGKILL) == 128 + SIGKILL);
    daemon = StartDaemon(irrrd, dir + "/daemon" + std::to_string(k) + ".log");
  }
  INFO("seed " << seed << ", SIGKILL at" << kills << " s");
  const int inject_code = inject.Wait();
  INFO(ReadText(dir + "/inject.log"));
  REQUIRE(inject_code == 0);
  CHECK(listener.Stop(SIGINT) == 0);
  CHECK(daemon->Stop() == 0);
  // Every restart rebuilt the state from the journal (and said so), and the producer resent what
  // the dead daemons had lost.
  int recovered = 0;
  int from_snapshot = 0;
  int with_steps = 0;
  for (int k = 1; k <= kKills; ++k) {
    const std::string log = ReadText(dir + "/daemon" + std::to_string(k) + ".log");
    recovered += log.find("replayed") != std::string::npos ? 1 : 0;
    from_snapshot += log.find("restored the snapshot") != std::string::npos ? 1 : 0;
    with_steps += log.find("restored the snapshot") != std::string::npos &&
                          log.find("; 0 steps,") == std::string::npos
                      ? 1
                      : 0;
  }
  CHECK(recovered == kKills);
  INFO(from_snapshot << " of " << kKills << " restarts restored a snapshot, " << with_steps
                     << " of them with steps in it");
  CHECK(with_steps >= 1);
  CHECK_THAT(ReadText(dir + "/inject.log"), Contains("the daemon is missing 0"));
  CheckSameAsBatch(dir);
}

// Drops a share of the multicast datagrams inside this network namespace, with netem where the
// kernel has it, else with an nftables rule (numgen random); removed again on destruction.
class PacketLoss {
 public:
  explicit PacketLoss(int percent) {
    if (std::system(
            fmt::format("tc qdisc add dev lo root netem loss {}% 2>/dev/null", percent).c_str()) ==
        0) {
      how_ = "tc netem";
      return;
    }
    const std::string rule = fmt::format(
        "nft add table inet irrr_loss && nft add chain inet irrr_loss in "
        "'{{ type filter hook prerouting priority 0; }}' && nft add rule inet irrr_loss in ip "
        "daddr 224.0.0.0/4 counter && nft add rule inet irrr_loss in ip daddr 224.0.0.0/4 "
        "numgen random mod 100 '<' {} counter drop",
        percent);
    if (std::system(rule.c_str()) == 0) how_ = "nftables";
  }
  ~PacketLoss() {
    if (how_ == "tc netem") std::system("tc qdisc del dev lo root");
    if (how_ == "nftables") std::system("nft delete table inet irrr_loss");
  }
  const std::string& how() const { return how_; }
  // Datagrams seen and dropped so far, from the kernel's counters (-1: unreadable).
  std::pair<int64_t, int64_t> Counters(const std::string& dir) const {
    const std::string out = dir + "/loss_counters.txt";
    long long seen = -1;
    long long dropped = -1;
    if (how_ == "tc netem") {
      // " Sent 1234 bytes 56 pkt (dropped 7, overlimits 0 requeues 0)"
      RunTool("tc -s qdisc show dev lo", out);
      const std::string text = ReadText(out);
      const size_t at = text.find("Sent ");
      long long bytes = 0;
      long long sent = 0;
      if (at != std::string::npos && std::sscanf(text.c_str() + at,
                                                 "Sent %lld bytes %lld pkt (dropped %lld",
                                                 &bytes,
                                                 &sent,
                                                 &dropped) == 3) {
        seen = sent + dropped;
      }
      return {seen, dropped};
    }
    // Two rules: "counter packets N ..." (every multicast datagram), then the dropping one.
    RunTool("nft list table inet irrr_loss", out);
    const std::string text = ReadText(out);
    const size_t first = text.find("packets ");
    const size_t second = first == std::string::npos ? first : text.find("packets ", first + 1);
    if (second != std::string::npos) {
      seen = std::atoll(text.c_str() + first + 8);
      dropped = std::atoll(text.c_str() + second + 8);
    }
    return {seen, dropped};
  }

 private:
  std::string how_;
};

TEST_CASE("udpm: with 10% of datagrams lost, the daemon still ends as irrr-batch", "[.][udpm]") {
  const std::string dir = TestDirectory("daemon_loss");
  const std::string input = MakeTwoSessionIntel(dir);
  const std::string config = WriteDaemonConfig(dir);
  RunBatch(dir, input, config);
  const PacketLoss loss(10);
  INFO("packet loss by " << loss.how());
  REQUIRE_FALSE(loss.how().empty());  // tools/setup installs nftables
  Background listener(std::string(IRRR_LISTEN) + " --config " + Quoted(config) + " --decisions " +
                          Quoted(dir + "/listen.csv") + " --output " + Quoted(dir + "/listen.g2o"),
                      dir + "/listen.log");
  std::unique_ptr<Background> daemon =
      StartDaemon(std::string(IRRRD) + " --config " + Quoted(config), dir + "/daemon.log");
  const std::string inject = std::string(IRRR_INJECT) + " " + Quoted(input) + " --config " +
                             Quoted(config) + " --rate 0 --wait --timeout 300";
  const int code = RunTool(inject, dir + "/inject.log");
  INFO(ReadText(dir + "/inject.log"));
  REQUIRE(code == 0);
  CHECK(listener.Stop(SIGINT) == 0);
  CHECK(daemon->Stop() == 0);
  const auto [seen, dropped] = loss.Counters(dir);
  WARN("packet loss by " << loss.how() << ": " << dropped << " of " << seen
                         << " datagrams dropped");
  CHECK(dropped > 50);
  CHECK(dropped > 0.06 * seen);
  CHECK(dropped < 0.14 * seen);
  CHECK_THAT(ReadText(dir + "/inject.log"), Contains("the daemon is missing 0"));
  CheckSameAsBatch(dir, /*all_edges_heard=*/false);
}

TEST_CASE("udpm: an LCM log written by irrr-inject and replayed by lcm-logplayer gives the same",
          "[.][udpm]") {
  const std::string dir = TestDirectory("daemon_lcmlog");
  const std::string input = MakeTwoSessionIntel(dir);
  const std::string config = WriteDaemonConfig(dir);
  RunBatch(dir, input, config);
  const std::string log = dir + "/input.lcmlog";
  {
    const std::string write = std::string(IRRR_INJECT) + " " + Quoted(input) + " --lcmlog " +
                              Quoted(log) + " --rate 1000";
    const int code = RunTool(write, dir + "/inject.log");
    INFO(write << "\n" << ReadText(dir + "/inject.log"));
    REQUIRE(code == 0);
  }
  Background daemon(std::string(IRRRD) + " --config " + Quoted(config), dir + "/daemon.log");
  Background listener(std::string(IRRR_LISTEN) + " --config " + Quoted(config) + " --decisions " +
                          Quoted(dir + "/listen.csv") + " --output " + Quoted(dir + "/listen.g2o"),
                      dir + "/listen.log");
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  {
    const std::string play = std::string("lcm-logplayer -l '") + kUdpmUrl + "' " + Quoted(log);
    const int code = RunTool(play, dir + "/play.log");
    INFO(play << "\n" << ReadText(dir + "/play.log"));
    REQUIRE(code == 0);
  }
  // The log is played; wait until the daemon has applied it (its status says queue 0 and the
  // listener heard the last step), then stop both.
  lcm::LCM lcm(kUdpmUrl);
  REQUIRE(lcm.good());
  struct Watcher {
    status_t status{};
    bool heard = false;
    void On(const lcm::ReceiveBuffer* b, const std::string&) {
      heard = status.decode(b->data, 0, static_cast<int>(b->data_size)) >= 0;
    }
  } watcher;
  const RawSubscription subscription(
      &lcm,
      "IRRR_STATUS",
      [&watcher](const lcm::ReceiveBuffer& b, const std::string& c) { watcher.On(&b, c); },
      100);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::minutes(5);
  int settled = 0;
  while (settled < 3 && std::chrono::steady_clock::now() < deadline) {
    watcher.heard = false;
    lcm.handleTimeout(1000);
    if (!watcher.heard) continue;
    settled =
        watcher.status.queue_depth == 0 && watcher.status.n_keyframes == 400 ? settled + 1 : 0;
  }
  CHECK(settled == 3);
  // The listener first: before writing, it asks the daemon for its whole solution.
  CHECK(listener.Stop(SIGINT) == 0);
  CHECK(daemon.Stop() == 0);
  CheckSameAsBatch(dir);
}

}  // namespace
}  // namespace irrr
