// The daemon: its configuration, the service in-process over memq:// (same decisions and
// estimate as RunIncrementalIrrr; every kind of bad input answered, nothing valid lost), and,
// hidden behind [udpm] and run inside a private network namespace by tools/netns-run, the
// processes end to end over UDP multicast and through an LCM log.

#include <signal.h>
#include <unistd.h>

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
#include "daemon/raw_subscription.h"
#include "daemon/service.h"
#include "daemon/wire.h"
#include "irrr/correction_t.hpp"
#include "irrr/error_t.hpp"
#include "irrr/resync_request_t.hpp"
#include "irrr/solution_t.hpp"
#include "irrr/verdicts_t.hpp"
#include "tests/processes.h"
#include "tests/recording_sink.h"
#include "tests/test_files.h"

namespace irrr {
namespace {

using Catch::Matchers::Contains;

// The service logs every rejection; the tests check the error channel instead.
const bool kQuiet = [] {
  spdlog::set_level(spdlog::level::off);
  return true;
}();

// ---- Configuration ----

TEST_CASE("config/irrrd.json holds every daemon default and parses", "[daemon][config]") {
  nlohmann::json config;
  REQUIRE(LoadConfigFile(IRRR_SOURCE_DIR "/config/irrrd.json", &config).ok());
  DaemonOptions daemon;
  daemon.daemon_id = "marker";
  IrrrOptions options;
  const Status status = ParseDaemonConfig(config, &daemon, &options);
  INFO(status.message());
  REQUIRE(status.ok());
  CHECK(DaemonOptionsToJson(daemon) == DaemonOptionsToJson(DaemonOptions()));
  CHECK(config["daemon"] == DaemonOptionsToJson(DaemonOptions()));
  CHECK(IrrrOptionsToJson(options) == IrrrOptionsToJson(IrrrOptions()));
}

TEST_CASE("Daemon configuration errors name the key", "[daemon][config]") {
  auto error = [](const std::string& text) {
    DaemonOptions daemon;
    IrrrOptions options;
    const Status s = ParseDaemonConfig(nlohmann::json::parse(text), &daemon, &options);
    REQUIRE_FALSE(s.ok());
    CHECK(daemon.daemon_id == DaemonOptions().daemon_id);  // untouched
    return s.message();
  };
  CHECK_THAT(error(R"({"deamon": {}})"), Contains("deamon: unknown key"));
  CHECK_THAT(error(R"({"daemon": {"status_hz": "fast"}})"),
             Contains("daemon.status_hz: expected a number"));
  CHECK_THAT(error(R"({"daemon": {"channels": {"keyframes": "X"}}})"),
             Contains("daemon.channels.keyframes: unknown key"));
  CHECK_THAT(error(R"({"daemon": {"limits": {"queue_limit": 0}}})"), Contains("daemon.limits"));
  CHECK_THAT(error(R"({"daemon": {"log_level": "loud"}})"), Contains("daemon.log_level"));
  CHECK_THAT(error(R"({"daemon": {"threads": -1}})"), Contains("daemon.threads"));
  CHECK_THAT(error(R"({"daemon": {"channels": {"loop": "IRRR_KEYFRAME"}}})"),
             Contains("used by another channel"));
  CHECK_THAT(error(R"({"irrr": {"alpha": 2}})"), Contains("irrr"));
  CHECK_THAT(error(R"({"irrr": {"cluster_gap": "ten"}})"), Contains("irrr.cluster_gap"));
}

// ---- The service in-process ----

// Publishes into one memq:// LCM instance (the only kind that sees its own messages).
class LcmSink : public MessageSink {
 public:
  explicit LcmSink(lcm::LCM* lcm) : lcm_(lcm) {}
  void Send(const std::string& channel, const std::vector<uint8_t>& bytes) override {
    REQUIRE(lcm_->publish(channel, bytes.data(), static_cast<unsigned>(bytes.size())) == 0);
  }

