// The daemon's configuration (daemon/common/irrr_config.h): config/irrrd.json holds every
// default, and every error names its key.

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
  CHECK_THAT(error(R"({"daemon": {"channels": {"loop": "IRRR_KEYFRAME"}}})"),
             Contains("used by another channel"));
  CHECK_THAT(error(R"({"daemon": {"journal": {"snapshot_after_s": -1}}})"),
             Contains("snapshot_after_s must be finite and >= 0"));
  CHECK_THAT(error(R"({"daemon": {"journal": {"compact_mb": -1}}})"),
             Contains("compact_mb must be finite and >= 0"));
  CHECK_THAT(error(R"({"daemon": {"journal": {"keep_compacted": 1}}})"),
             Contains("expected true or false"));
  CHECK_THAT(error(R"({"irrr": {"alpha": 2}})"), Contains("irrr"));
  CHECK_THAT(error(R"({"irrr": {"cluster_gap": "ten"}})"), Contains("irrr.cluster_gap"));
}

}  // namespace
}  // namespace irrr
