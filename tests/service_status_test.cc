// The service's status (daemon/service_status.cc): DEGRADED and why at a limit, and another
// daemon on our correction channel noticed.

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

TEST_CASE("At a limit the status says DEGRADED and why, and nothing grows past it",
          "[reliability]") {
  RecordingSink sink;
  DaemonOptions daemon;
  daemon.limits.max_sessions = 2;
  daemon.limits.max_held = 5;
  Service service(daemon, CaseOptions(), &sink);
  auto keyframe = [&](const std::string& sender, int32_t session, int64_t seq) {
    SendFirstKeyframe(&service, daemon.channels, sender, 0, session, seq);
  };
  keyframe("a", 0, 0);
  service.PublishStatus(status_t::RUNNING);
  CHECK(sink.New<status_t>(daemon.channels.status).back().state == status_t::RUNNING);
  keyframe("a", 1, 1);
  keyframe("a", 2, 2);  // a third session: refused
  status_t status = service.CurrentStatus();
  CHECK(status.n_sessions == 2);
  CHECK_THAT(status.degraded_reason, Contains("max_sessions"));
  const std::vector<error_t> errors = sink.New<error_t>(daemon.channels.error);
  REQUIRE(errors.size() == 1);
  CHECK_THAT(errors[0].reason, Contains("max_sessions"));
  service.PublishStatus(status_t::RUNNING);
  const status_t published = sink.New<status_t>(daemon.channels.status).back();
  CHECK(published.state == status_t::DEGRADED);
  CHECK_THAT(published.degraded_reason, Contains("max_sessions"));

  // Held inputs (a lost seq 3 of "b"): at most max_held; the rest are refused, asked for later.
  for (int64_t seq = 1; seq <= 8; ++seq) keyframe("b", 0, seq);
  status = service.CurrentStatus();
  for (const sender_count_t& s : status.senders) {
    if (s.sender == "b") CHECK(s.held == 5);
  }
  CHECK_THAT(status.degraded_reason, Contains("max_held"));
}

TEST_CASE("Another daemon publishing on our correction channel is noticed, ours are not",
          "[reliability]") {
  RecordingSink sink;
  DaemonOptions daemon;
  daemon.daemon_id = "base-a";
  Service service(daemon, CaseOptions(), &sink);
  auto hear = [&](const std::string& sender) {
    correction_t c{};
    c.header.sender = sender;
    c.solution_id = 1;
    const std::vector<uint8_t> bytes = EncodeMessage(c);
    service.Receive(daemon.channels.correction, bytes.data(), static_cast<int>(bytes.size()));
  };
  hear("base-a");  // our own, back over multicast
  CHECK(service.CurrentStatus().degraded_reason.empty());
  hear("base-b");
  hear("base-b");
  const status_t status = service.CurrentStatus();
  CHECK(status.degraded_reason == "daemon \"base-b\" also publishes on IRRR_CORRECTION");
  CHECK(status.n_errors == 0);
  service.PublishStatus(status_t::RUNNING);
  const std::vector<status_t> published = sink.Decoded<status_t>(daemon.channels.status);
  REQUIRE(published.size() == 1);
  CHECK(published[0].state == status_t::DEGRADED);
}

}  // namespace
}  // namespace irrr
