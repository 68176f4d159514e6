// The stamp merge of a fleet's senders (daemon/stamp_merger.h).

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

TEST_CASE("The stamp merge hands inputs over by (stamp, sender), waiting for open senders",
          "[reliability]") {
  using Merger = StampMerger<std::string>;
  const auto t0 = Clock::now();
  std::vector<std::string> out;
  auto take = [&out](std::string&& m) { out.push_back(m); };

  SECTION("two senders in any arrival order come out by stamp, ties by sender name") {
    Merger merger(std::chrono::milliseconds(1000), {});
    merger.Add("b", 10, true, "b10", t0);
    merger.Release(t0, take);
    CHECK(out == std::vector<std::string>{"b10"});  // "a" is not known yet: nothing to wait for
    merger.Add("a", 5, true, "a5", t0);
    merger.Add("a", Merger::kNoStamp, true, "a-loop", t0);  // follows a's latest stamp
    merger.Add("b", 20, true, "b20", t0);
    merger.Add("a", 20, true, "a20", t0);
    merger.Release(t0, take);
    // b20 waits while "a" has shown 20 and "b" is open: a20 and b20 tie, "a" first; then
    // nothing shows > 20 yet, so the last of them waits for the other's next stamp.
    CHECK(out == std::vector<std::string>{"b10", "a5", "a-loop", "a20"});
    CHECK(merger.held() == 1);
    merger.Add("a", 30, false, "a30-end", t0);  // "a" closes: it holds nobody back
    merger.Release(t0, take);
    CHECK(out == std::vector<std::string>{"b10", "a5", "a-loop", "a20", "b20"});
    CHECK(merger.held() == 1);  // a30-end waits: "b" is open and may still send up to 30
    merger.Add("b", 40, true, "b40", t0);
    merger.Add("b", 50, true, "b50", t0);
    merger.Release(t0, take);
    CHECK(out ==
          std::vector<std::string>{"b10", "a5", "a-loop", "a20", "b20", "a30-end", "b40", "b50"});
    CHECK(merger.held() == 0);
  }
  SECTION("a silent open sender is waited for at most the window") {
    Merger merger(std::chrono::milliseconds(100), {});
    merger.Add("a", 1, true, "a1", t0);
    merger.Add("b", 5, true, "b5", t0);
    merger.Add("b", 6, true, "b6", t0);
    CHECK(merger.Release(t0, take) == 0);
    CHECK(out == std::vector<std::string>{"a1"});
    CHECK(merger.Release(t0 + std::chrono::milliseconds(50), take) == 0);
    CHECK(out.size() == 1);
    CHECK(merger.Release(t0 + std::chrono::milliseconds(150), take) == 2);
    CHECK(out == std::vector<std::string>{"a1", "b5", "b6"});
  }
  SECTION("expected senders are waited for before they are heard") {
    Merger merger(std::chrono::milliseconds(1000), {"robot1", "robot2"});
    merger.Add("robot2", 150, true, "r2-150", t0);
    merger.Release(t0, take);
    CHECK(out.empty());  // robot1 may still send earlier stamps
    merger.Add("robot1", 0, true, "r1-0", t0);
    merger.Add("robot1", 149, true, "r1-149", t0);
    merger.Release(t0, take);
    CHECK(out == std::vector<std::string>{"r1-0", "r1-149"});
    merger.Add("robot1", 149, false, "r1-end", t0);
    merger.Release(t0, take);
    CHECK(out == std::vector<std::string>{"r1-0", "r1-149", "r1-end", "r2-150"});
  }
}

}  // namespace
}  // namespace irrr