 private:
  lcm::LCM* lcm_;
};

struct ServiceReceiver {
  Service* service;
  std::map<std::string, int> heard;
  int step_corrections = 0;
  void OnMessage(const lcm::ReceiveBuffer* b, const std::string& channel) {
    ++heard[channel];
    correction_t c;
    if (channel == "IRRR_CORRECTION" && c.decode(b->data, 0, static_cast<int>(b->data_size)) > 0) {
      step_corrections += c.step >= 0 ? 1 : 0;
    }
    service->Receive(channel, static_cast<const uint8_t*>(b->data), static_cast<int>(b->data_size));
  }
};

IrrrOptions TestOptions() {
  IrrrOptions options;
  options.cluster_gap = 10.0;
  return options;
}

TEST_CASE("Over memq://, the service decides as RunIncrementalIrrr and merges the sessions",
          "[daemon]") {
  const std::string dir = TestDirectory("daemon_memq");
  const std::string path = MakeTwoSessionIntel(dir);
  GraphFile<Pose2> file;
  PoseGraph<Pose2> graph;
  std::vector<int> graph_edge_of_file_edge;
  REQUIRE(
      LoadPoseGraph(path, FileFormat::kG2o, ReadOptions(), &file, &graph, &graph_edge_of_file_edge)
          .ok());
  REQUIRE(graph.num_sessions() == 2);
  const IrrrOptions options = TestOptions();
  std::vector<Pose2> expected_estimate;
  std::vector<StepResult> steps;
  const std::vector<LoopDecision> expected =
      RunIncrementalIrrr(graph, options, &expected_estimate, &steps);

  lcm::LCM lcm("memq://");
  REQUIRE(lcm.good());
  LcmSink sink(&lcm);
  DaemonOptions daemon;
  Service service(daemon, options, &sink);
  ServiceReceiver receiver{&service, {}};
  std::vector<std::unique_ptr<RawSubscription>> subscriptions;
  for (const std::string& channel : {daemon.channels.keyframe,
                                     daemon.channels.loop,
                                     daemon.channels.session,
                                     daemon.channels.correction,
                                     daemon.channels.error}) {
    subscriptions.push_back(std::make_unique<RawSubscription>(
        &lcm,
        channel,
        [&receiver](const lcm::ReceiveBuffer& b, const std::string& c) {
          receiver.OnMessage(&b, c);
        },
        100000));
  }
  std::vector<ReplayMessage> messages = ReplayMessages(graph, graph_edge_of_file_edge, 0);
  messages.push_back(FlushMessage());
  MessageSequencer sequencer("test", daemon.channels);
  for (const ReplayMessage& m : messages) {
    const auto [channel, bytes] = sequencer.Encode(m, NowUtime());
    REQUIRE(lcm.publish(channel, bytes.data(), static_cast<unsigned>(bytes.size())) == 0);
    while (lcm.handleTimeout(0) > 0) {
    }
    // Apply as the worker would, in arrival order (its corrections land in the memq queue).
    service.ProcessQueued(std::chrono::milliseconds(0));
  }
  while (lcm.handleTimeout(0) > 0) {
  }
  CHECK(service.QueueDepth() == 0);
  CHECK(receiver.heard[daemon.channels.error] == 0);
  CHECK(receiver.step_corrections == static_cast<int>(steps.size()));
  CHECK(receiver.heard[daemon.channels.correction] > receiver.step_corrections);  // + full ones
  const status_t status = service.CurrentStatus();
  CHECK(status.n_errors == 0);
  CHECK(status.n_keyframes == graph.num_vertices());
  CHECK(status.n_steps == static_cast<int64_t>(steps.size()));
  CHECK(status.n_components == 1);  // the two sessions were merged

  // Decisions: hypothesis id = file edge index.
  const std::vector<HypothesisDecision> decisions = service.Decisions();
  int loops = 0;
  for (const Edge<Pose2>& e : graph.edges()) loops += e.kind == EdgeKind::kLoop ? 1 : 0;
  REQUIRE(static_cast<int>(decisions.size()) == loops);
  int accepted = 0;
  for (const HypothesisDecision& d : decisions) {
    const LoopDecision& want = expected[graph_edge_of_file_edge[d.hypothesis_id]];
    INFO("hypothesis " << d.hypothesis_id);
    CHECK(d.decision.state == want.state);
    CHECK(d.decision.cluster == want.cluster);
    CHECK(d.decision.step == want.step);
    if (!std::isnan(want.chi2)) CHECK(d.decision.chi2 == Approx(want.chi2).epsilon(1e-9));
    accepted += d.decision.state == LoopState::kAccepted ? 1 : 0;
  }
  CHECK(accepted > loops / 2);

  // Estimates: key = file vertex id.
  double worst = 0.0;
  int poses = 0;
  for (const Service::SessionEstimate& s : service.Estimates()) {
    for (size_t k = 0; k < s.poses.size(); ++k) {
      Pose2 got;
      REQUIRE(PoseFromWire(s.poses[k], "pose", &got).ok());
      const Pose2& want = expected_estimate[graph.FindVertex(s.first_key + k)];
      worst = std::max(
          {worst, (got.translation() - want.translation()).norm(), YawDifference(got, want)});
      ++poses;
    }
  }
  CHECK(poses == graph.num_vertices());
  CHECK(worst < 1e-6);
}

TEST_CASE("Two files injected as two robots keep their keys apart and their own decisions",
          "[daemon]") {
  // Both files number their poses from 0: only (robot, session, key) tells them apart.
  const std::string dir = TestDirectory("daemon_two_robots");
  const int sizes[2] = {250, 300};
  std::vector<std::vector<ReplayMessage>> robots;
  std::vector<PoseGraph<Pose2>> graphs(2);
  std::vector<std::vector<int>> graph_edge_of_file_edge(2);
  const IrrrOptions options = TestOptions();
  std::vector<std::vector<LoopDecision>> expected(2);
  std::vector<std::vector<Pose2>> expected_estimate(2);
  for (int r = 0; r < 2; ++r) {
    const std::string path = dir + "/intel" + std::to_string(sizes[r]) + ".g2o";
    WriteIntelPrefix(sizes[r], path);
    GraphFile<Pose2> file;
    REQUIRE(
        LoadPoseGraph(
            path, FileFormat::kG2o, ReadOptions(), &file, &graphs[r], &graph_edge_of_file_edge[r])
            .ok());
    expected[r] = RunIncrementalIrrr(graphs[r], options, &expected_estimate[r], nullptr);
    robots.push_back(ReplayMessages(graphs[r], graph_edge_of_file_edge[r], /*robot_id=*/r));
  }
  std::vector<ReplayMessage> messages = MergeByStamp(robots);
  REQUIRE(messages.size() == robots[0].size() + robots[1].size());
  // Merged by stamp: robot 0's key k comes before robot 1's key k + 1.
  CHECK(messages[0].keyframe.robot_id == 0);
  CHECK(messages[1].keyframe.robot_id == 1);
  messages.push_back(FlushMessage());

  RecordingSink sink;
  DaemonOptions daemon;
  Service service(daemon, options, &sink);
  SenderFleet fleet("inject", daemon.channels, /*first_robot=*/0, /*num_robots=*/2);
  CHECK(fleet.names() == std::vector<std::string>{"inject/robot0", "inject/robot1"});
  for (const ReplayMessage& m : messages) {
    const auto [channel, bytes] = fleet.Encode(m, NowUtime());
    service.Receive(channel, bytes.data(), static_cast<int>(bytes.size()));
    service.ProcessQueued(std::chrono::milliseconds(0));
  }
  const status_t status = service.CurrentStatus();
  const std::vector<error_t> errors = sink.Decoded<error_t>(daemon.channels.error);
  INFO((errors.empty() ? std::string() : errors[0].field + ": " + errors[0].reason));
  CHECK(status.n_errors == 0);
  CHECK(status.n_sessions == 2);
  CHECK(status.n_components == 2);  // no loop joins the robots
  CHECK(status.n_keyframes == sizes[0] + sizes[1]);

  // Decisions come back in arrival order; both robots' hypothesis ids are file edge indices,
  // told apart by the robot of their ends.
  std::vector<HypothesisDecision> decisions = service.Decisions();
  int checked = 0;
  size_t next[2] = {0, 0};
  std::vector<std::vector<int>> loops_in_arrival_order(2);
  for (const ReplayMessage& m : messages) {
    if (m.kind == ReplayMessage::Kind::kLoop) {
      loops_in_arrival_order[m.loop.robot_from].push_back(static_cast<int>(m.loop.hypothesis_id));
    }
  }
  for (const ReplayMessage& m : messages) {
    if (m.kind != ReplayMessage::Kind::kLoop) continue;
    const int r = m.loop.robot_from;
    const HypothesisDecision& d = decisions[checked];
    REQUIRE(d.hypothesis_id == loops_in_arrival_order[r][next[r]++]);
    const LoopDecision& want = expected[r][graph_edge_of_file_edge[r][d.hypothesis_id]];
    INFO("robot " << r << ", hypothesis " << d.hypothesis_id);
    CHECK(d.decision.state == want.state);
    ++checked;
  }
  CHECK(checked == static_cast<int>(decisions.size()));

  double worst = 0.0;
  for (const Service::SessionEstimate& e : service.Estimates()) {
    const int r = e.robot_id;
    for (size_t k = 0; k < e.poses.size(); ++k) {
      Pose2 got;
      REQUIRE(PoseFromWire(e.poses[k], "pose", &got).ok());
      const Pose2& want = expected_estimate[r][graphs[r].FindVertex(e.first_key + k)];
      worst = std::max(
          {worst, (got.translation() - want.translation()).norm(), YawDifference(got, want)});
    }
  }
  CHECK(worst < 1e-6);
}

// ---- Bad input ----

keyframe_t Keyframe(int32_t session, int64_t key) {
  keyframe_t k{};
  k.header = {0, key, "robot"};
  k.robot_id = 0;
  k.session_id = session;
  k.key = key;
  k.stamp_utime = key * 1000000;
  k.dim = keyframe_t::DIM_SE2;
  k.odom_pose = PoseToWire(Pose2(key, 0.0, 0.0));
  k.has_odom_edge = key > 0;
  k.odom_delta = PoseToWire(Pose2(1.0, 0.0, 0.0));
  InformationToWire<Pose2>(Pose2::Matrix::Identity() * 100.0, k.information);
  return k;
}

loop_hypothesis_t Loop(int64_t id, int64_t from, int64_t to) {
  loop_hypothesis_t l{};
  l.header = {0, id, "robot"};
  l.hypothesis_id = id;
  l.key_from = from;
  l.key_to = to;
  l.dim = keyframe_t::DIM_SE2;
  l.measurement = PoseToWire(Pose2(static_cast<double>(to - from), 0.0, 0.0));
  InformationToWire<Pose2>(Pose2::Matrix::Identity() * 100.0, l.information);
  l.score = 1.0f;
  return l;
}

// Sends messages into a service as producers would: header.seq counts from 0 per sender, over
// all its channels.
class Producer {
 public:
  Producer(Service* service, DaemonChannels channels)
      : service_(service), channels_(std::move(channels)) {}

