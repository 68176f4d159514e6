// Snapshot bodies (daemon/snapshot.h): read back as written, any cut refused.

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

}  // namespace
}  // namespace irrr
