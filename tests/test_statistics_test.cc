#include "core/test_statistics.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include <catch2/catch.hpp>

#include "core/irrr.h"
#include "core/optimizer.h"
#include "core/outliers.h"
#include "tests/corrupted_graph.h"
#include "tests/synthetic_graph.h"

namespace irrr {
namespace {

using testing::Corrupted;
using testing::MakeCorrupted;
using testing::MakeSyntheticGraph;
using testing::SyntheticOptions;

constexpr double kKnown = std::numeric_limits<double>::infinity();

TEST_CASE("A scaled threshold is the chi-square quantile for a known factor, the F one otherwise",
          "[statistics]") {
  // chi2(0.95, 3) = 7.8147 and F(0.95; 3, 50) = 2.7900 (NIST/SEMATECH tables).
  CHECK(ScaledChiSquareThreshold(0.95, 3, 1.0, kKnown) == Approx(7.8147).margin(5e-5));
  CHECK(ScaledChiSquareThreshold(0.95, 3, 2.0, kKnown) == Approx(2.0 * 7.8147).margin(1e-4));
  CHECK(ScaledChiSquareThreshold(0.95, 3, 1.0, 50.0) == Approx(3.0 * 2.7900).margin(1e-3));
  // The F threshold allows for the factor's uncertainty, and tends to the chi-square one as the
  // factor's degrees of freedom grow.
  for (double dof : {3.0, 30.0, 3000.0}) {
    const double chi2 = ScaledChiSquareThreshold(0.999, dof, 1.0, kKnown);
    CHECK(ScaledChiSquareThreshold(0.999, dof, 1.0, 50.0) > chi2);
    CHECK(ScaledChiSquareThreshold(0.999, dof, 1.0, 1e9) == Approx(chi2).epsilon(1e-3));
  }
  CHECK(ChiSquareMedian(3) == Approx(2.3660).margin(5e-5));
}

TEST_CASE("The robust variance factor is the dof-weighted median of the samples", "[statistics]") {
  // Samples exactly at their median under a factor of 0.02: every estimate is 0.02.
  std::vector<RedundancySample> samples;
  for (double dof : {3.0, 9.0, 60.0, 300.0}) samples.push_back({0.02 * ChiSquareMedian(dof), dof});
  CHECK(RobustVarianceFactor(samples) == Approx(0.02).epsilon(1e-12));
  // Wrong clusters holding less than half the redundancy cannot move it, however inconsistent.
  samples.push_back({1e6, 100.0});
  samples.push_back({1e7, 200.0});
  CHECK(RobustVarianceFactor(samples) == Approx(0.02).epsilon(1e-12));
  // A sample without redundancy carries none; no sample: NaN.
  CHECK(std::isnan(RobustVarianceFactor({{1.0, 0.0}})));
  CHECK(std::isnan(RobustVarianceFactor({})));
}

// The good set: odometry and every loop but the last; the tested link: the last loop.
template <class Pose>
struct Increase {
  double linearized = 0.0;
  double exact = 0.0;
  double redundancy = 0.0;  // the screen's redundancy number of the link
  double hat = 0.0;         // tr(J Sigma_joint J' Omega) / d at the joint optimum
  double removal = 0.0;     // the link's linearized removal at the joint optimum
};

template <class Pose>
Increase<Pose> LinkIncrease(const PoseGraph<Pose>& graph) {
  int tested = -1;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kLoop) tested = e;
  }
  REQUIRE(tested >= 0);
  std::vector<char> good(graph.num_edges(), 1);
  good[tested] = 0;
  std::vector<Pose> x = graph.initial_estimate();
  Optimizer<Pose> optimizer;
  const OptimizerSummary base = optimizer.Solve(graph, good, &x);
  REQUIRE(base.termination == TerminationType::kConvergence);
  const Edge<Pose>& edge = graph.edge(tested);
  Eigen::MatrixXd covariance;
  REQUIRE(optimizer.FactorizeAt(graph, good, x));
  REQUIRE(optimizer.Covariance({edge.from, edge.to}, &covariance));
  Increase<Pose> out;
  const LinearizedAddition addition =
      LinearizeAddition<Pose>({&edge}, x, {edge.from, edge.to}, covariance);
  out.linearized = addition.chi2_increase;
  out.redundancy = addition.redundancy;
  const std::vector<char> all(graph.num_edges(), 1);
  const OptimizerSummary joint = optimizer.Solve(graph, all, &x);
  REQUIRE(joint.termination == TerminationType::kConvergence);
  out.exact = joint.final_chi2 - base.final_chi2;
  // The link's share of its own fit (its leverage) from the joint problem's covariance: one
  // minus its redundancy number.
  REQUIRE(optimizer.FactorizeAt(graph, all, x));
  REQUIRE(optimizer.Covariance({edge.from, edge.to}, &covariance));
  typename Pose::Matrix J_from;
  typename Pose::Matrix J_to;
  RelativePoseResidual<Pose>(edge.measurement, x[edge.from], x[edge.to], &J_from, &J_to);
  Eigen::MatrixXd J(Pose::kDim, 2 * Pose::kDim);
  J << J_from, J_to;
  out.hat = (J * covariance * J.transpose() * edge.information).trace() / Pose::kDim;
  out.removal = LinearizeRemoval<Pose>({&edge}, x, {edge.from, edge.to}, covariance);
  return out;
}

