// Public datasets from ../shared: every file loads with the counts the dataset README lists, and
// the optimizer reaches the known optimum of Manhattan, Intel and Sphere2500 from the raw guess;
// iRRR keeps its precision and recall on Manhattan with 1000 local wrong loops, a wrong part of a
// large true cluster leaves it (Intel), its variance factor is not set by wrong links in the
// first clusters (Manhattan, Vertigo's ring), and on KITTI 05 it reads the factor from the good
// set; on Bovisa its map stays within metres of GPS; New College (the paper's) loads once its
// self-loops are skipped and merges from three sessions; Kimera-RPGO's two robots keep their
// odometry maps and refuse every loop hypothesis.

#include <algorithm>
#include <cstdint>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <catch2/catch.hpp>

#include "core/graph_io.h"
#include "core/irrr.h"
#include "core/optimizer.h"
#include "core/outliers.h"
#include "core/test_statistics.h"
#include "core/trajectory_metrics.h"
#include "tests/corrupted_graph.h"

namespace irrr {
namespace {

std::string SharedPath(const std::string& relative) {
  return std::string(IRRR_SHARED_DIR) + "/datasets/" + relative;
}

template <class Pose>
Status Load(const std::string& relative,
            const ReadOptions& options,
            GraphFile<Pose>* file,
            PoseGraph<Pose>* graph) {
  const std::string path = SharedPath(relative);
  std::ifstream sniff(path);
  REQUIRE(sniff.good());
  FileFormat format;
  int dimension = 0;
  if (Status s = DetectGraphFile(sniff, &format, &dimension); !s.ok()) return s;
  REQUIRE(dimension == Pose::kTranslationDim);
  std::ifstream in(path);
  if (Status s = ReadGraphFile(in, format, options, file); !s.ok()) return s;
  std::vector<int> unused;
  return BuildPoseGraph(*file, graph, &unused);
}

struct Counts {
  const char* path;
  int vertices;  // as listed in datasets/README.md (edges-only files: distinct endpoints)
  int edges;
  int sessions;  // inferred from missing (i-1, i) odometry edges
};

TEST_CASE("Every 2D dataset loads with the listed counts", "[datasets]") {
  const Counts counts =
      GENERATE(Counts{"manhattan/vertigo/Olson/manhattanOlson3500.g2o", 3500, 5598, 1},
               Counts{"intel/vertigo/intel.g2o", 943, 1837, 1},
               Counts{"city10000/vertigo/city10000.g2o", 10000, 20687, 1},
               Counts{"csail/carlone_toro/CSAIL_P_toro.graph", 1045, 1172, 1},
               Counts{"fr079/carlone_toro/FR079_P_toro.graph", 989, 1217, 1},
               Counts{"ring/vertigo/originalDataset/ring.g2o", 434, 459, 1},
               Counts{"kitti_rrr/00/kitti_00_alpha_0.50.g2o", 4541, 4877, 1},
               Counts{"rrr_bicocca25b/B25b_0.500.g2o", 8358, 8479, -1});
  INFO(counts.path);
  GraphFile<Pose2> file;
  PoseGraph<Pose2> graph;
  const Status status = Load(counts.path, ReadOptions(), &file, &graph);
  INFO(status.message());
  REQUIRE(status.ok());
  CHECK(graph.num_vertices() == counts.vertices);
  CHECK(graph.num_edges() == counts.edges);
  if (counts.sessions > 0) CHECK(graph.num_sessions() == counts.sessions);
}

TEST_CASE("Every 3D dataset loads with the listed counts", "[datasets]") {
  const Counts counts = GENERATE(Counts{"sphere2500/vertigo/sphere2500.g2o", 2500, 4949, 1},
                                 Counts{"garage/parking-garage.g2o", 1661, 6275, 1},
                                 Counts{"torus3d/torus3D.g2o", 5000, 9048, 1});
  INFO(counts.path);
  GraphFile<Pose3> file;
  PoseGraph<Pose3> graph;
  const Status status = Load(counts.path, ReadOptions(), &file, &graph);
  INFO(status.message());
  REQUIRE(status.ok());
  CHECK(graph.num_vertices() == counts.vertices);
  CHECK(graph.num_edges() == counts.edges);
  CHECK(graph.num_sessions() == counts.sessions);
}

TEST_CASE("TORO's EQUIV lines are an error unless skipping is asked for", "[datasets]") {
  GraphFile<Pose2> file;
  PoseGraph<Pose2> graph;
  const Status strict = Load("toy/gtsam/w100.graph", ReadOptions(), &file, &graph);
  REQUIRE_FALSE(strict.ok());
  CHECK_THAT(strict.message(), Catch::Contains("line") && Catch::Contains("EQUIV"));
  ReadOptions skip;
  skip.skip_unknown_tags = true;
  REQUIRE(Load("toy/gtsam/w100.graph", skip, &file, &graph).ok());
  CHECK(graph.num_vertices() == 100);
  CHECK(graph.num_edges() == 300);
}

template <class Pose>
OptimizerSummary SolveAll(const PoseGraph<Pose>& graph, std::vector<Pose>* estimate) {
  Optimizer<Pose> optimizer;
  *estimate = graph.initial_estimate();
  return optimizer.Solve(graph, std::vector<char>(graph.num_edges(), 1), estimate);
}

TEST_CASE("Manhattan is optimized from its raw guess to the known optimum", "[datasets]") {
  GraphFile<Pose2> file;
  PoseGraph<Pose2> graph;
  REQUIRE(
      Load("manhattan/vertigo/Olson/manhattanOlson3500.g2o", ReadOptions(), &file, &graph).ok());
  std::vector<Pose2> estimate;
  const OptimizerSummary summary = SolveAll(graph, &estimate);
  INFO(summary.message);
  REQUIRE(summary.termination == TerminationType::kConvergence);
  // The optimum of Manhattan with all its (true) loops: chi2 146.1 (algorithm-notes, "Beyond the
  // paper"; g2o reports the same). 0.5% covers convergence tolerance, not a different minimum.
  CHECK(summary.final_chi2 == Approx(146.1).epsilon(0.005));

  // Vertigo's ground truth, line k = vertex k.
  std::ifstream in(
      SharedPath("manhattan/vertigo/groundTruth/manhattanOlson3500_nodes_groundTruth.dat"));
  std::vector<Pose2> ground_truth;
  double x, y, yaw;
  while (in >> x >> y >> yaw) ground_truth.push_back(Pose2(x, y, yaw));
  REQUIRE(ground_truth.size() == estimate.size());
  const double ate = AbsoluteTrajectoryError(estimate, ground_truth).rmse_m;
  // The optimum's ATE (0.79 m, see docs/measurements.md); a wrong minimum is metres away.
  CHECK(ate == Approx(0.79).margin(0.02));
}

// Gauss-Newton and Levenberg-Marquardt take different paths from the raw guess; reaching the same
// chi2 says both found the minimum (a wrong Jacobian or a stalled solver would not agree).
template <class Pose>
void CheckBothAlgorithmsAgree(const std::string& relative, double known_chi2) {
  INFO(relative);
  GraphFile<Pose> file;
  PoseGraph<Pose> graph;
  REQUIRE(Load(relative, ReadOptions(), &file, &graph).ok());
  std::vector<Pose> gauss_newton;
  const OptimizerSummary gn = SolveAll(graph, &gauss_newton);
  OptimizerOptions lm_options;
  lm_options.algorithm = OptimizerAlgorithm::kLevenbergMarquardt;
  Optimizer<Pose> lm_optimizer(lm_options);
  std::vector<Pose> levenberg = graph.initial_estimate();
  const OptimizerSummary lm =
      lm_optimizer.Solve(graph, std::vector<char>(graph.num_edges(), 1), &levenberg);
  REQUIRE(gn.termination == TerminationType::kConvergence);
  REQUIRE(lm.termination == TerminationType::kConvergence);
  CHECK(lm.final_chi2 == Approx(gn.final_chi2).epsilon(1e-6));
  // The value this optimizer reports (docs/measurements.md); 0.1% is convergence noise.
  CHECK(gn.final_chi2 == Approx(known_chi2).epsilon(1e-3));
}

TEST_CASE("Intel, Sphere2500 and Garage reach the same optimum by Gauss-Newton and LM",
          "[datasets]") {
  CheckBothAlgorithmsAgree<Pose2>("intel/vertigo/intel.g2o", 546.461);
  CheckBothAlgorithmsAgree<Pose3>("sphere2500/vertigo/sphere2500.g2o", 727.15);
  CheckBothAlgorithmsAgree<Pose3>("garage/parking-garage.g2o", 1.23869);
}

// `relative` with `count` wrong loops of `mode` (core/outliers.h) appended, run through iRRR.
struct CorruptedRun {
  int true_loops = 0;
  int accepted_true = 0;
  int accepted_wrong = 0;
  // Loops still pending at the end in a cluster of two links or more (only a lone link nothing
  // can check may wait for good).
  int pending_in_clusters = 0;
  std::vector<StepResult> steps;
};

template <class Pose = Pose2>
CorruptedRun RunCorrupted(
    const std::string& relative, OutlierMode mode, int count, int seed, int group_size = 3) {
  GraphFile<Pose> file;
  PoseGraph<Pose> clean;
  REQUIRE(Load(relative, ReadOptions(), &file, &clean).ok());
  OutlierOptions outliers;
  outliers.mode = mode;
  outliers.count = count;
  outliers.seed = seed;
  outliers.group_size = group_size;
  const testing::Corrupted<Pose> corrupted = testing::Corrupt(clean, outliers);
  const PoseGraph<Pose>& graph = corrupted.graph;
  CorruptedRun run;
  const std::vector<LoopDecision> decisions =
      RunIncrementalIrrr<Pose>(graph, IrrrOptions(), nullptr, &run.steps);
  const testing::AcceptedLoops accepted = testing::CountAccepted(corrupted, decisions);
  run.true_loops = accepted.true_loops;
  run.accepted_true = accepted.accepted_true;
  run.accepted_wrong = accepted.accepted_wrong;
  run.pending_in_clusters = static_cast<int>(testing::PendingInClusters(graph, decisions).size());
  return run;
}

// No wrong loop accepted, recall at least 0.99, and nothing left pending in a cluster of two links
// or more.
void CheckNoneWrongRecallAtLeast99(const CorruptedRun& run) {
  INFO(run.accepted_true << " of " << run.true_loops << " true loops accepted");
  CHECK(run.accepted_wrong == 0);
  CHECK(run.accepted_true >= 0.99 * run.true_loops);
  CHECK(run.pending_in_clusters == 0);
}

// No wrong loop accepted and every true loop accepted.
void CheckNoneWrongEveryTrue(const CorruptedRun& run) {
  INFO(run.accepted_true << " of " << run.true_loops << " true loops accepted");
  CHECK(run.accepted_wrong == 0);
  CHECK(run.accepted_true == run.true_loops);
}

// The reversals over a run's steps.
int Reversals(const std::vector<StepResult>& steps) {
  int reversals = 0;
  for (const StepResult& step : steps) reversals += step.reversals;
  return reversals;
}

// The largest variance factor a decision was made at (steps that wait for a factor change
// nothing).
double LargestFactorDecidedAt(const std::vector<StepResult>& steps) {
  double largest = 0.0;
  for (const StepResult& step : steps) {
    if (!step.changed_loops.empty()) largest = std::max(largest, step.variance_factor);
  }
  return largest;
}

// Vertigo's ring (434 poses, 26 true loops, its heading information 60 times too loose) with
// `count` wrong loops of `mode`.
CorruptedRun RunRing(OutlierMode mode, int count, int seed) {
  return RunCorrupted("ring/vertigo/originalDataset/ring.g2o", mode, count, seed);
}

// Nothing wrong and every true loop accepted, and no decision made at a factor of 0.5 or more:
// the ring's own is 0.13-0.17, and a larger one came from a sample holding wrong links.
void CheckRingDecidedAtItsOwnFactor(const CorruptedRun& run) {
  CheckNoneWrongEveryTrue(run);
  CHECK(LargestFactorDecidedAt(run.steps) < 0.5);
}

// Manhattan + 1000 wrong loops each 2-50 poses back (core/outliers.h, seed 1): they cluster with
// the true loops of the places they lie in, and a cluster holding a few of them fails the joint
// test whole. Judged again as its runs, the true runs are kept: 0 wrong, 2099 of 2099 true
// accepted (without the runs 2048, recall 0.976; 2086 while lone links failing together fell
// together). About 3 s in Release.
TEST_CASE("Manhattan + 1000 local wrong loops: none accepted, recall at least 0.99",
          "[datasets][irrr]") {
  const CorruptedRun run =
      RunCorrupted("manhattan/vertigo/Olson/manhattanOlson3500.g2o", OutlierMode::kLocal, 1000, 1);
  CheckNoneWrongRecallAtLeast99(run);
}

// Wrong links that fit by bending the odometry inside a true revisit. Judged by the chi2 increase
// alone, both come in with a true revisit at steps 6-7, and only later evidence reverses them
// (ReverseOutvoted):
// - Manhattan + 1000 local, seed 2: the wrong link 910 -> 870 (3.4 m and 0.5 rad off). Clusters
//   accepted later pinned that odometry: its removal statistic reached 13.4 times its threshold.
// - Manhattan + 1000 local-grouped, seed 6: the wrong group 1015-1017 -> 992-994 (1.2 m off
//   across 23 poses) fitted its own links; its removal statistic reached 6.3 times its threshold
//   at step 12 (BendingRuns).
// Their removal statistics, read with the Jacobians H holds, now show them when their revisit
// is tried (BendingParts): both are refused by the joint test as they come, and nothing needs
// reversing.
TEST_CASE("Manhattan + 1000 local, seeds 2 and 6: a wrong link inside a true revisit is refused",
          "[datasets][irrr]") {
  for (const auto& [mode, seed] :
       {std::pair{OutlierMode::kLocal, 2}, std::pair{OutlierMode::kLocalGrouped, 6}}) {
    INFO(OutlierModeName(mode) << ", seed " << seed);
    const CorruptedRun run =
        RunCorrupted("manhattan/vertigo/Olson/manhattanOlson3500.g2o", mode, 1000, seed);
    CheckNoneWrongRecallAtLeast99(run);
    CHECK(Reversals(run.steps) == 0);
  }
}

// Manhattan + 1000 local-grouped in groups of 10, seed 2: six links of the wrong group 2450-2459
// -> 2414-2423 (claims 2-3 m and 0.2-0.3 rad off) came in at step 49 inside a true revisit of
// about 100 links and fitted by bending the odometry at 2449-2453 (2451 -> 2452 fails its link
// test). The group's removal statistic stayed at 2.0-2.5 times its threshold, under the margin of
// 4 that single links need, so it stayed to the end: 6 wrong, 2096 of 2099, ATE 1.078 m against
// the oracle's 0.794. A run whose span holds failing odometry is now reversed at 2 times.
TEST_CASE("Manhattan + 1000 local-grouped in groups of 10, seed 2: a bending wrong run is reversed",
          "[datasets][irrr]") {
  const CorruptedRun run = RunCorrupted(
      "manhattan/vertigo/Olson/manhattanOlson3500.g2o", OutlierMode::kLocalGrouped, 1000, 2, 10);
  CheckNoneWrongEveryTrue(run);
  CHECK(Reversals(run.steps) >= 1);
}

// Manhattan + 1000 local-grouped, seed 42: the wrong group 2869-2871 -> 2836-2838 (claims
// 0.3-0.6 m and 0.27 rad off) came in at step 55 as a run of its own inside a 153-link revisit,
// its removal statistic 0.65 times its threshold: only odometry held that stretch. At step 56 a
// 48-link loop closing back to poses 0-127 ended at 2859-2878 and pinned it, 5.4 times its
// threshold from then on; no rule looked again (the good set had not doubled): 3 wrong, 2098 of
// 2099, ATE 0.819 m against the oracle's 0.794. Manhattan + 1000 local, seed 30: the wrong link
// 2615 -> 2578 (0.94 m and 0.24 rad off) came in at step 53 with a 146-link revisit at 1.7 times
// its threshold, and stood at 4.0-4.7 times from step 56 on: 1 wrong, 2098 of 2099, ATE 1.52
// times the oracle's. Good runs and lone links near the links a step accepts are now weighed
// again (PinnedParts).
TEST_CASE("Manhattan + 1000 local(-grouped), seeds 42 and 30: a wrong part later pinned leaves",
          "[datasets][irrr]") {
  for (const auto& [mode, seed] :
       {std::pair{OutlierMode::kLocalGrouped, 42}, std::pair{OutlierMode::kLocal, 30}}) {
    INFO(OutlierModeName(mode) << ", seed " << seed);
    const CorruptedRun run =
        RunCorrupted("manhattan/vertigo/Olson/manhattanOlson3500.g2o", mode, 1000, seed);
    CheckNoneWrongEveryTrue(run);
    CHECK(Reversals(run.steps) >= 1);
  }
}

// Manhattan + 300 local, seed 1: the wrong link 1584 -> 1575 (1.3 m and 0.34 rad off) came in at
// step 16 inside a true revisit of 89 links, near none of them, and fitted by bending the odometry
// 1575-1584 (every edge under its test). At step 44 the true lone links 1577 -> 2191 and 1574 ->
// 2198 failed the joint test, each alone too, and were refused without naming a suspect: 1 wrong,
// 2096 of 2099, ATE 1.079 m against the oracle's 0.794. Lone links that all fail alone then named
// suspects too, and the two outvoted 1584 -> 1575. With removal statistics at the Jacobians H
// holds, it is refused when its revisit is tried, and nothing needs reversing.
TEST_CASE("Manhattan + 300 local, seed 1: a wrong lone link inside a true revisit is refused",
          "[datasets][irrr]") {
  const CorruptedRun run =
      RunCorrupted("manhattan/vertigo/Olson/manhattanOlson3500.g2o", OutlierMode::kLocal, 300, 1);
  CheckNoneWrongEveryTrue(run);
  CHECK(Reversals(run.steps) == 0);
}

// Manhattan + 2000 local-grouped, seed 2: the wrong group 2859-2861 -> 2815-2817 (claims 3.6 m
// and 0.35 rad off) came in at steps 55 and 59, two of its links inside a revisit of 112 short
// loops. At step 56 the loop closing 2780 poses (75-127 -> 2848-2878) failed: half of its links
// at the screen, the rest in runs of 2-3, each too weak alone to show the group (its removal
// statistic under its threshold at each run's trial): 3 wrong, 2087 of 2099. The failed runs tried
// together show it at 5 times its threshold, and outvote it.
TEST_CASE("Manhattan + 2000 local-grouped, seed 2: runs that failed one by one challenge together",
          "[datasets][irrr]") {
  const CorruptedRun run = RunCorrupted(
      "manhattan/vertigo/Olson/manhattanOlson3500.g2o", OutlierMode::kLocalGrouped, 2000, 2);
  CheckNoneWrongEveryTrue(run);
  CHECK(Reversals(run.steps) >= 1);
}

// What a reversed cluster made the tests refuse, and true lone links judged with wrong ones, come
// back (docs/decisions.md, "Reversing and recovering"):
// - Manhattan + 1000 random-grouped, seed 10: the wrong group 86-88 -> 2917-2919 bent the map
//   while 327 -> 2907 (a loop closing 2580 poses) and 2895 -> 2902 were refused; the group was
//   reversed in the same step, they stayed refused: 2097 of 2099, ATE 1.007 m against the
//   oracle's 0.794.
// - Manhattan + 1000 local, seed 9: ten true lone links (2044 -> 2050, 2035 -> 2059, ...) were
//   judged together with eight wrong lone links and fell with them: 2089 of 2099, ATE 0.805 m.
TEST_CASE("Manhattan + 1000, random-grouped seed 10 and local seed 9: every true loop accepted",
          "[datasets][irrr]") {
  for (const auto& [mode, seed] :
       {std::pair{OutlierMode::kRandomGrouped, 10}, std::pair{OutlierMode::kLocal, 9}}) {
    INFO(OutlierModeName(mode) << ", seed " << seed);
    const CorruptedRun run =
        RunCorrupted("manhattan/vertigo/Olson/manhattanOlson3500.g2o", mode, 1000, seed);
    CheckNoneWrongEveryTrue(run);
  }
}

// Manhattan + 1000 random-grouped in groups of 10 (seed 1): at step 76 the wrong group 2341-2350
// -> 1631-1640 outvoted three true lone links (1544 -> 2294, 1527 -> 2296, 1544 -> 2310), which
// were reversed. At step 78 a true revisit of 18 links outvoted the group in turn, but what it
// had reversed stayed out: 2096 of 2099. Recovering after a reversal now judges again the links
// reversed since the reversed cluster's acceptance, not only those refused.
TEST_CASE(
    "Manhattan + 1000 random-grouped in groups of 10: what a wrong group reversed comes back "
    "when it goes",
    "[datasets][irrr]") {
  const CorruptedRun run = RunCorrupted(
      "manhattan/vertigo/Olson/manhattanOlson3500.g2o", OutlierMode::kRandomGrouped, 1000, 1, 10);
  CheckNoneWrongEveryTrue(run);
  CHECK(Reversals(run.steps) >= 2);
}

// Intel + 1000 local, seed 14: the wrong link 925 -> 895 came in at step 10 with a true revisit of
// 37 links (cluster of 38) and bent the map's last poses. The true revisits of those poses from
// poses 70, 188, 525, 564 and 692 (15-29 links each) then failed the joint test at 1.1-1.8 times
// their thresholds, and none named a suspect: no good cluster was inconsistent, and the bending
// cluster was larger than each of them. 764 of 895 true loops, 1 wrong. A failing cluster now
// also weighs the lone links of larger good clusters; the wrong link, near no other link of its
// cluster, is challenged alone.
TEST_CASE("Intel + 1000 local, seed 14: a wrong link inside a larger good cluster is challenged",
          "[datasets][irrr]") {
  const CorruptedRun run = RunCorrupted("intel/vertigo/intel.g2o", OutlierMode::kLocal, 1000, 14);
  CheckNoneWrongRecallAtLeast99(run);
}

// A first cluster holding many wrong links must not set the variance factor (docs/decisions.md,
// "The variance factor"). Manhattan + 1000 local-grouped, seed 3: the first cluster has 132
// links, the median of all their pairs says 1, and its consistent set's sample 1.9; without the
// concentration step the factor stays at 1 for 14 steps and 80 wrong loops are accepted. The
// clean factor is 0.023 (chi2 146 at the oracle).
TEST_CASE(
    "Manhattan + 1000 local-grouped, seed 3: a contaminated first cluster does not set "
    "the variance factor",
    "[datasets][irrr]") {
  const CorruptedRun run = RunCorrupted(
      "manhattan/vertigo/Olson/manhattanOlson3500.g2o", OutlierMode::kLocalGrouped, 1000, 3);
  CheckNoneWrongRecallAtLeast99(run);
  CHECK(LargestFactorDecidedAt(run.steps) < 0.05);
}

// Manhattan + 1000 local-grouped in groups of 10 (seed 1): the group 2261-2270 -> 2242-2251
// (claims about 2 m and 0.1 rad off across 19 poses) is clustered with a true revisit of 26 links.
// Judged at that cluster's own factor (twice the global one, which the group itself raised) it
// passed: 10 wrong loops, ATE 0.889 m against the oracle's 0.794. A cluster of several runs is
// judged at most at the lowest of its runs' own factors.
TEST_CASE(
    "Manhattan + 1000 local-grouped in groups of 10: a wrong run does not raise the factor "
    "its cluster is judged at",
    "[datasets][irrr]") {
  const CorruptedRun run = RunCorrupted(
      "manhattan/vertigo/Olson/manhattanOlson3500.g2o", OutlierMode::kLocalGrouped, 1000, 1, 10);
  CheckNoneWrongRecallAtLeast99(run);
}

// Intel + 1000 random-grouped (seed 1): the group 480-482 -> 850-852 claims a pose 0.4 m and 5
// degrees from the truth. It came in with a true cluster of 69 links judged at that cluster's own
// factor (3 wrong loops, ATE 0.046 m from the oracle). At the lowest of its runs' factors the
// cluster fails and is judged run by run, each run at its own factor: the group stays out and the
// true runs, whose matches share their error, pass.
TEST_CASE("Intel + 1000 random-grouped: the near-true wrong group stays out, recall at least 0.99",
          "[datasets][irrr]") {
  const CorruptedRun run =
      RunCorrupted("intel/vertigo/intel.g2o", OutlierMode::kRandomGrouped, 1000, 1);
  CheckNoneWrongRecallAtLeast99(run);
}

// Intel + 1000 random wrong loops, seed 6: a 91-link revisit failed the joint test by 1% (one
// true link that fails on its own, 549 -> 898, d^2 10.1) and was judged run by run. Its runs of
// three, too short for a factor of their own, were judged at the global 0.16, and two true ones
// fell: the one holding 549 -> 898, and 786-789 -> 934-936 (chi2 increase 6.4 against 5.5). 885
// of 895. At the lowest own factor of the cluster's longer runs, 0.21, the second passes: 888.
TEST_CASE("Intel + 1000 random, seed 6: a short run is judged at its place's factor",
          "[datasets][irrr]") {
  const CorruptedRun run = RunCorrupted("intel/vertigo/intel.g2o", OutlierMode::kRandom, 1000, 6);
  CheckNoneWrongRecallAtLeast99(run);
}

// Intel + 1000 wrong loops, three seeds the engine was not tuned on: a wrong group or link came
// in with a large true cluster, its error diluted by the cluster's many degrees of freedom.
// Local-grouped seed 19's group 654-656 -> 629-631 (0.5 m and 0.07 rad off the oracle, where
// Intel's true loops lie within 0.15 m and 0.04 rad) came in with a revisit of 91 links; local
// seed 18's 833 -> 818 and random seed 20's 657 -> 675 (0.3-0.4 m off) with clusters of 37 and
// 56. At the cluster's joint optimum their removal statistics stood at 2.2-2.8 times their
// thresholds: they leave it before it is accepted (BendingParts) and fail on their own.
TEST_CASE("Intel + 1000, seeds 18-20: a wrong part of a large true cluster leaves it",
          "[datasets][irrr]") {
  struct Case {
    OutlierMode mode;
    int seed;
  };
  const Case c = GENERATE(Case{OutlierMode::kLocal, 18},
                          Case{OutlierMode::kLocalGrouped, 19},
                          Case{OutlierMode::kRandom, 20});
  CAPTURE(OutlierModeName(c.mode), c.seed);
  const CorruptedRun run = RunCorrupted("intel/vertigo/intel.g2o", c.mode, 1000, c.seed);
  CheckNoneWrongRecallAtLeast99(run);
}

// Vertigo's ring (434 poses, 26 true loops, heading information 60 times too loose) + 100
// random wrong loops, seed 7: one wrong link fits the first cluster by bending the odometry, its
// own d^2 0.4, and the sample comes out at 27 (used as 1: the wrong link was accepted, ATE 55 m).
// Leaving out the link whose removal lowers the cluster's chi2 most brings it to 0.17.
TEST_CASE("Ring + 100 random, seed 7: a wrong link that bends the odometry leaves the sample",
          "[datasets][irrr]") {
  const CorruptedRun run = RunRing(OutlierMode::kRandom, 100, 7);
  CheckRingDecidedAtItsOwnFactor(run);
  CHECK(run.pending_in_clusters == 0);
}

// The same ring + 1000 random wrong loops, seed 11: eq. 6 chains wrong links into clusters whose
// samples, cleaned, still stood at 32 to 222 times the information as given; the factor became
// known at 1 and a wrong link (418 -> 249) went in with the true revisit. Samples above their
// threshold at the information as given are not noise and give none: the first clean one says
// 0.13, and the revisit is judged there.
TEST_CASE("Ring + 1000 random, seed 11: a sample failing at the information as given gives none",
          "[datasets][irrr]") {
  const CorruptedRun run = RunRing(OutlierMode::kRandom, 1000, 11);
  CheckRingDecidedAtItsOwnFactor(run);
}

// The ring + 100 random-grouped wrong loops, seed 19: the cluster of the last revisit holds its
// 26 true loops and 34 wrong links, most pairs involve a wrong one, and its pairs' median says 1.
// The set consistent at 1 holds the true loops and two wrong groups (123-125 -> 263-265 and
// 291-293 -> 70-72) and says 2.1; its own pairs' median is 0.59. With a concentration step only
// below half the scale, leave-one-out took one group out, the sample said 0.79, and both groups
// went in with the true loops (6 wrong, the factor 1 at the end). Concentrating at 0.59 leaves
// one group out, leave-one-out the other: the sample says 0.14, nothing wrong is accepted.
TEST_CASE("Ring + 100 random-grouped, seed 19: a set mixing in wrong groups is concentrated",
          "[datasets][irrr]") {
  const CorruptedRun run = RunRing(OutlierMode::kRandomGrouped, 100, 19);
  CheckRingDecidedAtItsOwnFactor(run);
}

// The ring + 100 random wrong loops, seed 20: the cluster of the last revisit chains 19 wrong links
// from pose 246 on to the 26 true loops, and its set consistent at the pairs' scale holds the true
// loops and one wrong link, 58 -> 246, across the ring. Pairwise, that link agrees with each true
// loop (the ring's heading information is loose), and the set's sample, 0.77, is below 1, so
// nothing cleaned it: the link went in with the true loops at 0.78 (ATE 41.6 m from the oracle).
// Without it the rest says 0.14, and the chi2 it adds (51.3 over 3 degrees of freedom) is 20
// times its F test's threshold at that scale.
TEST_CASE("Ring + 100 random, seed 20: a lone link the rest of its set refutes leaves the sample",
          "[datasets][irrr]") {
  const CorruptedRun run = RunRing(OutlierMode::kRandom, 100, 20);
  CheckRingDecidedAtItsOwnFactor(run);
}

// The ring + 1000 random-grouped wrong loops, seed 9: no sample is clean before the flush, which
// judges what waits at the information as given. Algorithm 1 left the revisit's cluster (681
// links chained by eq. 6) with a wrong group (104-106 -> 414-416) and split its true loops off in
// two parts (17 and 9 links). Judged in that order, the group went in, both true parts then
// failed the joint test against it (chi2 increase 251 against 88), and three more wrong groups
// followed: 12 wrong, no true loop. The largest part is judged first now.
TEST_CASE("Ring + 1000 random-grouped, seed 9: the largest part Algorithm 1 leaves is judged first",
          "[datasets][irrr]") {
  const CorruptedRun run = RunRing(OutlierMode::kRandomGrouped, 1000, 9);
  CheckNoneWrongEveryTrue(run);
}

// FRH (Freiburg hospital, Carlone's TORO file) is exact to its file's 4-6 decimals: its redundancy
// says a variance factor of 1.7e-8, and at that factor the rounding of a loop's numbers failed the
// tests (80 of 1505 true loops refused, with or without wrong ones). The factor stops at 1e-6.
TEST_CASE("FRH, exact to its file's decimals: every true loop accepted at the factor's floor",
          "[datasets][irrr]") {
  for (OutlierMode mode : {OutlierMode::kRandom, OutlierMode::kLocalGrouped}) {
    INFO(OutlierModeName(mode));
    const CorruptedRun run = RunCorrupted("frh/carlone_toro/FRH_P_toro.graph", mode, 100, 7);
    CheckNoneWrongEveryTrue(run);
    CHECK(run.steps.back().variance_factor == Approx(1e-6));
  }
}

// CSAIL (128 true loops) + 1000 local wrong loops in groups of 3, seeds 7 and 8: the first
// cluster to carry 30 degrees of freedom mixes true links and wrong groups, and its sample stood
// at 3.4 after cleaning. It made the factor known at 1, and the first steps let wrong groups in
// (6 and 3), reversed only once the clusters' median fell (to 0.12) and the good set's factor,
// which those groups raised, was capped at twice it. A sample above its threshold at the
// information as given gives none now: the factor stays at or below 0.48 (seed 7: 6 reversals on
// the way, 127 of 128 true loops at the end) and 0.069 (seed 8: 128 of 128).
TEST_CASE("CSAIL + 1000 local-grouped: a first cluster that mixes in wrong groups gives no factor",
          "[datasets][irrr]") {
  for (int seed : {7, 8}) {
    INFO("seed " << seed);
    const CorruptedRun run =
        RunCorrupted("csail/sesync/CSAIL.g2o", OutlierMode::kLocalGrouped, 1000, seed);
    INFO(run.accepted_true << " of " << run.true_loops << " true loops accepted");
    INFO("largest factor decided at " << LargestFactorDecidedAt(run.steps) << ", reversals "
                                      << Reversals(run.steps) << ", last factor "
                                      << run.steps.back().variance_factor);
    CHECK(run.accepted_wrong == 0);
    CHECK(run.accepted_true >= 0.97 * run.true_loops);
    CHECK(LargestFactorDecidedAt(run.steps) < 0.6);
    CHECK(run.steps.back().variance_factor < 0.15);
  }
}

// The parking garage's information is some 40000 times looser than its noise (factor 2.5e-5), so
// wrong loops a few poses long agree with each other by bending its odometry. With 1000 of them
// (seed 11) they outnumber the true loops of the first revisits: the first cluster's set, chosen
// consistent at its pairs' scale 0.020, held 18 wrong links of 76 and said 0.64. Being below 1 it
// was taken as clean, the factor was known at 0.44, and 158 wrong loops went in (recall 0.26,
// 510 s). A sample ten times its cluster's pairwise scale is cleaned like one above 1: the factor
// is 2.5e-5 from the first step. The clean file itself loses 6% of its true loops, whose d^2
// stand 2 to 30 times their thresholds (BENCHMARKS.md); here as many. About 50-70 s.
TEST_CASE(
    "Parking garage + 1000 local, seed 11: a sample far above its set's pairwise scale is cleaned",
    "[datasets][irrr]") {
  const CorruptedRun run =
      RunCorrupted<Pose3>("garage/parking-garage.g2o", OutlierMode::kLocal, 1000, 11);
  INFO(run.accepted_true << " of " << run.true_loops << " true loops accepted");
  INFO("largest factor decided at " << LargestFactorDecidedAt(run.steps));
  CHECK(run.accepted_wrong == 0);
  CHECK(run.accepted_true >= 0.92 * run.true_loops);
  CHECK(LargestFactorDecidedAt(run.steps) < 1e-4);
}

// Torus3D + 1000 random wrong loops, seed 7: the wrong 4936 -> 2427 (8.5 m and 92 degrees off)
// arrives while the loops of the 100 poses before it are still open, so it hangs on a loose tail
// (0.05 rad of heading per step). Its redundancy number (0.1013) let it be judged, and at the
// joint optimum the tail turned to fit it, under its threshold, though its linearized statistic
// was 2.7 times that threshold; the true 4936 -> 36 then failed against it (120.8 against
// 118.3). Held while its linearized statistic refuses it, it never gets in (it ends pending), and
// the true 4936 -> 36 is accepted.
TEST_CASE("Torus3D + 1000 random, seed 7: a lone link only a bend can fit waits",
          "[datasets][irrr]") {
  const CorruptedRun run =
      RunCorrupted<Pose3>("torus3d/torus3D.g2o", OutlierMode::kRandom, 1000, 7);
  CheckNoneWrongEveryTrue(run);
}

// Vertigo's Ring City (2361 poses, 901 true loops) + 1000 wrong loops in groups of 3, seed 9: the
// true revisit 2048-2083 -> 102-137 (36 links) failed its joint test against two wrong groups
// accepted before it, 1994-1996 -> 454-456 and 1177-1179 -> 1903-1905. Only the first stood out
// by its consistency index; without it the revisit still failed (increase 26.0 against 24.0), and
// 36 true loops stayed out (ATE 22 m against the oracle). At the revisit's trial without the
// first, the second's removal statistic is 5.4 times its threshold: named too, both leave.
TEST_CASE("Ring City + 1000 random-grouped, seed 9: a failed challenge names what else bends",
          "[datasets][irrr]") {
  const CorruptedRun run = RunCorrupted(
      "ringCity/vertigo/originalDataset/ringCity.g2o", OutlierMode::kRandomGrouped, 1000, 9);
  CheckNoneWrongEveryTrue(run);
  CHECK(Reversals(run.steps) >= 1);
}

// + 1000 local wrong loops in groups of 3: a wrong group accepted in the first steps, while little
// held the map, fits by bending odometry over tens of poses; no edge fails, so no later check
// looked at it. Ring City seed 9 (990-992 -> 940-942, 11 m off, step 10), CSAIL seed 10 (step 3)
// and FR079 seed 9 (step 2, at the factor 0.122, later 0.061). At the end their removal
// statistics stand 5.3, 5.6 and 2.9 times their thresholds. Judged again once the good set has
// doubled or the factor has fallen, they leave.
TEST_CASE(
    "Ring City / CSAIL / FR079 + 1000 local-grouped: early groups judged again as evidence grows",
    "[datasets][irrr]") {
  const std::pair<std::string, int> cases[] = {{"ringCity/vertigo/originalDataset/ringCity.g2o", 9},
                                               {"csail/sesync/CSAIL.g2o", 10},
                                               {"fr079/carlone_toro/FR079_P_toro.graph", 9}};
  for (const auto& [file, seed] : cases) {
    INFO(file << ", seed " << seed);
    const CorruptedRun run = RunCorrupted(file, OutlierMode::kLocalGrouped, 1000, seed);
    INFO(run.accepted_true << " of " << run.true_loops << " true loops accepted");
    CHECK(run.accepted_wrong == 0);
    CHECK(run.accepted_true >= 0.98 * run.true_loops);
    CHECK(Reversals(run.steps) >= 1);
  }
}

// KITTI 05 (place recognition at alpha 0.5, labelled true loops). The matches along one revisit
// share their error, so the clusters' own redundancy puts the variance factor at 0.16; the good
// set's, which also sees how the revisits disagree with each other and with the odometry, at
// 0.27. The factor used is the larger, and the clusters refused while it was lower are judged
// again: 59 of the 62 true loops accepted (57 with the clusters' factor alone), none wrong.
TEST_CASE("KITTI 05: the good set's variance factor, and what a lower one refused judged again",
          "[datasets][irrr]") {
  GraphFile<Pose2> file;
  PoseGraph<Pose2> graph;
  REQUIRE(Load("kitti_rrr/05/kitti_05_alpha_0.50.g2o", ReadOptions(), &file, &graph).ok());
  std::ifstream labels(SharedPath("kitti_rrr/05/kitti_05_alpha_0.50_GT_LC.txt"));
  REQUIRE(labels.good());
  std::set<std::pair<int, int>> true_pairs;
  for (int a, b; labels >> a >> b;) true_pairs.insert({std::min(a, b), std::max(a, b)});
  REQUIRE(true_pairs.size() == 62);

  std::vector<StepResult> steps;
  const std::vector<LoopDecision> decisions =
      RunIncrementalIrrr<Pose2>(graph, IrrrOptions(), nullptr, &steps);
  REQUIRE(steps.size() >= 2);
  int accepted_true = 0;
  int accepted_wrong = 0;
  int good_before_last = 0;  // loops in the good set when the last step began
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose2>& edge = graph.edge(e);
    if (edge.kind != EdgeKind::kLoop || decisions[e].state != LoopState::kAccepted) continue;
    const bool labelled_true =
        true_pairs.count({std::min(edge.from, edge.to), std::max(edge.from, edge.to)}) > 0;
    (labelled_true ? accepted_true : accepted_wrong) += 1;
    good_before_last += decisions[e].step < steps.back().step ? 1 : 0;
  }
  CHECK(accepted_wrong == 0);
  CHECK(accepted_true >= 59);
  // The last step's factor is the good set's as the step before left it: its chi2 over the
  // chi-square median of its degrees of freedom (3 per loop, one session).
  const double good_set_factor =
      steps[steps.size() - 2].chi2 / ChiSquareMedian(3.0 * good_before_last);
  CHECK(good_set_factor > 0.25);
  CHECK(steps.back().variance_factor == Approx(good_set_factor).epsilon(1e-9));
}

// Bovisa (RAWSEEDS, bag-of-words loops of the RRR author), never tuned on: its GT_GPS file holds
// one fix per 10 odometry poses (their steps match the odometry's 10-pose steps to 0.6%). The
// rigidly aligned RMS distance to those fixes, measured: 4.15 and 5.85 m; odometry
// alone 11.3 and 20.6 m, every loop trusted 80.7 and 59.8 m, batch RRR on 04 66.9 m (one wrong
// cluster bends the whole map).
TEST_CASE("Bovisa 04 and 06: the map stays within metres of GPS", "[datasets][irrr]") {
  struct Sequence {
    const char* name;
    double max_rmse_m;
  };
  const Sequence sequence = GENERATE(Sequence{"04", 5.0}, Sequence{"06", 7.0});
  GraphFile<Pose2> file;
  PoseGraph<Pose2> graph;
  const std::string folder = "rrr_bovisa/Bovisa" + std::string(sequence.name);
  REQUIRE(Load(folder + "_odometry_bow_tr.g2o", ReadOptions(), &file, &graph).ok());
  GraphFile<Pose2> gps_file;
  PoseGraph<Pose2> gps;
  REQUIRE(Load(folder + "_GT_GPS.g2o", ReadOptions(), &gps_file, &gps).ok());

  constexpr int kStride = 10;
  std::vector<Pose2> reference(graph.num_vertices());
  std::vector<int> fixed;  // graph vertices with a GPS fix
  for (int k = 0; k < gps.num_vertices(); ++k) {
    const int v = graph.FindVertex(gps.vertex(k).id * kStride);
    if (v < 0) continue;
    reference[v] = gps.initial_estimate()[k];
    fixed.push_back(v);
  }
  REQUIRE(fixed.size() >= 1000);

  std::vector<Pose2> estimate;
  RunIncrementalIrrr<Pose2>(graph, IrrrOptions(), &estimate, nullptr);
  const double rmse = AbsoluteTrajectoryError(estimate, reference, {fixed}).rmse_m;
  const double odometry_rmse =
      AbsoluteTrajectoryError(graph.OdometryEstimate(), reference, {fixed}).rmse_m;
  CHECK(odometry_rmse > 10.0);
  CHECK(rmse < sequence.max_rmse_m);
}

// New College (the iRRR paper's second dataset, never tuned on): visual odometry and bag-of-words
// loops with a geometric check, from the RRR author's repository. Its file holds nine EDGE_SE2 1 1.
constexpr char kNewCollege[] = "rrr_newcollege/NewCollege_odometry_bow_tr.g2o";

TEST_CASE("New College's self-loops are an error unless skipping invalid edges is asked for",
          "[datasets]") {
  GraphFile<Pose2> file;
  PoseGraph<Pose2> graph;
  const Status strict = Load(kNewCollege, ReadOptions(), &file, &graph);
  REQUIRE_FALSE(strict.ok());
  CHECK_THAT(strict.message(), Catch::Contains("line 25632: EDGE_SE2 1 1: self-loop"));
  ReadOptions skip;
  skip.skip_invalid_edges = true;
  REQUIRE(Load(kNewCollege, skip, &file, &graph).ok());
  REQUIRE(file.skipped.size() == 9);
  for (size_t k = 0; k < file.skipped.size(); ++k) {
    CHECK(file.skipped[k].line == 25632 + static_cast<int>(k));
    CHECK_THAT(file.skipped[k].message, Catch::EndsWith("EDGE_SE2 1 1: self-loop"));
  }
  CHECK(graph.num_vertices() == 12816);
  CHECK(graph.num_edges() == 13465 - 9);
  CHECK(graph.num_sessions() == 1);
}

// The accepted state of each loop, in file order (a split file keeps its loops in that order).
std::vector<char> AcceptedLoops(const PoseGraph<Pose2>& graph,
                                const std::vector<LoopDecision>& decisions) {
  std::vector<char> accepted;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind != EdgeKind::kLoop) continue;
    accepted.push_back(decisions[e].state == LoopState::kAccepted ? 1 : 0);
  }
  return accepted;
}

