// What the service publishes (daemon/service_publish.cc): corrections with map-to-odometry
// transforms and poses in chunks, in a map frame that does not depend on arrival order, and the
// whole solution to a consumer that asks.

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
    ApplyQueued(&service);
  }
  *decisions = service.Decisions();
  *status = service.CurrentStatus();
  return service.Estimates();
}

TEST_CASE(
    "A fleet in one file: each robot sends its part, and the map frame does not depend on "
    "who was heard first",
    "[daemon][slow]") {
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
  // (docs/fleets.md); the maps agree to a few centimetres.
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

TEST_CASE("A consumer's solution request is answered with every pose and every verdict",
          "[reliability]") {
  const Case& c = IntelCase();
  RecordingSink sink;
  const DaemonOptions daemon = FastResync();
  Service service(daemon, CaseOptions(), &sink);
  MessageSequencer producer("robot", daemon.channels);
  for (const ReplayMessage& m : c.messages) {
    const auto [channel, bytes] = producer.Encode(m, NowUtime());
    service.Receive(channel, bytes.data(), static_cast<int>(bytes.size()));
  }
  ApplyQueued(&service);
  sink.New<correction_t>(daemon.channels.correction);
  sink.New<verdicts_t>(daemon.channels.verdicts);
  sink.New<solution_t>(daemon.channels.solution);

  solution_request_t request{};
  request.header = {0, 0, "late-listener"};
  request.reason = "test";
  const std::vector<uint8_t> bytes = EncodeMessage(request);
  service.Receive(daemon.channels.solution_request, bytes.data(), static_cast<int>(bytes.size()));
  ApplyQueued(&service);
  const std::vector<correction_t> corrections = sink.New<correction_t>(daemon.channels.correction);
  REQUIRE(corrections.size() == 1);
  const correction_t& complete = corrections[0];
  CHECK(complete.complete == 1);
  CHECK(complete.n_sessions == c.graph.num_sessions());
  int verdicts = 0;
  for (const verdicts_t& chunk : sink.New<verdicts_t>(daemon.channels.verdicts)) {
    CHECK(chunk.solution_id == complete.solution_id);
    verdicts += chunk.n_verdicts;
  }
  CHECK(verdicts == static_cast<int>(service.Decisions().size()));
  int poses = 0;
  for (const solution_t& chunk : sink.New<solution_t>(daemon.channels.solution)) {
    CHECK(chunk.solution_id == complete.solution_id);
    poses += chunk.n_poses;
  }
  CHECK(poses == c.graph.num_vertices());
}

}  // namespace
}  // namespace irrr