// Rotations known to 1e-7 rad and translations noisy: the problem is linear in the translations
// to within rounding.
SyntheticOptions LinearSyntheticOptions() {
  SyntheticOptions linear;
  linear.num_poses = 120;
  linear.translation_sigma_m = 0.05;
  linear.rotation_sigma_rad = 1e-7;
  linear.loop_probability = 0.3;
  linear.seed = 4;
  return linear;
}

TEMPLATE_TEST_CASE(
    "On a linear graph the linearized screen and removal equal the chi2 increase, and the "
    "redundancy one minus the leverage",
    "[statistics]",
    Pose2,
    Pose3) {
  // The screen's statistic is the exact chi2 increase there.
  const SyntheticOptions linear = LinearSyntheticOptions();
  const Increase<TestType> near = LinkIncrease(MakeSyntheticGraph<TestType>(linear).graph);
  INFO("linearized " << near.linearized << ", exact " << near.exact);
  CHECK(near.exact > 0.1);
  CHECK(near.linearized == Approx(near.exact).epsilon(1e-5));
  // Its redundancy number is what the joint problem leaves of the link to itself: 1 - leverage.
  INFO("redundancy " << near.redundancy << ", leverage " << near.hat);
  CHECK(near.redundancy > 0.05);
  CHECK(near.redundancy < 0.95);
  CHECK(near.redundancy == Approx(1.0 - near.hat).epsilon(1e-5));
  // Taken out again at the joint optimum, the link gives back exactly what it added.
  INFO("removal " << near.removal);
  CHECK(near.removal == Approx(near.exact).epsilon(1e-5));

  // With rotation noise of 0.01 rad it is an approximation, still within a few percent.
  SyntheticOptions noisy = linear;
  noisy.rotation_sigma_rad = 0.01;
  const Increase<TestType> far = LinkIncrease(MakeSyntheticGraph<TestType>(noisy).graph);
  INFO("linearized " << far.linearized << ", exact " << far.exact);
  CHECK(far.linearized == Approx(far.exact).epsilon(0.05));
}

// The edges of `group` and their end poses, each once, as LinearizeAddition and LinearizeRemoval
// take them.
template <class Pose>
struct Group {
  std::vector<const Edge<Pose>*> edges;
  std::vector<int> vertices;
};

template <class Pose>
Group<Pose> GroupOf(const PoseGraph<Pose>& graph, const std::vector<int>& group) {
  Group<Pose> out;
  for (int e : group) {
    out.edges.push_back(&graph.edge(e));
    for (int v : {graph.edge(e).from, graph.edge(e).to}) {
      if (std::find(out.vertices.begin(), out.vertices.end(), v) == out.vertices.end()) {
        out.vertices.push_back(v);
      }
    }
  }
  return out;
}

