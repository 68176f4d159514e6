// The service applies inputs to core's Irrr (daemon/service_apply.cc): over memq:// it decides as
// RunIncrementalIrrr, keeps robots' keys apart, and holds inputs that arrive before what they
// refer to until it arrives.

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

double YawDifference(const Pose2& a, const Pose2& b) {
  return std::abs(NormalizeAngle(a.yaw_rad() - b.yaw_rad()));
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
    ApplyQueued(&service);
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
  CHECK(status.variance_factor == Approx(steps.back().variance_factor));
  CHECK(status.variance_estimate == Approx(steps.back().variance_estimate));

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
    ApplyQueued(&service);
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

}  // namespace
}  // namespace irrr