TEST_CASE(
    "New College in three sessions, each in its own frame, becomes one map with the decisions of "
    "one session, and batch RRR agrees with them",
    "[datasets][irrr]") {
  ReadOptions skip;
  skip.skip_invalid_edges = true;
  GraphFile<Pose2> file;
  PoseGraph<Pose2> one;
  REQUIRE(Load(kNewCollege, skip, &file, &one).ok());
  REQUIRE(SplitIntoSessions<Pose2>({4000, 8000}, &file).ok());
  PoseGraph<Pose2> three;
  std::vector<int> unused;
  REQUIRE(BuildPoseGraph(file, &three, &unused).ok());
  REQUIRE(three.num_sessions() == 3);

  const std::vector<char> in_one =
      AcceptedLoops(one, RunIncrementalIrrr<Pose2>(one, IrrrOptions(), nullptr, nullptr));
  const std::vector<LoopDecision> decisions =
      RunIncrementalIrrr<Pose2>(three, IrrrOptions(), nullptr, nullptr);
  const std::vector<char> in_three = AcceptedLoops(three, decisions);
  REQUIRE(in_one.size() == 641);
  REQUIRE(in_three.size() == in_one.size());
  CHECK(SessionComponents(three, testing::MapEdges(three, decisions)) ==
        std::vector<int>{0, 0, 0});  // one map
  // Where each session starts changes no decision (but for rounding).
  int differ = 0;
  int accepted = 0;
  for (size_t k = 0; k < in_one.size(); ++k) {
    differ += in_one[k] != in_three[k] ? 1 : 0;
    accepted += in_one[k];
  }
  CHECK(differ <= 2);
  // The paper's batch RRR, another reading of the same tests, keeps nearly the same loops: a loop
  // accepted by one and refused by the other is rare (6 and 5 of about 527 when measured).
  const std::vector<char> batch =
      AcceptedLoops(one, RunBatchRrr<Pose2>(one, IrrrOptions(), nullptr));
  int only_irrr = 0;
  int only_batch = 0;
  for (size_t k = 0; k < in_one.size(); ++k) {
    only_irrr += in_one[k] && !batch[k] ? 1 : 0;
    only_batch += batch[k] && !in_one[k] ? 1 : 0;
  }
  INFO("accepted " << accepted << ", only iRRR " << only_irrr << ", only batch " << only_batch);
  CHECK(only_irrr <= accepted / 50);
  CHECK(only_batch <= accepted / 50);
}

