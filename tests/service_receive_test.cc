// The service receives (daemon/service_receive.cc, daemon/inputs.h): every kind of bad input is
// answered, a full queue refuses and re-requests, each sender's order survives loss, duplicates
// and reordering, and the allow-lists keep others out.

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
#include "tests/recording_sink.h"
#include "tests/service_helpers.h"
#include "tests/test_files.h"

namespace irrr {
namespace {

using Catch::Matchers::Contains;
using Clock = std::chrono::steady_clock;

TEST_CASE("Every kind of bad input is answered on the error channel and nothing valid is lost",
          "[daemon]") {
  RecordingSink sink;
  DaemonOptions daemon;
  daemon.limits.max_message_bytes = 4096;
  IrrrOptions options;
  options.cluster_gap = 3.0;
  Service service(daemon, options, &sink);
  const DaemonChannels& ch = daemon.channels;
  const double nan = std::numeric_limits<double>::quiet_NaN();

  Producer producer(&service, ch);

  // A valid session of 20 keys on a straight line, and four true loops (poses 2 apart).
  std::vector<std::function<void()>> valid;
  int valid_loops = 0;
  for (int64_t key = 0; key < 20; ++key) {
    valid.push_back([&producer, key] { producer.Send(Keyframe(0, key)); });
    if (key >= 10 && key % 3 == 1) {
      valid.push_back([&producer, key] { producer.Send(Loop(key, key - 2, key)); });
      ++valid_loops;
    }
  }
  valid.push_back([&producer] { producer.Send(SessionEvent(session_event_t::END)); });

  std::vector<BadInput> bad;
  auto keyframe = [&](const char* what, const char* field, auto edit) {
    keyframe_t k = Keyframe(0, 5);
    edit(k);
    bad.push_back({what, ch.keyframe, [k](Producer& p) { p.Send(k); }, field});
  };
  auto loop = [&](const char* what, const char* field, auto edit) {
    loop_hypothesis_t l = Loop(100, 3, 5);
    edit(l);
    bad.push_back({what, ch.loop, [l](Producer& p) { p.Send(l); }, field});
  };
  auto raw = [&](const char* what, const std::string& channel, std::vector<uint8_t> bytes) {
    bad.push_back({what, channel, [channel, bytes](Producer& p) { p.Raw(channel, bytes); }, ""});
  };
  keyframe("NaN in the odometry", "odom_delta.t", [&](keyframe_t& k) { k.odom_delta.t[0] = nan; });
  keyframe("infinite pose", "odom_pose.t", [](keyframe_t& k) {
    k.odom_pose.t[1] = std::numeric_limits<double>::infinity();
  });
  keyframe("quaternion of norm 2", "odom_delta.q", [](keyframe_t& k) { k.odom_delta.q[0] = 2.0; });
  keyframe("SE(2) pose with a z", "odom_delta.t", [](keyframe_t& k) { k.odom_delta.t[2] = 1.0; });
  keyframe("SE(2) pose rotating about x", "odom_delta.q", [](keyframe_t& k) {
    k.odom_delta.q[0] = std::sqrt(0.5);
    k.odom_delta.q[1] = std::sqrt(0.5);
    k.odom_delta.q[3] = 0.0;
  });
  keyframe("information not positive definite", "information", [](keyframe_t& k) {
    k.information[2][2] = -1.0;
  });
  keyframe(
      "information not symmetric", "information", [](keyframe_t& k) { k.information[0][1] = 5.0; });
  keyframe("information with NaN", "information[1][1]", [&](keyframe_t& k) {
    k.information[1][1] = nan;
  });
  keyframe("information outside the SE(2) block", "information[4][4]", [](keyframe_t& k) {
    k.information[4][4] = 1.0;
  });
  keyframe("unknown dimension", "dim", [](keyframe_t& k) { k.dim = 4; });
  keyframe("negative key", "key", [](keyframe_t& k) { k.key = -1; });
  keyframe("negative robot", "robot_id", [](keyframe_t& k) { k.robot_id = -2; });
  keyframe(
      "has_odom_edge not boolean", "has_odom_edge", [](keyframe_t& k) { k.has_odom_edge = 7; });
  {
    keyframe_t k = Keyframe(0, 5);
    k.header.sender.clear();
    raw("empty sender", ch.keyframe, EncodeMessage(k));
    bad.back().field = "header.sender";
    k.header.sender = std::string(65, 'r');
    raw("sender name over 64 bytes", ch.keyframe, EncodeMessage(k));
    bad.back().field = "header.sender";
  }
  keyframe("duplicate key", "key", [](keyframe_t& k) { k.key = 0; });
  keyframe("session changes pose type", "dim", [](keyframe_t& k) {
    k.dim = keyframe_t::DIM_SE3;
    InformationToWire<Pose3>(Pose3::Matrix::Identity(), k.information);
  });
  keyframe("later pose without odometry", "has_odom_edge", [](keyframe_t& k) {
    k.key = 20, k.has_odom_edge = 0;
  });
  keyframe("stamp older than the session's last", "stamp_utime", [](keyframe_t& k) {
    k.key = 20, k.stamp_utime = 0;
  });
  loop("loop of the other pose type", "dim", [](loop_hypothesis_t& l) {
    l.dim = keyframe_t::DIM_SE3;
    InformationToWire<Pose3>(Pose3::Matrix::Identity(), l.information);
  });
  loop("self-loop", "key_to", [](loop_hypothesis_t& l) { l.key_to = 3; });
  loop("duplicate hypothesis id", "hypothesis_id", [](loop_hypothesis_t& l) {
    l.hypothesis_id = 13;
  });
  loop("negative hypothesis id", "hypothesis_id", [](loop_hypothesis_t& l) {
    l.hypothesis_id = -5;
  });
  loop("NaN score", "score", [&](loop_hypothesis_t& l) { l.score = static_cast<float>(nan); });
  loop("loop information singular", "information", [](loop_hypothesis_t& l) {
    InformationToWire<Pose2>(Pose2::Matrix::Zero(), l.information);
  });
  {
    session_event_t e = SessionEvent(9);
    bad.push_back({"unknown session event", ch.session, [e](Producer& p) { p.Send(e); }, "event"});
    e = SessionEvent(session_event_t::END, 77);
    bad.push_back(
        {"END of an unknown session", ch.session, [e](Producer& p) { p.Send(e); }, "session_id"});
  }
  raw("garbage bytes", ch.keyframe, std::vector<uint8_t>(64, 0xAB));
  {
    std::vector<uint8_t> truncated = EncodeMessage(Keyframe(0, 5));
    truncated.resize(truncated.size() / 2);
    raw("truncated message", ch.loop, truncated);
  }
  raw("a keyframe on the loop channel", ch.loop, EncodeMessage(Keyframe(0, 5)));
  // String lengths that lcm-gen 1.3.1's decoder turned into an exception or an overflow (found
  // by tests/fuzz): header.sender's int32 length follows the fingerprint, utime and seq.
  for (const uint32_t length : {0u, 0x80000000u}) {
    std::vector<uint8_t> bytes = EncodeMessage(Keyframe(0, 5));
    for (int k = 0; k < 4; ++k) bytes[24 + k] = static_cast<uint8_t>(length >> (24 - 8 * k));
    raw(length == 0 ? "a string of length 0" : "a string of length INT_MIN", ch.keyframe, bytes);
  }
  raw("message over max_message_bytes", ch.keyframe, std::vector<uint8_t>(5000, 0));
  REQUIRE(bad.size() >= 30);
  // Not errors: inputs that refer to keyframes not received yet wait for them.
  std::vector<std::function<void()>> waiting;
  {
    waiting.push_back([&producer] { producer.Send(Keyframe(0, 40)); });
    waiting.push_back([&producer] { producer.Send(Loop(200, 3, 999)); });
    loop_hypothesis_t elsewhere = Loop(201, 3, 5);
    elsewhere.session_from = 9;
    waiting.push_back([&producer, elsewhere] { producer.Send(elsewhere); });
  }

  // The bad inputs go in between the valid ones, at the point where the state they test holds
  // (after key 19 was received: a duplicate key 0, a gap to 40, an older stamp for key 20).
  int answered = 0;
  auto errors = [&] { return sink.Decoded<error_t>(ch.error); };
  for (size_t k = 0; k < valid.size(); ++k) {
    valid[k]();
    if (k + 2 != valid.size()) continue;  // after the last keyframe and loop, before END
    for (const BadInput& b : bad) {
      INFO(b.what);
      const size_t before = errors().size();
      b.send(producer);
      const std::vector<error_t> now = errors();
      REQUIRE(now.size() == before + 1);
      const error_t& e = now.back();
      CHECK(e.channel == b.channel);
      CHECK_THAT(e.field, Contains(b.field));
      CHECK_FALSE(e.reason.empty());
      CHECK(e.daemon_id == daemon.daemon_id);
      ++answered;
    }
    for (const auto& send : waiting) send();
    CHECK(errors().size() == bad.size());
    CHECK(service.CurrentStatus().n_parked == static_cast<int>(waiting.size()));
  }
  CHECK(answered == static_cast<int>(bad.size()));
  const status_t status = service.CurrentStatus();
  CHECK(status.n_errors == static_cast<int64_t>(bad.size()));
  CHECK(status.n_undecodable == 6);
  REQUIRE(status.n_senders == 1);
  CHECK(status.senders[0].sender == "robot");
  CHECK(status.senders[0].gaps == 0);  // rejected inputs take their seq: nothing is re-requested
  CHECK(status.senders[0].held == 0);
  CHECK(status.last_error.size() > 0);
  // Every valid input was applied: 20 keys, four loops, all accepted once the session ended.
  REQUIRE(valid_loops == 4);
  CHECK(status.n_keyframes == 20);
  CHECK(status.n_hypotheses == valid_loops);
  CHECK(status.n_accepted == valid_loops);
  CHECK(status.n_rejected == 0);
  const std::vector<HypothesisDecision> decisions = service.Decisions();
  REQUIRE(static_cast<int>(decisions.size()) == valid_loops);
  for (const HypothesisDecision& d : decisions) CHECK(d.decision.state == LoopState::kAccepted);
}

TEST_CASE("A full input queue refuses, then re-requests what it refused: nothing is lost",
          "[daemon]") {
  RecordingSink sink;
  DaemonOptions daemon;
  daemon.limits.queue_limit = 5;
  daemon.resync.interval_ms = 1;
  Service service(daemon, IrrrOptions(), &sink);
  Producer producer(&service, daemon.channels);
  std::vector<std::vector<uint8_t>> sent;
  for (int64_t key = 0; key < 8; ++key) {
    sent.push_back(producer.Stamp(Keyframe(0, key)));
    producer.Raw(daemon.channels.keyframe, sent.back(), /*apply=*/false);
  }
  CHECK(service.QueueDepth() == 5);
  // Key 5 is refused (answered); 6 and 7 wait for it in their sender's order.
  const std::vector<error_t> errors = sink.Decoded<error_t>(daemon.channels.error);
  REQUIRE(errors.size() == 1);
  CHECK_THAT(errors[0].reason, Contains("queue full"));
  CHECK(errors[0].key == 5);
  status_t status = service.CurrentStatus();
  CHECK(status.senders[0].next_seq == 5);
  CHECK(status.senders[0].held == 2);
  CHECK(service.ProcessQueued(std::chrono::milliseconds(0)) == 5);
  // The daemon asks for seq 5 again; the producer resends it; 6 and 7 follow.
  std::this_thread::sleep_for(std::chrono::milliseconds(2));
  service.Tick();
  const std::vector<resync_request_t> requests =
      sink.Decoded<resync_request_t>(daemon.channels.resync);
  REQUIRE(requests.size() == 1);
  CHECK(requests[0].sender == "robot");
  REQUIRE(requests[0].n_ranges == 1);
  CHECK(requests[0].first_seq[0] == 5);
  CHECK(requests[0].last_seq[0] == 5);
  producer.Raw(daemon.channels.keyframe, sent[5]);
  status = service.CurrentStatus();
  CHECK(status.n_keyframes == 8);
  CHECK(status.senders[0].next_seq == 8);
  CHECK(status.senders[0].held == 0);
  CHECK(status.n_errors == 1);
}

TEST_CASE("Under 10% loss, duplicates and reordering the service decides as without them",
          "[reliability][slow]") {
  const Case& c = IntelCase();
  for (uint32_t seed : {1u, 2u}) {
    RecordingSink sink;
    const DaemonOptions daemon = FastResync();
    Service service(daemon, CaseOptions(), &sink);
    LossyProducer producer(&service, &sink, daemon.channels, 0.10, seed);
    for (const ReplayMessage& m : c.messages) {
      producer.Send(m);
      producer.Pump();
    }
    producer.Settle();
    INFO("seed " << seed << ": " << producer.sent << " datagrams, " << producer.lost << " lost, "
                 << producer.requests << " resync requests");
    CHECK(producer.lost > 0.05 * producer.sent);
    CHECK(producer.requests > 0);
    const status_t status = service.CurrentStatus();
    CHECK(status.n_errors == 0);
    REQUIRE(status.n_senders == 1);
    CHECK(status.senders[0].next_seq == static_cast<int64_t>(c.messages.size()));
    CHECK(status.senders[0].gaps > 0);
    CHECK(status.senders[0].duplicates > 0);
    CHECK(status.senders[0].given_up == 0);
    CheckAnswer(service, c, 1e-9);
  }
}

TEST_CASE("The allow-list ignores other senders and robots, and counts them", "[reliability]") {
  RecordingSink sink;
  DaemonOptions daemon;
  daemon.allowed_senders = {"robot3/*", "base"};
  daemon.allowed_robots = {3};
  Service service(daemon, CaseOptions(), &sink);
  auto send = [&](const std::string& sender, int32_t robot, int64_t seq) {
    SendFirstKeyframe(&service, daemon.channels, sender, robot, 0, seq);
  };
  send("robot3/frontend", 3, 0);
  send("intruder", 3, 0);
  send("robot4/frontend", 4, 0);
  send("base", 4, 0);    // an allowed sender naming a robot that is not allowed
  send("robot3", 3, 0);  // "robot3/*" needs the slash
  const status_t status = service.CurrentStatus();
  CHECK(status.n_keyframes == 1);
  CHECK(status.n_ignored == 4);
  CHECK(status.n_errors == 0);
  CHECK(sink.New<error_t>(daemon.channels.error).empty());
}

}  // namespace
}  // namespace irrr
