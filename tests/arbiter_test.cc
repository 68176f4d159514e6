// Conflicts settled on all their evidence (core/warm_arbiter.cc), and odometry faults the
// accepted loops refute (WarmEngine::OdometryFaults).

#include <vector>

#include <catch2/catch.hpp>

#include "core/irrr.h"
#include "core/outliers.h"
#include "core/time_reversal.h"
#include "tests/corrupted_graph.h"
#include "tests/synthetic_graph.h"

namespace irrr {
namespace {

using testing::CountAccepted;
using testing::MakeCorrupted;
using testing::NoisyWorld;
using testing::SyntheticOptions;
using testing::WithFault;

template <class Pose>
std::vector<LoopDecision> Reversed(const PoseGraph<Pose>& graph, const IrrrOptions& options) {
  const ReversedGraph<Pose> reversed = TimeReversed(graph);
  const std::vector<LoopDecision> decisions =
      RunIncrementalIrrr<Pose>(reversed.graph, options, nullptr, nullptr);
  std::vector<LoopDecision> out(graph.num_edges());
  for (int e = 0; e < graph.num_edges(); ++e) out[e] = decisions[reversed.edge_of[e]];
  return out;
}

// Runs iRRR over `graph` in arrival order; returns its decisions, and its odometry faults in
// `faults`.
template <class Pose>
std::vector<LoopDecision> Decide(const PoseGraph<Pose>& graph, std::vector<int>* faults) {
  Irrr<Pose> irrr{IrrrOptions()};
  GraphReplay<Pose> replay(graph, &irrr);
  for (const ArrivalEvent& event : ArrivalOrder(graph)) {
    replay.Apply(event);
    while (irrr.HasPendingStep()) irrr.RunStep();
  }
  irrr.Flush();
  while (irrr.HasPendingStep()) irrr.RunStep();
  *faults = replay.OdometryFaults();
  return replay.Decisions();
}

TEMPLATE_TEST_CASE("Loops arriving in reversed order are decided as in forward order",
                   "[arbiter][slow]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  // Each session driven backwards (TimeReversed): every loop arrives with the other of its two
  // poses, so wrong groups and the true loops that contradict them come in the opposite order.
  for (OutlierMode mode :
       {OutlierMode::kAliasedGrouped, OutlierMode::kRandomGrouped, OutlierMode::kLocalGrouped}) {
    for (uint32_t seed = 1; seed <= 3; ++seed) {
      OutlierOptions outliers;
      outliers.mode = mode;
      outliers.count = 30;
      outliers.seed = seed;
      SyntheticOptions synthetic = NoisyWorld<Pose>(seed);
      synthetic.num_poses = Pose::kDim == 3 ? 400 : 300;
      const auto corrupted = MakeCorrupted<Pose>(synthetic, outliers);
      const auto forward =
          RunIncrementalIrrr<Pose>(corrupted.graph, IrrrOptions(), nullptr, nullptr);
      const auto backward = Reversed(corrupted.graph, IrrrOptions());
      INFO(OutlierModeName(mode) << ", seed " << seed);
      const auto f = CountAccepted(corrupted, forward);
      const auto b = CountAccepted(corrupted, backward);
      CHECK(f.accepted_wrong == 0);
      CHECK(b.accepted_wrong == 0);
      CHECK(f.accepted_true == f.true_loops);
      int differ = 0;
      for (int e = 0; e < corrupted.graph.num_edges(); ++e) {
        differ += (forward[e].state == LoopState::kAccepted) !=
                  (backward[e].state == LoopState::kAccepted);
      }
      CHECK(differ == 0);
    }
  }
}

TEMPLATE_TEST_CASE(
    "Clean odometry is never flagged; a fault the accepted loops span is found "
    "as the stretch it lies in",
    "[arbiter]",
    Pose2,
    Pose3) {
  using Pose = TestType;
  int found = 0;
  constexpr int kSeeds = 5;
  for (uint32_t seed = 1; seed <= kSeeds; ++seed) {
    SyntheticOptions synthetic = NoisyWorld<Pose>(seed);
    synthetic.num_poses = Pose::kDim == 3 ? 400 : 300;
    const PoseGraph<Pose> clean = testing::MakeSyntheticGraph<Pose>(synthetic).graph;
    std::vector<int> faults;
    Decide(clean, &faults);
    INFO("seed " << seed);
    CHECK(faults.empty());

    // 2 m and 0.6 rad wrong (20 and 30 times the odometry's noise) halfway along.
    const int fault = clean.OdometryInto(synthetic.num_poses / 2);
    typename Pose::Tangent offset = Pose::Tangent::Zero();
    offset(0) = 2.0;
    offset(Pose::kDim - 1) = 0.6;
    const PoseGraph<Pose> faulty = WithFault(clean, fault, offset);
    Decide(faulty, &faults);
    // Flagged edges are one stretch of adjacent edges around the fault, or none (when no
    // accepted loop spans it).
    for (size_t k = 1; k < faults.size(); ++k) CHECK(faults[k] == faults[k - 1] + 1);
    if (!faults.empty()) {
      CHECK(faults.front() <= fault);
      CHECK(faults.back() >= fault);
      ++found;
    }
  }
  // Loops across a fault are refused when they contradict it too strongly to be accepted at all
  // (2D seeds 1 and 3): at least three in five are found.
  CHECK(found >= 3);
}

}  // namespace
}  // namespace irrr
