#include "core/optimizer.h"

#include <cmath>
#include <limits>
#include <random>

#include <catch2/catch.hpp>

#include "core/outliers.h"
#include "tests/synthetic_graph.h"

namespace irrr {
namespace {

using testing::MakeSyntheticGraph;
using testing::RelativeDifference;
using testing::SyntheticGraph;
using testing::SyntheticOptions;

// Zero-noise graphs have an exact solution; Gauss-Newton reaches it to rounding.
constexpr double kExactToleranceM = 1e-9;
constexpr double kExactToleranceRad = 1e-9;

std::vector<char> AllActive(int num_edges) { return std::vector<char>(num_edges, 1); }

// A noisy 300-pose grid world with 20 random wrong loops: from dead reckoning, full Gauss-Newton
// steps overshoot, and the solve crawls towards an optimum far above zero.
SyntheticGraph<Pose2> GridWithWrongLoops() {
  SyntheticOptions options;
  options.num_poses = 300;
  options.translation_sigma_m = 0.05;
  options.rotation_sigma_rad = 0.02;
  SyntheticGraph<Pose2> synthetic = MakeSyntheticGraph<Pose2>(options);
  OutlierOptions outlier_options;
  outlier_options.count = 20;
  std::vector<OutlierLink<Pose2>> outliers;
  REQUIRE(MakeOutliers(synthetic.graph, outlier_options, &outliers).ok());
  for (const OutlierLink<Pose2>& link : outliers) {
    REQUIRE(synthetic.graph.AddLoop(link.from, link.to, link.measurement, link.information, nullptr)
                .ok());
  }
  return synthetic;
}

// Ground truth moved by independent random errors per pose (not accumulated), far from the
// solution but in its basin.
template <class Pose>
std::vector<Pose> Perturbed(const std::vector<Pose>& poses, double scale, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0.0, scale);
  std::vector<Pose> out;
  for (const Pose& pose : poses) {
    typename Pose::Tangent noise;
    for (int k = 0; k < Pose::kDim; ++k) noise(k) = normal(rng);
    out.push_back(pose.Retract(noise));
  }
  return out;
}

TEMPLATE_TEST_CASE("A zero-noise graph is solved to ground truth within 1e-9",
                   "[optimizer]",
                   Pose2,
                   Pose3) {
  const auto algorithm =
      GENERATE(OptimizerAlgorithm::kGaussNewton, OptimizerAlgorithm::kLevenbergMarquardt);
  const uint32_t seed = GENERATE(1u, 2u, 3u);
  INFO("seed " << seed << " algorithm " << static_cast<int>(algorithm));
  SyntheticOptions options;
  options.num_poses = 400;
  options.seed = seed;
  const auto synthetic = MakeSyntheticGraph<TestType>(options);
  REQUIRE(synthetic.loop_edges.size() > 20);

  OptimizerOptions optimizer_options;
  optimizer_options.algorithm = algorithm;
  Optimizer<TestType> optimizer(optimizer_options);
  std::vector<TestType> estimate = Perturbed(synthetic.ground_truth, 0.05, seed);
  estimate[0] = synthetic.ground_truth[0];
  const OptimizerSummary summary =
      optimizer.Solve(synthetic.graph, AllActive(synthetic.graph.num_edges()), &estimate);
  INFO(summary.message);
  REQUIRE(summary.termination == TerminationType::kConvergence);
  REQUIRE(summary.estimate_updated);
  CHECK(summary.initial_chi2 > 1e3);
  CHECK(summary.final_chi2 < 1e-12);

  double translation_m = 0.0;
  double rotation_rad = 0.0;
  RelativeDifference(estimate, synthetic.ground_truth, 0, &translation_m, &rotation_rad);
  CHECK(translation_m < kExactToleranceM);
  CHECK(rotation_rad < kExactToleranceRad);
}

TEMPLATE_TEST_CASE("A noisy graph reaches a chi2 consistent with its degrees of freedom",
                   "[optimizer]",
                   Pose2,
                   Pose3) {
  const uint32_t seed = GENERATE(11u, 12u);
  INFO("seed " << seed);
  SyntheticOptions options;
  options.num_poses = 500;
  options.translation_sigma_m = 0.05;
  options.rotation_sigma_rad = 0.01;
  options.seed = seed;
  const auto synthetic = MakeSyntheticGraph<TestType>(options);
  std::vector<TestType> gauss_newton = synthetic.graph.initial_estimate();
  std::vector<TestType> levenberg = gauss_newton;

  Optimizer<TestType> gn;
  OptimizerOptions lm_options;
  lm_options.algorithm = OptimizerAlgorithm::kLevenbergMarquardt;
  Optimizer<TestType> lm(lm_options);
  const auto active = AllActive(synthetic.graph.num_edges());
  const OptimizerSummary gn_summary = gn.Solve(synthetic.graph, active, &gauss_newton);
  const OptimizerSummary lm_summary = lm.Solve(synthetic.graph, active, &levenberg);
  REQUIRE(gn_summary.termination == TerminationType::kConvergence);
  REQUIRE(lm_summary.termination == TerminationType::kConvergence);

  // At the optimum chi2 ~ chi2(dof), dof = residual rows - free parameters; five standard
  // deviations (sqrt(2 dof)) either side is a test that fails only on a wrong residual,
  // Jacobian or information.
  const double dof = gn_summary.residual_dimension - gn_summary.free_parameters;
  REQUIRE(dof > 100);
  CHECK(std::abs(gn_summary.final_chi2 - dof) < 5.0 * std::sqrt(2.0 * dof));
  // Both algorithms find the same minimum.
  CHECK(lm_summary.final_chi2 == Approx(gn_summary.final_chi2).epsilon(1e-6));
  double translation_m = 0.0;
  double rotation_rad = 0.0;
  RelativeDifference(gauss_newton, levenberg, 0, &translation_m, &rotation_rad);
  CHECK(translation_m < 1e-4);
  CHECK(rotation_rad < 1e-5);
  CHECK(gn_summary.final_chi2 < gn_summary.initial_chi2);
}

TEMPLATE_TEST_CASE("Per-edge chi2 and the summary's totals agree with direct evaluation",
                   "[optimizer]",
                   Pose2,
                   Pose3) {
  SyntheticOptions options;
  options.num_poses = 200;
  options.translation_sigma_m = 0.02;
  options.rotation_sigma_rad = 0.01;
  const auto synthetic = MakeSyntheticGraph<TestType>(options);
  std::vector<char> active = AllActive(synthetic.graph.num_edges());
  active[synthetic.loop_edges.front()] = 0;
  std::vector<TestType> estimate = synthetic.graph.initial_estimate();
  Optimizer<TestType> optimizer;
  const OptimizerSummary summary = optimizer.Solve(synthetic.graph, active, &estimate);
  REQUIRE(summary.edge_chi2.size() == static_cast<size_t>(synthetic.graph.num_edges()));
  double total = 0.0;
  for (int e = 0; e < synthetic.graph.num_edges(); ++e) {
    const double direct = EdgeChi2(synthetic.graph.edge(e), estimate);
    CHECK(summary.edge_chi2[e] == Approx(direct).epsilon(1e-12));
    if (active[e]) total += direct;
  }
  CHECK(summary.final_chi2 == Approx(total).epsilon(1e-12));
  CHECK(summary.num_active_edges == synthetic.graph.num_edges() - 1);
  CHECK(summary.residual_dimension == TestType::kDim * summary.num_active_edges);
  CHECK(summary.free_parameters == TestType::kDim * (synthetic.graph.num_vertices() - 1));
}

TEMPLATE_TEST_CASE("An inactive loop is the same as a graph without it",
                   "[optimizer]",
                   Pose2,
                   Pose3) {
  SyntheticOptions options;
  options.num_poses = 200;
  options.translation_sigma_m = 0.02;
  options.rotation_sigma_rad = 0.01;
  const auto synthetic = MakeSyntheticGraph<TestType>(options);
  const int dropped = synthetic.loop_edges[synthetic.loop_edges.size() / 2];

  // The same graph rebuilt without the dropped loop.
  PoseGraph<TestType> without;
  REQUIRE(without.AddSession(0, nullptr).ok());
  for (int v = 0; v < synthetic.graph.num_vertices(); ++v) {
    const TestType* odometry = nullptr;
    const typename TestType::Matrix* information = nullptr;
    for (const Edge<TestType>& e : synthetic.graph.edges()) {
      if (e.kind == EdgeKind::kOdometry && e.to == v) {
        odometry = &e.measurement;
        information = &e.information;
      }
    }
    REQUIRE(
        without
            .AddPose(0, v, v, synthetic.graph.initial_estimate()[v], odometry, information, nullptr)
            .ok());
  }
  for (int e : synthetic.loop_edges) {
    if (e == dropped) continue;
    const Edge<TestType>& edge = synthetic.graph.edge(e);
    REQUIRE(without.AddLoop(edge.from, edge.to, edge.measurement, edge.information, nullptr).ok());
  }

  std::vector<char> active = AllActive(synthetic.graph.num_edges());
  active[dropped] = 0;
  std::vector<TestType> subset_estimate = synthetic.graph.initial_estimate();
  std::vector<TestType> rebuilt_estimate = without.initial_estimate();
  Optimizer<TestType> a;
  Optimizer<TestType> b;
  const OptimizerSummary subset = a.Solve(synthetic.graph, active, &subset_estimate);
  const OptimizerSummary rebuilt =
      b.Solve(without, AllActive(without.num_edges()), &rebuilt_estimate);
  CHECK(subset.final_chi2 == Approx(rebuilt.final_chi2).epsilon(1e-9));
  double translation_m = 0.0;
  double rotation_rad = 0.0;
  RelativeDifference(subset_estimate, rebuilt_estimate, 0, &translation_m, &rotation_rad);
  CHECK(translation_m < 1e-9);
  CHECK(rotation_rad < 1e-9);
}

TEMPLATE_TEST_CASE("Each component keeps its own gauge until an active loop joins it",
                   "[optimizer]",
                   Pose2,
                   Pose3) {
  SyntheticOptions options;
  options.num_poses = 300;
  options.num_sessions = 3;
  options.translation_sigma_m = 0.02;
  options.rotation_sigma_rad = 0.01;
  const auto synthetic = MakeSyntheticGraph<TestType>(options);
  const PoseGraph<TestType>& graph = synthetic.graph;
  std::vector<char> intra_only(graph.num_edges(), 1);
  int inter_session_loops = 0;
  for (int e : synthetic.loop_edges) {
    const bool inter =
        graph.vertex(graph.edge(e).from).session != graph.vertex(graph.edge(e).to).session;
    intra_only[e] = inter ? 0 : 1;
    inter_session_loops += inter ? 1 : 0;
  }
  REQUIRE(inter_session_loops > 0);

  Optimizer<TestType> optimizer;
  std::vector<TestType> separate = graph.initial_estimate();
  const OptimizerSummary apart = optimizer.Solve(graph, intra_only, &separate);
  CHECK(apart.num_components == 3);
  CHECK(apart.free_parameters == TestType::kDim * (graph.num_vertices() - 3));
  for (int s = 0; s < 3; ++s) {
    const int first = graph.session(s).vertices.front();
    const TestType moved = graph.initial_estimate()[first].Inverse() * separate[first];
    CHECK(moved.Log().norm() == 0.0);
  }

  // Joining needs a start in the basin of the joint optimum: every session is re-based so that
  // its first pose sits at its ground truth (iRRR does the same through a cluster's first link).
  std::vector<TestType> joined = graph.initial_estimate();
  for (int s = 0; s < graph.num_sessions(); ++s) {
    const int first = graph.session(s).vertices.front();
    const TestType world_T_session =
        synthetic.ground_truth[first] * graph.initial_estimate()[first].Inverse();
    for (int v : graph.session(s).vertices) joined[v] = world_T_session * joined[v];
  }
  const OptimizerSummary together = optimizer.Solve(graph, AllActive(graph.num_edges()), &joined);
  CHECK(together.num_components == 1);
  const int anchor = graph.session(0).vertices.front();
  const TestType anchor_start = synthetic.ground_truth[anchor] *
                                graph.initial_estimate()[anchor].Inverse() *
                                graph.initial_estimate()[anchor];
  CHECK((anchor_start.Inverse() * joined[anchor]).Log().norm() == 0.0);
  // Session 1 now lives in session 0's frame: its first pose moved onto the ground truth offset.
  const int second = graph.session(1).vertices.front();
  const TestType expected =
      synthetic.ground_truth[anchor].Inverse() * synthetic.ground_truth[second];
  const TestType got = joined[anchor].Inverse() * joined[second];
  // Before the join the sessions' frames were unrelated (dead reckoning from the identity);
  // after it the offset matches the ground truth up to the measurement noise.
  CHECK((expected.Inverse() * got).translation().norm() < 0.2);
  CHECK((expected.Inverse() * got)
            .Log()
            .template tail<TestType::kDim - TestType::kTranslationDim>()
            .norm() < 0.05);
  const TestType before =
      graph.initial_estimate()[anchor].Inverse() * graph.initial_estimate()[second];
  CHECK((expected.Inverse() * before).translation().norm() > 1.0);
}

TEST_CASE("A session whose edges are all inactive is left where it is and not counted",
          "[optimizer]") {
  SyntheticOptions options;
  options.num_poses = 200;
  options.num_sessions = 2;
  options.translation_sigma_m = 0.02;
  options.rotation_sigma_rad = 0.01;
  const auto synthetic = MakeSyntheticGraph<Pose2>(options);
  const PoseGraph<Pose2>& graph = synthetic.graph;
  // Only session 0: its odometry and its own loops.
  std::vector<char> active(graph.num_edges(), 0);
  int session_zero_edges = 0;
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose2>& edge = graph.edge(e);
    if (graph.vertex(edge.from).session == 0 && graph.vertex(edge.to).session == 0) {
      active[e] = 1;
      ++session_zero_edges;
    }
  }
  std::vector<Pose2> estimate = graph.initial_estimate();
  Optimizer<Pose2> optimizer;
  const OptimizerSummary summary = optimizer.Solve(graph, active, &estimate);
  REQUIRE(summary.termination == TerminationType::kConvergence);
  CHECK(summary.num_components == 1);
  CHECK(summary.num_active_edges == session_zero_edges);
  const int session_zero_poses = static_cast<int>(graph.session(0).vertices.size());
  CHECK(summary.free_parameters == Pose2::kDim * (session_zero_poses - 1));
  for (int v : graph.session(1).vertices) {
    CHECK((graph.initial_estimate()[v].Inverse() * estimate[v]).Log().norm() == 0.0);
  }
}

