#include "core/robust_solve.h"

#include <cmath>
#include <vector>

#include <catch2/catch.hpp>

#include "core/optimizer.h"
#include "core/outliers.h"
#include "core/test_statistics.h"
#include "tests/synthetic_graph.h"

namespace irrr {
namespace {

using testing::MakeSyntheticGraph;
using testing::RelativeDifference;
using testing::SyntheticGraph;
using testing::SyntheticOptions;

// A noisy synthetic graph whose information is ten times conservative, as public datasets' is
// (true loops end far below Phi = 1 and the TLS bound), and the same graph with `wrong` random
// wrong loops appended; is_true marks the first graph's loops in the second.
template <class Pose>
struct CleanAndCorrupted {
  SyntheticGraph<Pose> clean;
  PoseGraph<Pose> corrupted;
  std::vector<char> is_true;
};

template <class Pose>
CleanAndCorrupted<Pose> MakeCase(int wrong, OutlierMode mode, uint32_t seed) {
  SyntheticOptions options = testing::NoisyOptions<Pose>(seed);
  options.information_scale = 0.1;
  CleanAndCorrupted<Pose> out;
  out.clean = MakeSyntheticGraph<Pose>(options);
  out.corrupted = out.clean.graph;
  out.is_true.resize(out.corrupted.num_edges());
  for (int e = 0; e < out.corrupted.num_edges(); ++e) {
    out.is_true[e] = out.corrupted.edge(e).kind == EdgeKind::kLoop;
  }
  OutlierOptions outlier_options;
  outlier_options.mode = mode;
  outlier_options.count = wrong;
  outlier_options.seed = seed;
  std::vector<OutlierLink<Pose>> links;
  REQUIRE(MakeOutliers(out.corrupted, outlier_options, &links).ok());
  for (const OutlierLink<Pose>& link : links) {
    REQUIRE(out.corrupted.AddLoop(link.from, link.to, link.measurement, link.information, nullptr)
                .ok());
    out.is_true.push_back(0);
  }
  return out;
}

// The clean graph's optimum from its dead reckoning.
template <class Pose>
std::vector<Pose> CleanOptimum(const PoseGraph<Pose>& graph) {
  std::vector<Pose> estimate = graph.OdometryEstimate();
  Optimizer<Pose> optimizer;
  const OptimizerSummary summary =
      optimizer.Solve(graph, std::vector<char>(graph.num_edges(), 1), &estimate);
  REQUIRE(summary.termination == TerminationType::kConvergence);
  return estimate;
}

TEMPLATE_TEST_CASE("A weighted solve: weight 0 is the edge left out, a common factor scales chi2",
                   "[robust]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  const SyntheticGraph<Pose> synthetic = MakeSyntheticGraph<Pose>(testing::NoisyOptions<Pose>(3));
  const PoseGraph<Pose>& graph = synthetic.graph;
  REQUIRE(synthetic.loop_edges.size() >= 2);
  const int left_out = synthetic.loop_edges[0];

  std::vector<char> without(graph.num_edges(), 1);
  without[left_out] = 0;
  std::vector<Pose> expected = graph.OdometryEstimate();
  Optimizer<Pose> plain;
  const OptimizerSummary reference = plain.Solve(graph, without, &expected);
  REQUIRE(reference.termination == TerminationType::kConvergence);

  std::vector<double> weights(graph.num_edges(), 1.0);
  weights[left_out] = 0.0;
  std::vector<Pose> weighted = graph.OdometryEstimate();
  Optimizer<Pose> optimizer;
  const OptimizerSummary summary =
      optimizer.SolveWeighted(graph, std::vector<char>(graph.num_edges(), 1), weights, &weighted);
  REQUIRE(summary.termination == TerminationType::kConvergence);
  double translation_m = 0.0;
  double rotation_rad = 0.0;
  RelativeDifference(expected, weighted, 0, &translation_m, &rotation_rad);
  CHECK(translation_m < 1e-6);
  CHECK(rotation_rad < 1e-6);
  CHECK(summary.final_chi2 == Approx(reference.final_chi2).epsilon(1e-6));
  // edge_chi2 stays unweighted: the left-out loop's own d^2 at the estimate.
  CHECK(summary.edge_chi2[left_out] == Approx(EdgeChi2(graph.edge(left_out), weighted)));

  std::fill(weights.begin(), weights.end(), 4.0);
  std::vector<Pose> scaled = graph.OdometryEstimate();
  std::vector<Pose> unscaled = graph.OdometryEstimate();
  const OptimizerSummary four =
      optimizer.SolveWeighted(graph, std::vector<char>(graph.num_edges(), 1), weights, &scaled);
  const OptimizerSummary one =
      plain.Solve(graph, std::vector<char>(graph.num_edges(), 1), &unscaled);
  CHECK(four.final_chi2 == Approx(4.0 * one.final_chi2).epsilon(1e-6));
  RelativeDifference(unscaled, scaled, 0, &translation_m, &rotation_rad);
  CHECK(translation_m < 1e-6);
  CHECK(rotation_rad < 1e-6);
}

TEMPLATE_TEST_CASE("DCS and GNC give back the clean optimum of a graph with wrong loops",
                   "[robust]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  for (OutlierMode mode : {OutlierMode::kRandom, OutlierMode::kRandomGrouped}) {
    for (RobustKernel kernel : {RobustKernel::kDcs, RobustKernel::kGncTls}) {
      INFO(RobustKernelName(kernel) << ", " << OutlierModeName(mode));
      const CleanAndCorrupted<Pose> c = MakeCase<Pose>(30, mode, 5);
      const std::vector<Pose> clean = CleanOptimum(c.clean.graph);
      RobustOptions options;
      options.kernel = kernel;
      RobustResult<Pose> result;
      REQUIRE(RobustSolve(c.corrupted, options, c.corrupted.initial_estimate(), &result).ok());
      int accepted_true = 0;
      int accepted_wrong = 0;
      int true_loops = 0;
      for (int e = 0; e < c.corrupted.num_edges(); ++e) {
        if (c.corrupted.edge(e).kind != EdgeKind::kLoop) {
          CHECK(result.weight[e] == 1.0);
          continue;
        }
        true_loops += c.is_true[e] ? 1 : 0;
        if (!result.Accepted(e)) continue;
        (c.is_true[e] ? accepted_true : accepted_wrong) += 1;
      }
      CHECK(accepted_wrong == 0);
      CHECK(accepted_true == true_loops);
      // The clean graph's map: GNC drops the wrong loops (weight 0), so it is the clean optimum to
      // the solver's tolerance; DCS keeps each at s^2 ~ (2 Phi / d^2)^2, a pull that moves the
      // helix (5 cm, 0.01 rad noise) by 2 cm and 0.005 rad.
      std::vector<Pose> estimate(result.estimate.begin(),
                                 result.estimate.begin() + c.clean.graph.num_vertices());
      double translation_m = 0.0;
      double rotation_rad = 0.0;
      RelativeDifference(clean, estimate, 0, &translation_m, &rotation_rad);
      const bool dcs = kernel == RobustKernel::kDcs;
      CHECK(translation_m < (dcs ? 0.03 : 1e-3));
      CHECK(rotation_rad < (dcs ? 0.01 : 1e-4));
    }
  }
}

TEST_CASE("DCS's scale and GNC's threshold follow their papers' formulas", "[robust]") {
  // One loop on a two-pose chain: the loop disagrees with the odometry by a known amount, and
  // with the odometry's information far larger the estimate stays on the odometry, so the loop's
  // d^2 is known in advance.
  PoseGraph<Pose2> graph;
  int session = -1;
  REQUIRE(graph.AddSession(0, &session).ok());
  int a = -1;
  int b = -1;
  const Pose2 odometry(1.0, 0.0, 0.0);
  const Pose2::Matrix odometry_information = 1e8 * Pose2::Matrix::Identity();
  REQUIRE(graph.AddPose(session, 0, 0.0, Pose2(), nullptr, nullptr, &a).ok());
  REQUIRE(graph.AddPose(session, 1, 1.0, odometry, &odometry, &odometry_information, &b).ok());
  int loop = -1;
  // 0.5 m off along x with unit information: d^2 = 0.25 wherever the odometry holds.
  REQUIRE(graph.AddLoop(a, b, Pose2(1.5, 0.0, 0.0), Pose2::Matrix::Identity(), &loop).ok());
  for (double phi : {0.05, 1.0}) {
    RobustOptions options;
    options.dcs_phi = phi;
    RobustResult<Pose2> result;
    REQUIRE(RobustSolve(graph, options, graph.initial_estimate(), &result).ok());
    CHECK(result.edge_chi2[loop] == Approx(0.25).epsilon(1e-6));
    CHECK(result.weight[loop] == Approx(std::min(1.0, 2.0 * phi / (phi + 0.25))).epsilon(1e-6));
    CHECK(result.threshold[loop] == 3.0 * phi);
    CHECK(result.Accepted(loop) == (0.25 < 3.0 * phi));
  }
  // GNC: d^2 = 0.25 is below the 99% bound of 3 dof (11.34): an inlier of the trusting solve,
  // accepted without any reweighting.
  RobustOptions gnc;
  gnc.kernel = RobustKernel::kGncTls;
  RobustResult<Pose2> result;
  REQUIRE(RobustSolve(graph, gnc, graph.initial_estimate(), &result).ok());
  CHECK(result.threshold[loop] == Approx(ChiSquareQuantile(0.99, 3.0)));
  CHECK(result.threshold[loop] == Approx(11.345).epsilon(1e-4));
  CHECK(result.outer_iterations == 0);
  CHECK(result.Accepted(loop));
  // 5 m off: d^2 = 25 > 11.34, an outlier that GNC drops (weight 0) and DCS scales down to
  // 2 / (1 + 25).
  PoseGraph<Pose2> far = graph;
  int far_loop = -1;
  REQUIRE(far.AddLoop(a, b, Pose2(6.0, 0.0, 0.0), Pose2::Matrix::Identity(), &far_loop).ok());
  REQUIRE(RobustSolve(far, gnc, far.initial_estimate(), &result).ok());
  CHECK(result.weight[far_loop] == 0.0);
  CHECK(result.weight[loop] == 1.0);
  CHECK(result.converged);
  RobustOptions dcs;
  REQUIRE(RobustSolve(far, dcs, far.initial_estimate(), &result).ok());
  CHECK(result.weight[far_loop] == Approx(2.0 / 26.0).epsilon(1e-5));
  CHECK_FALSE(result.Accepted(far_loop));
}

TEST_CASE("Robust options out of range are refused", "[robust]") {
  RobustOptions options;
  CHECK(options.Validate().ok());
  options.dcs_phi = 0.0;
  CHECK_FALSE(options.Validate().ok());
  options = RobustOptions();
  options.inlier_probability = 1.0;
  CHECK_FALSE(options.Validate().ok());
  options = RobustOptions();
  options.gnc_mu_step = 1.0;
  CHECK_FALSE(options.Validate().ok());
}

}  // namespace
}  // namespace irrr