TEMPLATE_TEST_CASE(
    "On a linear graph a group of links sharing poses adds and gives back its exact chi2 increase",
    "[statistics]",
    Pose2,
    Pose3) {
  // The last three loops, the last one twice (a duplicate shares both its poses), tested as one
  // group: the cross terms of J Sigma J' between links and the poses they share count.
  const SyntheticOptions linear = LinearSyntheticOptions();
  PoseGraph<TestType> graph = MakeSyntheticGraph<TestType>(linear).graph;
  std::vector<int> group;
  for (int e = graph.num_edges() - 1; e >= 0 && group.size() < 3; --e) {
    if (graph.edge(e).kind == EdgeKind::kLoop) group.push_back(e);
  }
  REQUIRE(group.size() == 3);
  const Edge<TestType> last = graph.edge(group.front());
  int duplicate = -1;
  REQUIRE(graph.AddLoop(last.from, last.to, last.measurement, last.information, &duplicate).ok());
  group.push_back(duplicate);
  const auto [edges, vertices] = GroupOf(graph, group);
  std::vector<char> good(graph.num_edges(), 1);
  for (int e : group) good[e] = 0;
  REQUIRE(vertices.size() < 2 * group.size());
  std::vector<TestType> x = graph.initial_estimate();
  Optimizer<TestType> optimizer;
  const OptimizerSummary base = optimizer.Solve(graph, good, &x);
  REQUIRE(base.termination == TerminationType::kConvergence);
  Eigen::MatrixXd covariance;
  REQUIRE(optimizer.FactorizeAt(graph, good, x));
  REQUIRE(optimizer.Covariance(vertices, &covariance));
  const double added = LinearizeAddition<TestType>(edges, x, vertices, covariance).chi2_increase;
  // The same from J Sigma J' as a factorization gives it without Sigma (A' Sigma A with A = J',
  // the warm engine's way: IncrementalSolver::ProjectedCovariances).
  const StackedEdges<TestType> stack = StackEdges<TestType>(edges, x, vertices);
  Eigen::MatrixXd A = stack.TransposedJacobian();
  const double added_projected =
      AdditionStatistic(stack, A.transpose() * covariance * A).chi2_increase;
  const std::vector<char> all(graph.num_edges(), 1);
  const OptimizerSummary joint = optimizer.Solve(graph, all, &x);
  REQUIRE(joint.termination == TerminationType::kConvergence);
  const double exact = joint.final_chi2 - base.final_chi2;
  REQUIRE(optimizer.FactorizeAt(graph, all, x));
  REQUIRE(optimizer.Covariance(vertices, &covariance));
  const double removed = LinearizeRemoval<TestType>(edges, x, vertices, covariance);
  const StackedEdges<TestType> joint_stack = StackEdges<TestType>(edges, x, vertices);
  A = joint_stack.TransposedJacobian();
  const double removed_projected = RemovalStatistic(joint_stack, A.transpose() * covariance * A);
  INFO("exact " << exact << ", linearized addition " << added << " (projected " << added_projected
                << "), removal " << removed << " (projected " << removed_projected << ")");
  CHECK(exact > 0.1);
  CHECK(added == Approx(exact).epsilon(1e-5));
  CHECK(removed == Approx(exact).epsilon(1e-5));
  CHECK(added_projected == Approx(exact).epsilon(1e-5));
  CHECK(removed_projected == Approx(exact).epsilon(1e-5));
}

TEMPLATE_TEST_CASE(
    "At the same residuals a group's removal statistic falls as the good set gains links, and "
    "rises as it loses them",
    "[statistics]",
    Pose2,
    Pose3) {
  // What lets the warm engine skip judging a bending run again while its strain is unchanged and
  // no link has left the good set (ReverseOutvoted): the group's ends' covariance shrinks with
  // every link added, so its residuals' own covariance, Omega^-1 - J Sigma J', grows. The group:
  // the last three loops; the same estimate, two good sets.
  SyntheticOptions options = LinearSyntheticOptions();
  options.rotation_sigma_rad = 0.01;
  const PoseGraph<TestType> graph = MakeSyntheticGraph<TestType>(options).graph;
  std::vector<int> loops;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kLoop) loops.push_back(e);
  }
  REQUIRE(loops.size() > 10);
  const std::vector<int> group(loops.end() - 3, loops.end());
  const auto [edges, vertices] = GroupOf(graph, group);
  std::vector<char> sparse(graph.num_edges(), 1);  // odometry and the group
  for (int e : loops) sparse[e] = 0;
  for (int e : group) sparse[e] = 1;
  const std::vector<char> dense(graph.num_edges(), 1);  // every loop
  std::vector<TestType> x = graph.initial_estimate();
  Optimizer<TestType> optimizer;
  REQUIRE(optimizer.Solve(graph, dense, &x).termination == TerminationType::kConvergence);
  const std::vector<char>* good[2] = {&sparse, &dense};
  double removal[2];
  for (int k = 0; k < 2; ++k) {
    Eigen::MatrixXd covariance;
    REQUIRE(optimizer.FactorizeAt(graph, *good[k], x));
    REQUIRE(optimizer.Covariance(vertices, &covariance));
    removal[k] = LinearizeRemoval<TestType>(edges, x, vertices, covariance);
  }
  INFO("removal with the group alone " << removal[0] << ", with every loop " << removal[1]);
  CHECK(removal[1] > 0.1);
  CHECK(removal[0] > 1.5 * removal[1]);
}

// Chi2 of the optimum with the loops `extra` added to the good set `good`, started from `x`.
template <class Pose>
double OptimumChi2(const PoseGraph<Pose>& graph,
                   std::vector<char> good,
                   const std::vector<int>& extra,
                   std::vector<Pose> x) {
  for (int e : extra) good[e] = 1;
  Optimizer<Pose> optimizer;
  const OptimizerSummary summary = optimizer.Solve(graph, good, &x);
  REQUIRE(summary.termination == TerminationType::kConvergence);
  return summary.final_chi2;
}