TEST_CASE("The symbolic analysis is reused while the pattern is unchanged", "[optimizer]") {
  SyntheticOptions options;
  options.num_poses = 200;
  options.translation_sigma_m = 0.02;
  options.rotation_sigma_rad = 0.01;
  const auto synthetic = MakeSyntheticGraph<Pose2>(options);
  const PoseGraph<Pose2>& graph = synthetic.graph;
  std::vector<char> all = AllActive(graph.num_edges());
  std::vector<char> fewer = all;
  fewer[synthetic.loop_edges.back()] = 0;

  SECTION("active-edge pattern: a new subset is a new analysis") {
    Optimizer<Pose2> optimizer;
    std::vector<Pose2> estimate = graph.initial_estimate();
    CHECK(optimizer.Solve(graph, all, &estimate).linear_solver_analyses == 1);
    estimate = graph.initial_estimate();
    CHECK(optimizer.Solve(graph, all, &estimate).linear_solver_analyses == 0);
    estimate = graph.initial_estimate();
    CHECK(optimizer.Solve(graph, fewer, &estimate).linear_solver_analyses == 1);
  }
  SECTION("all-edge pattern: one analysis serves every subset, with the same answer") {
    OptimizerOptions union_options;
    union_options.pattern = SparsityPattern::kAllEdges;
    Optimizer<Pose2> optimizer(union_options);
    Optimizer<Pose2> reference;
    std::vector<Pose2> estimate = graph.initial_estimate();
    CHECK(optimizer.Solve(graph, all, &estimate).linear_solver_analyses == 1);
    estimate = graph.initial_estimate();
    const OptimizerSummary reused = optimizer.Solve(graph, fewer, &estimate);
    CHECK(reused.linear_solver_analyses == 0);
    std::vector<Pose2> expected = graph.initial_estimate();
    const OptimizerSummary fresh = reference.Solve(graph, fewer, &expected);
    CHECK(reused.final_chi2 == Approx(fresh.final_chi2).epsilon(1e-9));
    CHECK(reused.iterations == fresh.iterations);
  }
}

