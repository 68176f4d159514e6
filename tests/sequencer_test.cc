// Each sender's order restored (daemon/sequencer.h): seq order, once each, and a bounded hold.

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

TEST_CASE("Sequencer: each sender's messages come out in seq order, once each", "[reliability]") {
  SequencerLimits limits;
  limits.interval = std::chrono::milliseconds(10);
  limits.give_up = std::chrono::milliseconds(100);
  Sequencer<int> sequencer(limits);
  std::vector<int> out;
  auto take = [&out](int&& v) {
    out.push_back(v);
    return true;
  };
  using Outcome = Sequencer<int>::Outcome;
  const auto t0 = Clock::now();
  CHECK(sequencer.Offer("a", 0, 0, t0, take) == Outcome::kTaken);
  CHECK(sequencer.Offer("a", 2, 2, t0, take) == Outcome::kHeld);
  CHECK(sequencer.Offer("a", 5, 5, t0, take) == Outcome::kHeld);
  CHECK(sequencer.Offer("b", 0, 100, t0, take) == Outcome::kTaken);  // senders are independent
  CHECK(sequencer.Offer("a", 2, 2, t0, take) == Outcome::kDuplicate);
  CHECK(sequencer.Offer("a", 0, 0, t0, take) == Outcome::kDuplicate);
  CHECK(out == std::vector<int>{0, 100});

  // Missing: 1, 3 and 4, asked for at once, then not again before the interval.
  std::vector<Sequencer<int>::Request> due = sequencer.DueRequests(t0);
  REQUIRE(due.size() == 1);
  CHECK(due[0].sender == "a");
  CHECK(due[0].ranges == std::vector<std::pair<int64_t, int64_t>>{{1, 1}, {3, 4}});
  CHECK(sequencer.DueRequests(t0 + std::chrono::milliseconds(5)).empty());
  CHECK(sequencer.DueRequests(t0 + std::chrono::milliseconds(11)).size() == 1);

  CHECK(sequencer.Offer("a", 1, 1, t0, take) == Outcome::kTaken);  // releases 2
  CHECK(sequencer.Offer("a", 4, 4, t0, take) == Outcome::kHeld);
  CHECK(out == std::vector<int>{0, 100, 1, 2});
  std::map<std::string, StreamCounts> counts = sequencer.Counts();
  CHECK(counts["a"].next_seq == 3);
  CHECK(counts["a"].last_seq == 5);
  CHECK(counts["a"].held == 2);
  CHECK(counts["a"].gaps == 3);
  CHECK(counts["a"].duplicates == 2);
  CHECK(counts["a"].requested == 6);

  // Seq 3 never comes: given up after give_up, 4 and 5 follow.
  CHECK(sequencer.GiveUp(t0 + std::chrono::milliseconds(50), take).empty());
  const auto skipped = sequencer.GiveUp(t0 + std::chrono::milliseconds(101), take);
  REQUIRE(skipped.size() == 1);
  CHECK(skipped[0].ranges == std::vector<std::pair<int64_t, int64_t>>{{3, 3}});
  CHECK(out == std::vector<int>{0, 100, 1, 2, 4, 5});
  counts = sequencer.Counts();
  CHECK(counts["a"].given_up == 1);
  CHECK(counts["a"].held == 0);
  CHECK(sequencer.Offer("a", 3, 3, t0, take) == Outcome::kDuplicate);  // too late

  // A receiver that refuses: the message is dropped and the stream waits for its resend.
  bool full = true;
  auto refusing = [&](int&& v) {
    if (full) return false;
    out.push_back(v);
    return true;
  };
  CHECK(sequencer.Offer("c", 0, 7, t0, refusing) == Outcome::kRefused);
  CHECK(sequencer.Counts()["c"].next_seq == 0);
  full = false;
  CHECK(sequencer.Offer("c", 0, 7, t0, refusing) == Outcome::kTaken);

  // Resume (after recovery from the journal): seqs below are duplicates.
  sequencer.Resume("d", 10);
  CHECK(sequencer.Offer("d", 9, 9, t0, take) == Outcome::kDuplicate);
  CHECK(sequencer.Offer("d", 10, 10, t0, take) == Outcome::kTaken);
}

TEST_CASE("Sequencer: held messages are bounded by max_held", "[reliability]") {
  SequencerLimits limits;
  limits.max_held = 3;
  Sequencer<int> sequencer(limits);
  auto take = [](int&&) { return true; };
  using Outcome = Sequencer<int>::Outcome;
  for (int seq = 1; seq <= 3; ++seq) {
    CHECK(sequencer.Offer("a", seq, seq, Clock::now(), take) == Outcome::kHeld);
  }
  CHECK(sequencer.Offer("a", 4, 4, Clock::now(), take) == Outcome::kHoldFull);
  CHECK(sequencer.total_held() == 3);
  CHECK(sequencer.Offer("a", 0, 0, Clock::now(), take) == Outcome::kTaken);
  CHECK(sequencer.total_held() == 0);
  CHECK(sequencer.Counts()["a"].next_seq == 4);  // 4 was dropped: it will be asked for
}

}  // namespace
}  // namespace irrr