TEMPLATE_TEST_CASE("A cluster's chi2 increase is at least that of any one of its links alone",
                   "[statistics]",
                   Pose2,
                   Pose3) {
  // The bound by which the warm engine rules out a challenger from one link's statistic: more
  // edges cannot lower the optimum's chi2. Checked on a true cluster (the last three loops) and a
  // wrong one (three loops in a consistent group, core/outliers.h).
  SyntheticOptions options;
  options.num_poses = 150;
  options.translation_sigma_m = 0.05;
  options.rotation_sigma_rad = 0.01;
  options.loop_probability = 0.3;
  options.seed = 7;
  OutlierOptions wrong_options;
  wrong_options.mode = OutlierMode::kRandomGrouped;
  wrong_options.count = 3;
  wrong_options.seed = 3;
  const Corrupted<TestType> corrupted = MakeCorrupted<TestType>(options, wrong_options);
  const PoseGraph<TestType>& graph = corrupted.graph;
  std::vector<int> loops;
  std::vector<int> wrong;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind != EdgeKind::kLoop) continue;
    (corrupted.is_outlier[e] ? wrong : loops).push_back(e);
  }
  REQUIRE(wrong.size() == 3);
  REQUIRE(loops.size() > 10);
  const std::vector<int> true_cluster(loops.end() - 3, loops.end());

  // The good set: odometry and every true loop but the cluster's, at its optimum.
  std::vector<char> good(graph.num_edges(), 0);
  for (int e = 0; e < graph.num_edges(); ++e) {
    good[e] = graph.edge(e).kind == EdgeKind::kOdometry;
  }
  for (auto it = loops.begin(); it != loops.end() - 3; ++it) good[*it] = 1;
  std::vector<TestType> x = graph.initial_estimate();
  Optimizer<TestType> optimizer;
  const OptimizerSummary solved = optimizer.Solve(graph, good, &x);
  REQUIRE(solved.termination == TerminationType::kConvergence);
  const double base = solved.final_chi2;
  for (const std::vector<int>& cluster : {true_cluster, wrong}) {
    const double increase = OptimumChi2(graph, good, cluster, x) - base;
    double largest_alone = 0.0;
    for (int e : cluster) {
      const double alone = OptimumChi2(graph, good, {e}, x) - base;
      INFO("cluster increase " << increase << ", link " << e << " alone " << alone);
      CHECK(alone >= -1e-6);
      CHECK(alone <= increase + 1e-6 * (1.0 + increase));
      largest_alone = std::max(largest_alone, alone);
    }
    // The bound is not empty: a link alone carries a good part of its cluster's increase.
    CHECK(largest_alone > 0.2 * increase);
  }
  // The wrong cluster stands far above the true one.
  CHECK(OptimumChi2(graph, good, wrong, x) - base >
        100.0 * (OptimumChi2(graph, good, true_cluster, x) - base));
}

TEMPLATE_TEST_CASE("The warm engine recovers a variance factor of 0.02 and of 50 within 10%",
                   "[statistics][irrr]",
                   Pose2,
                   Pose3) {
  const double factor = GENERATE(0.02, 50.0);
  INFO("variance factor " << factor);
  SyntheticOptions options;
  options.num_poses = 400;
  options.translation_sigma_m = 0.05;
  options.rotation_sigma_rad = 0.01;
  options.loop_probability = 0.5;
  // The information as the inverse noise covariance times the factor: chi2 values, and so the
  // factor the engine reads from them, scale with it.
  options.information_scale = factor;
  options.seed = 11;
  const auto synthetic = MakeSyntheticGraph<TestType>(options);
  IrrrOptions irrr;
  irrr.cluster_gap = 10.0;
  // Estimated factors above 1 are not used (the tests never get more lenient than the information
  // as given, see WarmEngine::CurrentScale): over-confident information is given its factor, and
  // the estimate from the data's redundancy is checked against it.
  if (factor > 1.0) irrr.variance_factor = factor;
  std::vector<StepResult> steps;
  const auto decisions = RunIncrementalIrrr<TestType>(synthetic.graph, irrr, nullptr, &steps);
  REQUIRE(!steps.empty());
  // The estimate at the end, from every cluster that passed Algorithm 1.
  const double estimate = steps.back().variance_estimate;
  CHECK(estimate == Approx(factor).epsilon(0.10));
  // The tests use the estimate up to 1 (or the factor given).
  for (const StepResult& step : steps) CHECK(step.variance_factor <= std::max(factor, 1.0));
  int accepted = 0;
  for (int e : synthetic.loop_edges) accepted += decisions[e].state == LoopState::kAccepted;
  CHECK(accepted >= 0.99 * static_cast<double>(synthetic.loop_edges.size()));
}

}  // namespace
}  // namespace irrr