TEST_CASE("Optimizer options are validated with a sentence naming the option", "[optimizer]") {
  OptimizerOptions options;
  CHECK(options.Validate().ok());
  options.max_iterations = 0;
  CHECK_THAT(options.Validate().message(), Catch::Contains("max_iterations"));
  options = OptimizerOptions();
  options.function_tolerance = std::nan("");
  CHECK_THAT(options.Validate().message(), Catch::Contains("function_tolerance"));
  options = OptimizerOptions();
  options.initial_damping = 0.0;
  CHECK_THAT(options.Validate().message(), Catch::Contains("initial_damping"));
}

TEST_CASE("Iterations stop at max_iterations with NO_CONVERGENCE and an improved estimate",
          "[optimizer]") {
  SyntheticOptions options;
  options.num_poses = 300;
  options.translation_sigma_m = 0.05;
  options.rotation_sigma_rad = 0.02;
  const auto synthetic = MakeSyntheticGraph<Pose2>(options);
  OptimizerOptions limited;
  limited.max_iterations = 1;
  Optimizer<Pose2> optimizer(limited);
  std::vector<Pose2> estimate = synthetic.graph.initial_estimate();
  const OptimizerSummary summary =
      optimizer.Solve(synthetic.graph, AllActive(synthetic.graph.num_edges()), &estimate);
  CHECK(summary.termination == TerminationType::kNoConvergence);
  CHECK(summary.iterations == 1);
  CHECK(summary.estimate_updated);
  CHECK(summary.final_chi2 < summary.initial_chi2);
}

