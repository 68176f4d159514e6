// iRRR's speed-ups change nothing but time: every decision is the one made with the speed-up
// switched off (issue "Make iRRR fast"). The benchmark cases themselves (thousands of poses, 1000
// wrong loops) are checked by irrr-bench-speed, which prints "same decisions" per variant and
// fails when one differs; here synthetic graphs with known outliers, 2D and 3D, several sessions.

#include <atomic>
#include <chrono>
#include <cmath>
#include <map>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <catch2/catch.hpp>

#include "core/irrr.h"
#include "core/outliers.h"
#include "daemon/common/thread_pool.h"
#include "tests/corrupted_graph.h"

namespace irrr {
namespace {

template <class Pose>
PoseGraph<Pose> CorruptedWorld(int sessions, OutlierMode mode, uint32_t seed) {
  testing::SyntheticOptions synthetic = testing::NoisyWorld<Pose>(seed);
  // 3D problems cost several times what 2D ones do: a smaller world keeps the test short.
  synthetic.num_poses = Pose::kDim == 6 ? 120 : 240;
  synthetic.num_sessions = sessions;
  OutlierOptions outliers;
  outliers.mode = mode;
  outliers.count = 30;
  outliers.seed = seed;
  return testing::MakeCorrupted<Pose>(synthetic, outliers).graph;
}

template <class Pose>
struct Run {
  std::vector<LoopDecision> decisions;
  std::vector<Pose> estimate;
  int solves = 0;
};

template <class Pose>
Run<Pose> Incremental(const PoseGraph<Pose>& graph, const IrrrOptions& options, int threads) {
  ThreadPool pool(threads);
  Run<Pose> run;
  std::vector<StepResult> steps;
  run.decisions =
      RunIncrementalIrrr(graph, options, &run.estimate, &steps, pool.AsParallelFor(), pool.size());
  for (const StepResult& step : steps) run.solves += step.solves;
  return run;
}

// How alike two runs must be.
enum class Alike {
  kBitwise,   // same state, statistics and estimate to the bit: the speed-ups that only skip or
              // move work (an optimization is a pure function of its problem)
  kAccepted,  // the same loops accepted (see "local_problems off")
};

template <class Pose>
void CheckSame(const Run<Pose>& reference, const Run<Pose>& other, Alike alike) {
  REQUIRE(other.decisions.size() == reference.decisions.size());
  int differ = 0;
  for (size_t e = 0; e < reference.decisions.size(); ++e) {
    const LoopDecision& a = reference.decisions[e];
    const LoopDecision& b = other.decisions[e];
    const bool same = alike == Alike::kBitwise
                          ? a.state == b.state
                          : (a.state == LoopState::kAccepted) == (b.state == LoopState::kAccepted);
    if (same) continue;
    ++differ;
    UNSCOPED_INFO("edge " << e << ": " << LoopStateName(a.state) << " (chi2 " << a.chi2 << " vs "
                          << a.threshold << ", step " << a.step << ") against "
                          << LoopStateName(b.state) << " (chi2 " << b.chi2 << " vs " << b.threshold
                          << ", step " << b.step << ")");
  }
  CHECK(differ == 0);
  if (alike != Alike::kBitwise) return;
  int chi2_differ = 0;
  for (size_t e = 0; e < reference.decisions.size(); ++e) {
    const double a = reference.decisions[e].chi2;
    const double b = other.decisions[e].chi2;
    chi2_differ += (a == b || (std::isnan(a) && std::isnan(b))) ? 0 : 1;
  }
  CHECK(chi2_differ == 0);
  REQUIRE(other.estimate.size() == reference.estimate.size());
  int poses_differ = 0;
  for (size_t v = 0; v < reference.estimate.size(); ++v) {
    poses_differ +=
        (reference.estimate[v].ErrorVector() - other.estimate[v].ErrorVector()).norm() == 0.0 ? 0
                                                                                              : 1;
  }
  CHECK(poses_differ == 0);
}

TEMPLATE_TEST_CASE("Every speed-up of iRRR leaves every decision as it is",
                   "[irrr][speed]",
                   Pose2,
                   Pose3) {
  const OutlierMode mode = GENERATE(OutlierMode::kRandom, OutlierMode::kRandomGrouped);
  const int sessions = GENERATE(1, 3);
  INFO(OutlierModeName(mode) << ", " << sessions << " session(s)");
  const PoseGraph<TestType> graph = CorruptedWorld<TestType>(sessions, mode, 7);
  // The speed-ups are the cold engine's (batch RRR and the paper preset run on it).
  const IrrrOptions all_on = [] {
    IrrrOptions options;
    options.engine = IrrrEngine::kCold;
    options.alpha = 0.95;
    options.cluster_gap = 10.0;
    return options;
  }();
  // Catch runs the body once per section: the reference run is kept for the next sections.
  static std::map<std::pair<OutlierMode, int>, Run<TestType>> references;
  if (references.count({mode, sessions}) == 0) {
    references[{mode, sessions}] = Incremental(graph, all_on, 2);
  }
  const Run<TestType>& reference = references[{mode, sessions}];
  int accepted = 0;
  int rejected = 0;
  for (const LoopDecision& d : reference.decisions) {
    accepted += d.state == LoopState::kAccepted ? 1 : 0;
    rejected += d.state != LoopState::kAccepted && d.state != LoopState::kPending ? 1 : 0;
  }
  // A case that decides something both ways (the checks below would be empty otherwise).
  REQUIRE(accepted > 0);
  REQUIRE(rejected > 0);

  SECTION("one thread") {
    const Run<TestType> serial = Incremental(graph, all_on, 1);
    CheckSame(reference, serial, Alike::kBitwise);
  }
  SECTION("reuse_solves off") {
    IrrrOptions options = all_on;
    options.reuse_solves = false;
    const Run<TestType> run = Incremental(graph, options, 2);
    CheckSame(reference, run, Alike::kBitwise);
    // What the reuse saves: the line-8 and final optimizations are never run twice.
    CHECK(run.solves > reference.solves);
  }
  SECTION("reuse_analysis off") {
    IrrrOptions options = all_on;
    options.reuse_analysis = false;
    CheckSame(reference, Incremental(graph, options, 2), Alike::kBitwise);
  }
  SECTION("lazy_lookahead off") {
    IrrrOptions options = all_on;
    options.lazy_lookahead = false;
    const Run<TestType> run = Incremental(graph, options, 1);
    CheckSame(reference, run, Alike::kBitwise);
  }
  SECTION("local_problems off") {
    // Whole sessions instead of the looped spans: the same optimum in exact arithmetic, reached
    // along another path. In 3D with wrong loops the two can settle in minima far enough apart to
    // change the order in which two wrong single links fall (one rejected, the other accepted
    // and reversed a step later, against the reverse): the accepted set is what stays the same.
    IrrrOptions options = all_on;
    options.local_problems = false;
    CheckSame(reference, Incremental(graph, options, 2), Alike::kAccepted);
  }
  SECTION("batch RRR on the pool") {
    ThreadPool pool(2);
    Run<TestType> parallel;
    parallel.decisions =
        RunBatchRrr(graph, all_on, &parallel.estimate, pool.AsParallelFor(), pool.size());
    Run<TestType> serial;
    serial.decisions = RunBatchRrr(graph, all_on, &serial.estimate);
    CheckSame(serial, parallel, Alike::kBitwise);
  }
}

TEST_CASE("The thread pool runs every item once, on several threads", "[irrr][speed]") {
  ThreadPool pool(3);
  REQUIRE(pool.size() == 3);
  for (int round = 0; round < 20; ++round) {
    const int n = 1 + round * 7;
    std::vector<std::atomic<int>> runs(n);
    std::mutex mutex;
    std::set<std::thread::id> threads;
    pool.Run(n, [&](int i) {
      runs[i].fetch_add(1);
      std::lock_guard<std::mutex> lock(mutex);
      threads.insert(std::this_thread::get_id());
      // Long enough that the others take items too.
      std::this_thread::sleep_for(std::chrono::microseconds(200));
    });
    for (int i = 0; i < n; ++i) CHECK(runs[i].load() == 1);
    if (n >= 30) CHECK(threads.size() >= 2);
  }
  ThreadPool inline_pool(1);
  int sum = 0;
  inline_pool.Run(10, [&](int i) { sum += i; });
  CHECK(sum == 45);
}

}  // namespace
}  // namespace irrr