  template <class Message>
  std::vector<uint8_t> Stamp(Message m) {
    m.header.seq = next_[m.header.sender]++;
    return EncodeMessage(m);
  }
  // Sends and, with `apply`, lets the worker apply it at once.
  template <class Message>
  void Send(const Message& m, bool apply = true) {
    Raw(ChannelOf(m), Stamp(m), apply);
  }
  // Bytes as they are (not stamped).
  void Raw(const std::string& channel, const std::vector<uint8_t>& bytes, bool apply = true) {
    service_->Receive(channel, bytes.data(), static_cast<int>(bytes.size()));
    if (apply) service_->ProcessQueued(std::chrono::milliseconds(0));
  }
  std::string ChannelOf(const keyframe_t&) const { return channels_.keyframe; }
  std::string ChannelOf(const loop_hypothesis_t&) const { return channels_.loop; }
  std::string ChannelOf(const session_event_t&) const { return channels_.session; }

 private:
  Service* service_;
  DaemonChannels channels_;
  std::map<std::string, int64_t> next_;
};

session_event_t SessionEvent(int8_t event, int32_t session = 0) {
  session_event_t e{};
  e.header = {0, 0, "robot"};
  e.event = event;
  e.session_id = session;
  e.last_key = -1;
  e.last_hypothesis_id = -1;
  return e;
}

struct BadInput {
  const char* what;
  std::string channel;
  std::function<void(Producer&)> send;
  const char* field;  // expected error_t.field
};

// The Intel two-session case as a fleet: session 0 is robot 1's, session 1 robot 2's.
struct FleetCase {
  PoseGraph<Pose2> graph;
  std::vector<int> graph_edge_of_file_edge;
  std::vector<ReplayMessage> all;       // both robots, in the file's arrival order
  std::vector<ReplayMessage> robot[3];  // what robot 1 and robot 2 each send
  std::string labels;                   // irrr-corrupt's labels of the wrong loops
};

FleetCase MakeFleetCase(const std::string& dir) {
  FleetCase c;
  GraphFile<Pose2> file;
  REQUIRE(LoadPoseGraph(MakeTwoSessionIntel(dir),
                        FileFormat::kG2o,
                        ReadOptions(),
                        &file,
                        &c.graph,
                        &c.graph_edge_of_file_edge)
              .ok());
  REQUIRE(c.graph.num_sessions() == 2);
  c.labels = dir + "/labels.csv";
  c.all = ReplayMessages(c.graph, c.graph_edge_of_file_edge, 0);
  const std::vector<int32_t> robot_of_session = {1, 2};
  for (int32_t r : {1, 2}) {
    c.robot[r] = c.all;
    REQUIRE(AssignRobots(robot_of_session, r, &c.robot[r]));
  }
  REQUIRE(AssignRobots(robot_of_session, -1, &c.all));
  return c;
}

// Feeds `messages` (each robot its own sender) to a new service; returns its estimate.
std::vector<Service::SessionEstimate> RunFleet(const std::vector<ReplayMessage>& messages,
                                               const DaemonOptions& daemon,
                                               std::vector<HypothesisDecision>* decisions,
                                               status_t* status) {
  RecordingSink sink;
  Service service(daemon, TestOptions(), &sink);
  SenderFleet fleet("robot", daemon.channels, /*first_robot=*/1, /*num_robots=*/2);
  for (const ReplayMessage& m : messages) {
    const auto [channel, bytes] = fleet.Encode(m, NowUtime());
    service.Receive(channel, bytes.data(), static_cast<int>(bytes.size()));
    service.ProcessQueued(std::chrono::milliseconds(0));
  }
  *decisions = service.Decisions();
  *status = service.CurrentStatus();
  return service.Estimates();
}

TEST_CASE(
    "A fleet in one file: each robot sends its part, and the map frame does not depend on "
    "who was heard first",
    "[daemon]") {
  const FleetCase c = MakeFleetCase(TestDirectory("daemon_fleet"));
  // Every message is sent by exactly one robot: keyframes and END by their session's robot,
  // a loop by the robot of its later pose.
  REQUIRE(c.robot[1].size() + c.robot[2].size() == c.all.size());
  int inter_robot = 0;
  for (int32_t r : {1, 2}) {
    for (const ReplayMessage& m : c.robot[r]) {
      CHECK(m.sender_robot == r);
      if (m.kind == ReplayMessage::Kind::kKeyframe) CHECK(m.keyframe.robot_id == r);
      if (m.kind != ReplayMessage::Kind::kLoop) continue;
      const loop_hypothesis_t& l = m.loop;
      const int later = std::max(c.graph.FindVertex(l.key_from), c.graph.FindVertex(l.key_to));
      CHECK(c.graph.vertex(later).session + 1 == r);
      inter_robot += l.robot_from != l.robot_to ? 1 : 0;
    }
  }
  CHECK(inter_robot > 30);  // the true and the wrong inter-session loops

  // Robot 1 heard first, then robot 2 (whose loops to robot 1 wait for nothing); and robot 2
  // heard first (its loops to robot 1 wait for robot 1's keyframes). Both end in one map in
  // the frame of robot 1's session, the earliest by stamp, whoever was heard first.
  std::vector<ReplayMessage> one_then_two = c.robot[1];
  one_then_two.insert(one_then_two.end(), c.robot[2].begin(), c.robot[2].end());
  std::vector<ReplayMessage> two_then_one = c.robot[2];
  two_then_one.insert(two_then_one.end(), c.robot[1].begin(), c.robot[1].end());
  std::vector<HypothesisDecision> decisions[2];
  status_t status[2];
  const std::vector<Service::SessionEstimate> first =
      RunFleet(one_then_two, DaemonOptions(), &decisions[0], &status[0]);
  const std::vector<Service::SessionEstimate> second =
      RunFleet(two_then_one, DaemonOptions(), &decisions[1], &status[1]);
  for (int k = 0; k < 2; ++k) {
    INFO("order " << k);
    CHECK(status[k].n_errors == 0);
    CHECK(status[k].n_components == 1);
    CHECK(status[k].n_parked == 0);
  }
  auto pose_of = [](const std::vector<Service::SessionEstimate>& estimate, int32_t robot, int k) {
    for (const Service::SessionEstimate& e : estimate) {
      if (e.robot_id != robot) continue;
      Pose2 p;
      REQUIRE(PoseFromWire(e.poses[static_cast<size_t>(k)], "pose", &p).ok());
      return p;
    }
    FAIL("robot " << robot << " has no session");
    return Pose2();
  };
  for (const auto* estimate : {&first, &second}) {
    const Pose2 anchor = pose_of(*estimate, 1, 0);
    CHECK(anchor.translation().norm() < 1e-9);
    CHECK(std::abs(anchor.yaw_rad()) < 1e-9);
  }
  // Neither order trusts a wrong loop. Decisions on a few true loops depend on the order
  // (clusters close at other times): the rule for daemons that hear different orders
  // (README, "Fleets"); the maps agree to a few centimetres.
  std::ifstream labels_in(c.labels);
  std::vector<LabelRow> labels;
  REQUIRE(ReadLabelsCsv(labels_in, &labels).ok());
  std::map<int64_t, bool> outlier;
  for (const LabelRow& row : labels) outlier[row.edge_index] = row.outlier;
  std::map<int64_t, LoopState> state_first;
  for (const HypothesisDecision& d : decisions[0]) state_first[d.hypothesis_id] = d.decision.state;
  int same = 0;
  for (int k = 0; k < 2; ++k) {
    for (const HypothesisDecision& d : decisions[k]) {
      CHECK(!(outlier.at(d.hypothesis_id) && d.decision.state == LoopState::kAccepted));
      if (k == 1) same += state_first.at(d.hypothesis_id) == d.decision.state ? 1 : 0;
    }
  }
  INFO(same << " of " << decisions[1].size() << " decisions the same in both orders");
  CHECK(same > static_cast<int>(decisions[1].size()) * 9 / 10);
  const Pose2 end_first = pose_of(first, 2, 199);
  const Pose2 end_second = pose_of(second, 2, 199);
  CHECK((end_first.translation() - end_second.translation()).norm() < 0.1);

  // With daemon.merge both orders are applied by stamp: the file's own order, so both decide
  // exactly as RunIncrementalIrrr on the file, pose for pose.
  DaemonOptions merged;
  merged.merge.window_ms = 60000;
  merged.merge.senders = {"robot/robot1", "robot/robot2"};
  std::vector<Pose2> expected_estimate;
  const std::vector<LoopDecision> expected =
      RunIncrementalIrrr(c.graph, TestOptions(), &expected_estimate, nullptr);
  for (const auto* order : {&one_then_two, &two_then_one}) {
    std::vector<HypothesisDecision> got;
    status_t got_status;
    const std::vector<Service::SessionEstimate> estimate =
        RunFleet(*order, merged, &got, &got_status);
    CHECK(got_status.n_errors == 0);
    CHECK(got_status.queue_depth == 0);
    REQUIRE(got.size() == decisions[0].size());
    for (const HypothesisDecision& d : got) {
      const LoopDecision& want = expected[c.graph_edge_of_file_edge[d.hypothesis_id]];
      INFO("hypothesis " << d.hypothesis_id);
      CHECK(d.decision.state == want.state);
      CHECK(d.decision.step == want.step);
    }
    double worst = 0.0;
    for (const Service::SessionEstimate& e : estimate) {
      for (size_t k = 0; k < e.poses.size(); ++k) {
        Pose2 p;
        REQUIRE(PoseFromWire(e.poses[k], "pose", &p).ok());
        const Pose2& want = expected_estimate[c.graph.FindVertex(e.first_key + k)];
        worst = std::max(worst, (p.translation() - want.translation()).norm());
      }
    }
    CHECK(worst < 1e-6);
  }
}

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

TEST_CASE("Inputs that arrive before what they refer to wait for it, then apply in order",
          "[daemon]") {
  // In order: keys 0..19, a loop 5 -> 12 right after key 12, END. Out of order: keys 0..9, the
  // loop, keys 11..19, then key 10 (as a resend after a loss would bring it), END.
  auto run = [](const std::vector<std::pair<int, int64_t>>& order, status_t* status) {
    RecordingSink sink;
    DaemonOptions daemon;
    IrrrOptions options;
    options.cluster_gap = 3.0;
    Service service(daemon, options, &sink);
    Producer producer(&service, daemon.channels);
    for (const auto& [kind, value] : order) {
      if (kind == 0) {
        producer.Send(Keyframe(0, value));
      } else if (kind == 1) {
        loop_hypothesis_t l = Loop(7, 5, 12);
        l.measurement = PoseToWire(Pose2(7.05, 0.02, 0.01));  // a little noise: a real fit
        producer.Send(l);
      } else {
        producer.Send(SessionEvent(session_event_t::END));
      }
    }
    *status = service.CurrentStatus();
    std::vector<Pose2> poses;
    const std::vector<Service::SessionEstimate> estimates = service.Estimates();
    REQUIRE(estimates.size() == 1);
    for (const pose_t& p : estimates[0].poses) {
      Pose2 pose;
      REQUIRE(PoseFromWire(p, "pose", &pose).ok());
      poses.push_back(pose);
    }
    const std::vector<HypothesisDecision> decisions = service.Decisions();
    REQUIRE(decisions.size() == 1);
    return std::make_pair(decisions[0].decision, poses);
  };
  std::vector<std::pair<int, int64_t>> in_order;
  for (int64_t key = 0; key < 20; ++key) {
    in_order.push_back({0, key});
    if (key == 12) in_order.push_back({1, 0});
  }
  in_order.push_back({2, 0});
  std::vector<std::pair<int, int64_t>> out_of_order;
  for (int64_t key = 0; key < 10; ++key) out_of_order.push_back({0, key});
  out_of_order.push_back({1, 0});
  for (int64_t key = 11; key < 20; ++key) out_of_order.push_back({0, key});
  out_of_order.push_back({0, 10});
  out_of_order.push_back({2, 0});

  status_t in_order_status{};
  status_t out_of_order_status{};
  const auto [want, want_poses] = run(in_order, &in_order_status);
  const auto [got, got_poses] = run(out_of_order, &out_of_order_status);
  CHECK(want.state == LoopState::kAccepted);
  CHECK(got.state == want.state);
  CHECK(got.cluster == want.cluster);
  CHECK(got.step == want.step);
  CHECK(got.chi2 == want.chi2);
  REQUIRE(got_poses.size() == 20);
  REQUIRE(want_poses.size() == 20);
  for (size_t k = 0; k < 20; ++k) {
    CHECK(got_poses[k].translation().x() == want_poses[k].translation().x());
    CHECK(got_poses[k].yaw_rad() == want_poses[k].yaw_rad());
  }
  CHECK(out_of_order_status.n_errors == 0);
  CHECK(out_of_order_status.n_parked == 0);  // all released
  CHECK(out_of_order_status.n_keyframes == 20);
}

TEST_CASE("Waiting inputs are bounded by limits.max_parked", "[daemon]") {
  RecordingSink sink;
  DaemonOptions daemon;
  daemon.limits.max_parked = 2;
  Service service(daemon, IrrrOptions(), &sink);
  Producer producer(&service, daemon.channels);
  for (int64_t key : {0, 5, 6, 7}) producer.Send(Keyframe(0, key));
  CHECK(service.CurrentStatus().n_parked == 2);
  const std::vector<error_t> errors = sink.Decoded<error_t>(daemon.channels.error);
  REQUIRE(errors.size() == 1);
  CHECK(errors[0].key == 7);
  CHECK_THAT(errors[0].reason, Contains("max_parked"));
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

TEST_CASE("Corrections carry map-to-odometry transforms and every pose in chunks", "[daemon]") {
  // One session of 2000 keys (three pose chunks), odometry frame offset from the map frame.
  RecordingSink sink;
  DaemonOptions daemon;
  IrrrOptions options;
  options.cluster_gap = 5.0;
  Service service(daemon, options, &sink);
  Producer producer(&service, daemon.channels);
  const int kKeys = 2000;
  for (int64_t key = 0; key < kKeys; ++key) {
    keyframe_t k = Keyframe(4, key);
    k.robot_id = 2;
    k.odom_pose = PoseToWire(Pose2(10.0 + key, 5.0, 0.0));  // odometry frame: origin at (10, 5)
    producer.Send(k, /*apply=*/false);
  }
  loop_hypothesis_t l = Loop(1, 1990, 1995);
  l.robot_from = l.robot_to = 2;
  l.session_from = l.session_to = 4;
  producer.Send(l, /*apply=*/false);
  producer.Send(SessionEvent(session_event_t::FLUSH));

  // The step's correction (decisions, transforms), then a full one (poses), as the worker
  // caught up with its input.
  const std::vector<correction_t> corrections =
      sink.Decoded<correction_t>(daemon.channels.correction);
  REQUIRE(corrections.size() == 2);
  const correction_t& step = corrections[0];
  CHECK(step.solution_id == 1);
  CHECK(step.step == 0);
  CHECK(step.n_pose_chunks == 0);
  CHECK(step.n_verdict_chunks == 1);
  CHECK(step.closed_utime <= step.published_utime);
  const correction_t& c = corrections[1];
  CHECK(c.solution_id == 2);
  CHECK(c.step == -1);
  for (const correction_t* each : {&step, &c}) {
    REQUIRE(each->n_sessions == 1);
    CHECK(each->sessions[0].robot_id == 2);
    CHECK(each->sessions[0].session_id == 4);
    CHECK(each->sessions[0].latest_key == kKeys - 1);
    // The map frame is that of the first pose: map_T_odom = identity x odom(0)^-1.
    Pose2 map_T_odom;
    REQUIRE(PoseFromWire(each->sessions[0].map_T_odom, "map_T_odom", &map_T_odom).ok());
    CHECK(map_T_odom.translation().x() == Approx(-10.0).margin(1e-9));
    CHECK(map_T_odom.translation().y() == Approx(-5.0).margin(1e-9));
  }

  const std::vector<solution_t> chunks = sink.Decoded<solution_t>(daemon.channels.solution);
  REQUIRE(static_cast<int>(chunks.size()) == c.n_pose_chunks);
  CHECK(c.n_pose_chunks == (kKeys + solution_t::MAX_POSES - 1) / solution_t::MAX_POSES);
  int64_t next_key = 0;
  for (size_t k = 0; k < chunks.size(); ++k) {
    CHECK(chunks[k].chunk_index == static_cast<int>(k));
    CHECK(chunks[k].solution_id == c.solution_id);
    CHECK(chunks[k].first_key == next_key);
    CHECK(EncodeMessage(chunks[k]).size() < 65000);  // one UDP datagram
    for (int i = 0; i < chunks[k].n_poses; ++i) {
      CHECK(chunks[k].poses[i].t[0] == Approx(static_cast<double>(next_key + i)).margin(1e-6));
    }
    next_key += chunks[k].n_poses;
  }
  CHECK(next_key == kKeys);
  const std::vector<verdicts_t> verdicts = sink.Decoded<verdicts_t>(daemon.channels.verdicts);
  REQUIRE(verdicts.size() == 1);  // the step's; the full correction found nothing new
  CHECK(verdicts[0].solution_id == step.solution_id);
  REQUIRE(verdicts[0].n_verdicts == 1);
  CHECK(verdicts[0].verdicts[0].state == verdict_t::ACCEPTED);
  CHECK(verdicts[0].verdicts[0].hypothesis_id == 1);
  CHECK(verdicts[0].verdicts[0].sender == "robot");
}

// ---- Processes end to end (inside a private network namespace: tools/netns-run) ----

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