TEST_CASE("Gauss-Newton never raises chi2, even where full steps diverge", "[optimizer]") {
  // Random wrong loops on a grid world, solved from dead reckoning: full Gauss-Newton steps
  // overshoot here (chi2 climbs by orders of magnitude); halved steps must keep every iterate at
  // or below the one before.
  const SyntheticGraph<Pose2> synthetic = GridWithWrongLoops();
  const std::vector<char> active = AllActive(synthetic.graph.num_edges());
  double previous_chi2 = std::numeric_limits<double>::infinity();
  for (int iterations = 1; iterations <= 30; ++iterations) {
    OptimizerOptions limited;
    limited.max_iterations = iterations;
    Optimizer<Pose2> optimizer(limited);
    std::vector<Pose2> estimate = synthetic.graph.initial_estimate();
    const OptimizerSummary summary = optimizer.Solve(synthetic.graph, active, &estimate);
    INFO("after " << iterations << " iterations: " << summary.message);
    REQUIRE(summary.IsSolutionUsable());
    CHECK(summary.final_chi2 <= summary.initial_chi2);
    CHECK(summary.final_chi2 <= previous_chi2);
    previous_chi2 = summary.final_chi2;
    if (summary.termination == TerminationType::kConvergence) break;
  }
}

TEST_CASE("A solve gives up on a target chi2 it cannot reach, and not on one it can",
          "[optimizer]") {
  const SyntheticGraph<Pose2> synthetic = GridWithWrongLoops();
  const std::vector<char> active = AllActive(synthetic.graph.num_edges());
  auto solve = [&](double target_chi2) {
    Optimizer<Pose2> optimizer;
    std::vector<Pose2> estimate = synthetic.graph.initial_estimate();
    return optimizer.Solve(synthetic.graph, active, &estimate, target_chi2);
  };
  const OptimizerSummary full = solve(std::numeric_limits<double>::infinity());
  REQUIRE(full.termination == TerminationType::kConvergence);
  REQUIRE(full.iterations >= 4);

  // Half the optimum: out of reach, found so before convergence, from the improved estimate.
  const OptimizerSummary cut = solve(0.5 * full.final_chi2);
  INFO(full.iterations << " iterations to " << full.final_chi2 << "; " << cut.iterations << " to "
                       << cut.final_chi2 << ": " << cut.message);
  CHECK(cut.termination == TerminationType::kOutOfReach);
  CHECK(cut.IsSolutionUsable());
  CHECK(cut.iterations >= 2);
  CHECK(cut.iterations < full.iterations);
  CHECK(cut.final_chi2 < cut.initial_chi2);
  CHECK(cut.final_chi2 >= full.final_chi2 * (1.0 - 1e-6));

  // Above the optimum: the solve is the one without a target, iterate for iterate.
  const OptimizerSummary reached = solve(1.01 * full.final_chi2);
  CHECK(reached.termination == TerminationType::kConvergence);
  CHECK(reached.iterations == full.iterations);
  CHECK(reached.final_chi2 == full.final_chi2);
}

}  // namespace
}  // namespace irrr