// Kimera-RPGO's test graphs (3D, GTSAM Symbol keys: the robot's letter in the top byte): each robot
// drives a near-straight line, and its loop hypotheses repeat an odometry step (about 1 m forward)
// between poses 6 to 19 apart. Kimera-RPGO's own tests expect none of them to pass its odometry
// check; the two robots, read as one file, share no loop and stay two maps.
TEST_CASE("Kimera-RPGO's two robots: every loop hypothesis refused, two maps", "[datasets][irrr]") {
  std::stringstream both;
  for (const char* robot : {"robot_a.g2o", "robot_b.g2o"}) {
    std::ifstream in(SharedPath(std::string("multirobot/kimera_rpgo/") + robot));
    REQUIRE(in.good());
    both << in.rdbuf();
  }
  GraphFile<Pose3> file;
  REQUIRE(ReadGraphFile(both, FileFormat::kG2o, ReadOptions(), &file).ok());
  PoseGraph<Pose3> graph;
  std::vector<int> unused;
  REQUIRE(BuildPoseGraph(file, &graph, &unused).ok());
  REQUIRE(graph.num_vertices() == 50 + 42);
  REQUIRE(graph.num_sessions() == 2);
  constexpr std::uint64_t kRobotB = std::uint64_t{'b'} << 56;
  CHECK(graph.FindVertex(static_cast<std::int64_t>(kRobotB + 41)) >= 0);

  const std::vector<LoopDecision> decisions =
      RunIncrementalIrrr<Pose3>(graph, IrrrOptions(), nullptr, nullptr);
  int loops = 0;
  int refused = 0;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind != EdgeKind::kLoop) continue;
    ++loops;
    const LoopState state = decisions[e].state;
    if (state != LoopState::kAccepted && state != LoopState::kPending) ++refused;
  }
  CHECK(loops == 3 + 2);
  CHECK(refused == loops);
  CHECK(SessionComponents(graph, testing::MapEdges(graph, decisions)) == std::vector<int>{0, 1});
}

}  // namespace
}  // namespace irrr
