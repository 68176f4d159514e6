// Snapshot bodies (daemon/snapshot.h): read back as written, any cut refused; an Irrr's inputs as a
// base holds them rebuild it.

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
#include "tests/corrupted_graph.h"
#include "tests/recording_sink.h"
#include "tests/service_helpers.h"
#include "tests/test_files.h"

namespace irrr {
namespace {

using Catch::Matchers::Contains;
using Clock = std::chrono::steady_clock;
using testing::SyntheticOptions;

TEST_CASE("A snapshot body reads back as written, and any cut of it is refused", "[reliability]") {
  IrrrStepState<Pose3> state;
  state.decisions.resize(3);
  state.decisions[1] = {0, LoopState::kReversed, 4, 12.5, 12.59};
  state.estimate = {Pose3(), Pose3::Exp((Pose3::Tangent() << 1, 2, 3, 0.1, -0.2, 0.3).finished())};
  state.clusters.resize(2);
  state.clusters[0].links = {1, 2};
  state.clusters[0].session_a = 1;
  state.clusters[0].in_good = true;
  state.clusters[0].redundancy_chi2 = 3.5;
  state.clusters[0].redundancy_dof = 6.0;
  state.clusters[0].accepted_variance = 0.16;
  state.clusters[0].checked_links = 42;
  state.clusters[0].checked_variance = 0.18;
  state.clusters[1].opponents = {0};
  state.clusters[1].in_reject = true;
  state.clusters[1].refused_variance = 0.27;
  state.cluster_of = {0, 1};
  state.steps = 7;
  state.judged = 2;
  state.weakened_odometry = {0};
  SnapshotWriter w;
  w.String("options");
  w.StepState(state);
  const std::vector<uint8_t> body = w.bytes();

  SnapshotReader r(body);
  std::string text;
  IrrrStepState<Pose3> back;
  REQUIRE(r.String(&text));
  REQUIRE(r.StepState(&back));
  CHECK(r.at_end());
  CHECK(text == "options");
  REQUIRE(back.decisions.size() == 3);
  CHECK(back.decisions[1].state == LoopState::kReversed);
  CHECK(back.decisions[1].threshold == 12.59);
  CHECK(std::isnan(back.decisions[0].chi2));
  REQUIRE(back.estimate.size() == 2);
  CHECK(back.estimate[1].translation() == state.estimate[1].translation());
  CHECK(back.estimate[1].quaternion().coeffs() == state.estimate[1].quaternion().coeffs());
  CHECK(back.clusters[0].links == std::vector<int>{1, 2});
  CHECK((back.clusters[0].in_good && !back.clusters[0].in_r && back.clusters[1].in_reject));
  CHECK(back.clusters[1].opponents == std::vector<int>{0});
  CHECK((back.clusters[0].redundancy_chi2 == 3.5 && back.clusters[0].redundancy_dof == 6.0));
  CHECK(back.clusters[0].accepted_variance == 0.16);
  CHECK((back.clusters[0].checked_links == 42 && back.clusters[0].checked_variance == 0.18));
  CHECK(back.clusters[0].refused_variance == 0.0);
  CHECK(back.clusters[1].refused_variance == 0.27);
  CHECK((back.steps == 7 && back.judged == 2 && back.cluster_of == state.cluster_of));
  CHECK(back.weakened_odometry == std::vector<int>{0});

  for (size_t cut = 0; cut < body.size(); ++cut) {
    const std::vector<uint8_t> part(body.begin(), body.begin() + static_cast<long>(cut));
    SnapshotReader partial(part);
    IrrrStepState<Pose3> ignored;
    const bool ok = partial.String(&text) && partial.StepState(&ignored) && partial.at_end();
    CHECK(!ok);
  }
}

// An Irrr that has decided a world with wrong loops in groups (splits, reversals), restarted from
// its step state with one more odometry edge weakened (as a snapshot of an engine that had found
// it faulty gives it back): the information it was given differs from its graph's.
template <class Pose>
std::unique_ptr<Irrr<Pose>> WeakenedRun() {
  SyntheticOptions synthetic = testing::NoisyWorld<Pose>(3);
  synthetic.num_sessions = 2;
  OutlierOptions outliers;
  outliers.mode = OutlierMode::kLocalGrouped;
  outliers.count = 30;
  outliers.seed = 3;
  const PoseGraph<Pose> graph = testing::MakeCorrupted<Pose>(synthetic, outliers).graph;
  Irrr<Pose> decided{IrrrOptions()};
  auto restarted = std::make_unique<Irrr<Pose>>(IrrrOptions());
  GraphReplay<Pose> decided_replay(graph, &decided);
  GraphReplay<Pose> restarted_replay(graph, restarted.get());
  for (const ArrivalEvent& event : ArrivalOrder(graph)) {
    decided_replay.Apply(event);
    while (decided.HasPendingStep()) decided.RunStep();
    restarted_replay.Apply(event);
  }
  IrrrStepState<Pose> state = decided.StepState();
  const int odometry = restarted->graph().OdometryInto(restarted->graph().num_vertices() / 3);
  state.weakened_odometry.push_back(odometry);
  std::sort(state.weakened_odometry.begin(), state.weakened_odometry.end());
  state.weakened_odometry.erase(
      std::unique(state.weakened_odometry.begin(), state.weakened_odometry.end()),
      state.weakened_odometry.end());
  const Status restored = restarted->RestoreStepState(std::move(state));
  INFO(restored.message());
  REQUIRE(restored.ok());
  return restarted;
}

TEMPLATE_TEST_CASE(
    "An Irrr's inputs as a base holds them, fed to a fresh Irrr with its step state, rebuild it",
    "[reliability][slow]",
    Pose2,
    Pose3) {
  using Pose = TestType;
  const std::unique_ptr<Irrr<Pose>> original = WeakenedRun<Pose>();
  SnapshotWriter w;
  w.Inputs(*original);
  w.StepState(original->StepState());
  const std::vector<uint8_t> body = w.bytes();

  SnapshotReader r(body);
  Irrr<Pose> fresh{IrrrOptions()};
  REQUIRE(r.FeedInputs(&fresh));
  IrrrStepState<Pose> state;
  REQUIRE(r.StepState(&state));
  CHECK(r.at_end());
  // The inputs as taken: same order, same graph, every edge with the information as given.
  const PoseGraph<Pose>& a = original->graph();
  const PoseGraph<Pose>& b = fresh.graph();
  REQUIRE(fresh.Arrivals().size() == original->Arrivals().size());
  for (size_t k = 0; k < fresh.Arrivals().size(); ++k) {
    CHECK(fresh.Arrivals()[k].kind == original->Arrivals()[k].kind);
    CHECK(fresh.Arrivals()[k].index == original->Arrivals()[k].index);
  }
  REQUIRE(b.num_vertices() == a.num_vertices());
  REQUIRE(b.num_edges() == a.num_edges());
  for (int v = 0; v < a.num_vertices(); ++v) {
    CHECK((b.vertex(v).id == a.vertex(v).id && b.vertex(v).stamp == a.vertex(v).stamp &&
           b.vertex(v).session == a.vertex(v).session));
  }
  int weakened = 0;
  for (int e = 0; e < a.num_edges(); ++e) {
    INFO("edge " << e);
    CHECK((b.edge(e).from == a.edge(e).from && b.edge(e).to == a.edge(e).to));
    CHECK(b.edge(e).measurement.Log() == a.edge(e).measurement.Log());
    CHECK(b.edge(e).information == original->GivenInformation(e));
    weakened += a.edge(e).information != original->GivenInformation(e) ? 1 : 0;
  }
  CHECK(weakened > 0);
  // With the step state: the same decisions, estimate and weakened odometry.
  REQUIRE(fresh.RestoreStepState(std::move(state)).ok());
  for (int e = 0; e < a.num_edges(); ++e) {
    INFO("edge " << e);
    CHECK(b.edge(e).information == a.edge(e).information);
    CHECK(fresh.decision(e).state == original->decision(e).state);
    CHECK(fresh.decision(e).step == original->decision(e).step);
  }
  CHECK(fresh.OdometryFaults() == original->OdometryFaults());
  for (int v = 0; v < a.num_vertices(); ++v) {
    CHECK((fresh.estimate()[v].Log() - original->estimate()[v].Log()).norm() < 1e-2);
  }

  // Any cut of the inputs is refused.
  for (size_t cut = 0; cut < body.size(); cut += 97) {
    const std::vector<uint8_t> part(body.begin(), body.begin() + static_cast<long>(cut));
    SnapshotReader partial(part);
    Irrr<Pose> refused{IrrrOptions()};
    IrrrStepState<Pose> ignored;
    CHECK(!(partial.FeedInputs(&refused) && partial.StepState(&ignored) && partial.at_end()));
  }
}

}  // namespace
}  // namespace irrr
