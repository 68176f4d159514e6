#include "core/incremental_solver.h"

#include <algorithm>
#include <limits>
#include <vector>

#include <catch2/catch.hpp>

#include "core/irrr.h"
#include "core/optimizer.h"
#include "tests/synthetic_graph.h"

namespace irrr {
namespace {

using testing::MakeSyntheticGraph;
using testing::NoisyOptions;
using testing::RelativeDifference;
using testing::SyntheticOptions;

// Relinearizing every pose that moves past the bounds (model_tolerance 0), the incremental
// estimate leaves each pose within the relinearization bounds (1e-3 rad, 1e-2 m) of its
// linearization point; the optimum it reaches differs from a batch solve's by products of those
// steps with the Jacobians' change. Measured on these graphs: up to 1.1e-5 rad and 2e-5 m.
constexpr double kOptimumToleranceM = 1e-4;
constexpr double kOptimumToleranceRad = 1e-4;
// chi2 at the two optima (relative): first order in the estimate's error, which is zero at an
// optimum, so far tighter.
constexpr double kChi2Tolerance = 1e-6;
// Covariances from a factor linearized at the estimate against a fresh factorization there
// (relative to the largest entry): rounding.
constexpr double kCovarianceTolerance = 1e-8;
// The same once poses have moved within the relinearization bounds of their linearization
// points: the covariance is that of the linearization points (measured: 5e-4 relative).
constexpr double kLaggingCovarianceTolerance = 1e-2;
// The same with moved poses kept at their points while the quadratic model there holds
// (measured: up to 1.6e-2 relative).
constexpr double kModelCovarianceTolerance = 2e-2;

// Every pose that moves past the relinearization bounds relinearized, however well the quadratic
// model still predicts its edges' residuals.
IncrementalSolverOptions ExactOptions() {
  IncrementalSolverOptions options;
  options.model_tolerance = 0.0;
  return options;
}

// Feeds a one-session graph to a solver in arrival order: each pose by Extend, each loop by Add
// as soon as its later pose has arrived. Returns the solver's estimate indexed like the graph.
template <class Pose>
std::vector<Pose> FeedIncrementally(const PoseGraph<Pose>& graph,
                                    IncrementalSolver<Pose>* solver,
                                    const std::vector<char>& use_loop) {
  std::vector<int> odometry_into(graph.num_vertices(), -1);
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kOdometry) odometry_into[graph.edge(e).to] = e;
  }
  std::vector<Pose> start(graph.num_vertices());
  const IncrementalSummary first = solver->Reset({0}, {}, start);
  REQUIRE(first.ok);
  for (const ArrivalEvent& event : ArrivalOrder(graph)) {
    if (event.kind == ArrivalEvent::Kind::kPose && event.index > 0) {
      solver->Extend(event.index, odometry_into[event.index]);
    } else if (event.kind == ArrivalEvent::Kind::kLoop && use_loop[event.index]) {
      const IncrementalSummary summary = solver->Add({event.index});
      INFO("loop " << event.index << ": " << summary.message);
      REQUIRE(summary.ok);
    }
  }
  std::vector<Pose> estimate(graph.num_vertices());
  for (int v = 0; v < graph.num_vertices(); ++v) estimate[v] = solver->estimate(v);
  return estimate;
}

template <class Pose>
void CheckAtBatchOptimum(const PoseGraph<Pose>& graph,
                         const std::vector<char>& active,
                         const IncrementalSolver<Pose>& solver,
                         const std::vector<Pose>& estimate) {
  std::vector<Pose> batch = estimate;
  Optimizer<Pose> optimizer;
  const OptimizerSummary summary = optimizer.Solve(graph, active, &batch);
  REQUIRE(summary.IsSolutionUsable());
  double translation = 0.0;
  double rotation = 0.0;
  RelativeDifference(batch, estimate, 0, &translation, &rotation);
  CHECK(translation < kOptimumToleranceM);
  CHECK(rotation < kOptimumToleranceRad);
  CHECK(solver.ExactChi2() == Approx(summary.final_chi2).epsilon(kChi2Tolerance));
  CHECK(solver.chi2() == Approx(summary.final_chi2).epsilon(kChi2Tolerance));
}

TEMPLATE_TEST_CASE(
    "Fed pose by pose and loop by loop, the incremental solver ends at the batch "
    "optimum",
    "[incremental]",
    Pose2,
    Pose3) {
  const uint32_t seed = GENERATE(1u, 2u);
  INFO("seed " << seed);
  const auto synthetic = MakeSyntheticGraph<TestType>(NoisyOptions<TestType>(seed));
  const PoseGraph<TestType>& graph = synthetic.graph;
  REQUIRE(synthetic.loop_edges.size() > 20);
  IncrementalSolverOptions options = ExactOptions();
  options.spare_fraction = 0.0;  // the minimum of free places: several reorderings on the way
  IncrementalSolver<TestType> solver(&graph, options);
  const std::vector<char> all(graph.num_edges(), 1);
  const std::vector<TestType> estimate = FeedIncrementally(graph, &solver, all);
  CHECK(solver.counters().rebuilds >= 3);
  CHECK(solver.counters().relinearized > 0);
  CHECK(static_cast<int>(solver.edges().size()) == graph.num_edges());
  CheckAtBatchOptimum(graph, all, solver, estimate);
}

// Adds a wrong loop and returns its edge: the first pose and one half way along said to be 30 m
// and nearly a half turn apart (whatever they are), as certain as the odometry.
template <class Pose>
int AddFarWrongLoop(PoseGraph<Pose>* graph) {
  const int wrong = graph->num_edges();
  typename Pose::Tangent far = Pose::Tangent::Zero();
  far(0) = 30.0;
  far(Pose::kDim - 1) = 3.0;
  REQUIRE(graph
              ->AddLoop(0,
                        graph->num_vertices() / 2,
                        Pose().Retract(far),
                        graph->edge(0).information,
                        nullptr)
              .ok());
  return wrong;
}

// D^2 of `active` at the batch optimum reached from `estimate`, and its degrees of freedom.
template <class Pose>
double BatchOptimumChi2(const PoseGraph<Pose>& graph,
                        const std::vector<char>& active,
                        std::vector<Pose> estimate,
                        double* dof) {
  Optimizer<Pose> optimizer;
  const OptimizerSummary optimum = optimizer.Solve(graph, active, &estimate);
  REQUIRE(optimum.IsSolutionUsable());
  const int edges = static_cast<int>(std::count(active.begin(), active.end(), 1));
  *dof = Pose::kDim * static_cast<double>(edges - graph.num_vertices() + 1);
  return optimum.final_chi2;
}

// How far above the optimum's chi2 an estimate whose moved poses keep their points may end:
// about model_tolerance degrees of freedom's chi2 (IncrementalSolverOptions), so twice it.
double ModelChi2Slack(const IncrementalSolverOptions& options, double optimum, double dof) {
  return 2.0 * options.model_tolerance * optimum / dof;
}

TEMPLATE_TEST_CASE(
    "Moved poses keep their linearization points while the model predicts their residuals, "
    "within the model tolerance of the optimum's chi2",
    "[incremental]",
    Pose2,
    Pose3) {
  // One seed: each run feeds the graph twice (3.5-4 s in 3D, about 50 s under the sanitizers).
  auto synthetic = MakeSyntheticGraph<TestType>(NoisyOptions<TestType>(1));
  PoseGraph<TestType>& graph = synthetic.graph;
  const int wrong = AddFarWrongLoop(&graph);
  std::vector<char> active(graph.num_edges(), 1);
  active[wrong] = 0;
  IncrementalSolver<TestType> exact(&graph, ExactOptions());
  FeedIncrementally(graph, &exact, active);
  const IncrementalSolverOptions options;
  IncrementalSolver<TestType> lazy(&graph, options);
  const std::vector<TestType> estimate = FeedIncrementally(graph, &lazy, active);

  // Loops that correct the drift by centimetres: the model at the old points predicts them.
  double dof = 0.0;
  const double optimum = BatchOptimumChi2(graph, active, estimate, &dof);
  const double tolerance = ModelChi2Slack(options, optimum, dof);
  INFO("chi2 " << lazy.ExactChi2() << " against the optimum's " << optimum << ", tolerance "
               << tolerance << "; relinearized " << lazy.counters().relinearized
               << " poses against " << exact.counters().relinearized);
  CHECK(lazy.ExactChi2() >= optimum * (1.0 - kChi2Tolerance));
  CHECK(lazy.ExactChi2() - optimum <= tolerance);
  CHECK(lazy.counters().relinearized < exact.counters().relinearized);

  // A loop that bends the graph by a half turn: the model at the old points does not predict
  // it, and the poses it moves are linearized anew (relinearized, or all of them by a rebuild)
  // until it does. The tolerance stays the one of the D^2 per degree of freedom before it.
  auto linearizations = [&] { return lazy.counters().relinearized + lazy.counters().rebuilds; };
  const long before = linearizations();
  REQUIRE(lazy.Add({wrong}).ok);
  active[wrong] = 1;
  std::vector<TestType> bent(graph.num_vertices());
  for (int v = 0; v < graph.num_vertices(); ++v) bent[v] = lazy.estimate(v);
  const double bent_optimum = BatchOptimumChi2(graph, active, bent, &dof);
  INFO("with the wrong loop: chi2 " << lazy.ExactChi2() << " against the optimum's "
                                    << bent_optimum);
  CHECK(linearizations() > before);
  CHECK(lazy.ExactChi2() >= bent_optimum * (1.0 - kChi2Tolerance));
  CHECK(lazy.ExactChi2() - bent_optimum <= tolerance);
}

TEMPLATE_TEST_CASE(
    "Marginal covariances and their projections equal the inverse of J'WJ at the estimate",
    "[incremental]",
    Pose2,
    Pose3) {
  const auto synthetic = MakeSyntheticGraph<TestType>(NoisyOptions<TestType>(3));
  const PoseGraph<TestType>& graph = synthetic.graph;
  const bool lazy = GENERATE(false, true);
  INFO((lazy ? "moved poses kept at their points while the model holds" : "exact"));
  IncrementalSolver<TestType> solver(&graph, lazy ? IncrementalSolverOptions() : ExactOptions());
  const std::vector<char> all(graph.num_edges(), 1);
  const std::vector<TestType> estimate = FeedIncrementally(graph, &solver, all);
  // The reference: a fresh factorization of J'WJ at the same poses, solved for unit vectors.
  Optimizer<TestType> reference;
  REQUIRE(reference.FactorizeAt(graph, all, estimate));
  const int n = graph.num_vertices();
  const std::vector<std::vector<int>> queries = {
      {n - 1}, {0, n / 2}, {n / 3, n - 2, 5}, {17, 18, 19, 250}};
  // Projections A (d*m x k, k = 2 and 5: fewer and more columns than one pose's d), with
  // entries -2 .. 2, for A' Sigma A from one recovery (ProjectedCovariances).
  std::vector<CovarianceProjection> projections;
  for (size_t k = 0; k < queries.size(); ++k) {
    const int rows = TestType::kDim * static_cast<int>(queries[k].size());
    const int columns = k % 2 == 0 ? 2 : 5;
    Eigen::MatrixXd A(rows, columns);
    for (int i = 0; i < rows; ++i) {
      for (int j = 0; j < columns; ++j) {
        A(i, j) = static_cast<double>((7 * i + 3 * j + k) % 5) - 2.0;
      }
    }
    projections.push_back({queries[k], A});
  }
  auto check = [&](double tolerance) {
    // Each query alone, and all of them from one recovery (Covariances).
    const std::vector<Eigen::MatrixXd> together = solver.Covariances(queries);
    const std::vector<Eigen::MatrixXd> projected = solver.ProjectedCovariances(projections);
    REQUIRE(together.size() == queries.size());
    REQUIRE(projected.size() == queries.size());
    for (size_t k = 0; k < queries.size(); ++k) {
      const std::vector<int>& query = queries[k];
      Eigen::MatrixXd expected;
      REQUIRE(reference.Covariance(query, &expected));
      const Eigen::MatrixXd covariance = solver.Covariance(query);
      INFO("query of " << query.size() << " poses, largest entry "
                       << expected.cwiseAbs().maxCoeff());
      CHECK((covariance - expected).cwiseAbs().maxCoeff() <=
            tolerance * expected.cwiseAbs().maxCoeff());
      REQUIRE(together[k].rows() == covariance.rows());
      CHECK((together[k] - expected).cwiseAbs().maxCoeff() <=
            tolerance * expected.cwiseAbs().maxCoeff());
      // A' Sigma A, from the same factor as Sigma: equal to rounding.
      const Eigen::MatrixXd& A = projections[k].A;
      const Eigen::MatrixXd expected_projected = A.transpose() * covariance * A;
      REQUIRE(projected[k].rows() == A.cols());
      CHECK((projected[k] - expected_projected).cwiseAbs().maxCoeff() <=
            kCovarianceTolerance * expected_projected.cwiseAbs().maxCoeff());
    }
  };
  // Built pose by pose: the factor's linearization points lag the estimate.
  check(lazy ? kModelCovarianceTolerance : kLaggingCovarianceTolerance);
  // Linearized afresh at the estimate: the same to rounding.
  std::vector<int> vertices;
  for (int v = 0; v < n; ++v) vertices.push_back(v);
  std::vector<int> edges;
  for (int e = 0; e < graph.num_edges(); ++e) edges.push_back(e);
  REQUIRE(solver.Reset(vertices, edges, estimate).ok);
  check(kCovarianceTolerance);
  // The anchor is held fixed: zero rows and columns.
  CHECK(solver.Covariance({0, n - 1}).topRows(TestType::kDim).isZero());
}

TEMPLATE_TEST_CASE("A rolled-back trial leaves the estimate as it was and the factor to rounding",
                   "[incremental]",
                   Pose2,
                   Pose3) {
  const auto synthetic = MakeSyntheticGraph<TestType>(NoisyOptions<TestType>(4));
  const PoseGraph<TestType>& graph = synthetic.graph;
  // The last few loops are left out, to be tried.
  std::vector<char> use(graph.num_edges(), 1);
  const std::vector<int> tried(synthetic.loop_edges.end() - 5, synthetic.loop_edges.end());
  for (int e : tried) use[e] = 0;
  const bool lazy = GENERATE(false, true);
  INFO((lazy ? "moved poses kept at their points while the model holds" : "exact"));
  const IncrementalSolverOptions options = lazy ? IncrementalSolverOptions() : ExactOptions();
  IncrementalSolver<TestType> solver(&graph, options);
  const std::vector<TestType> before = FeedIncrementally(graph, &solver, use);
  const int n = graph.num_vertices();
  const std::vector<int> query = {n / 4, n / 2, n - 1};
  const Eigen::MatrixXd covariance_before = solver.Covariance(query);
  const double chi2_before = solver.chi2();

  solver.Checkpoint();
  REQUIRE(solver.InTrial());
  REQUIRE(solver.Add(tried).ok);
  CHECK(solver.chi2() > chi2_before);
  solver.Rollback();
  CHECK(!solver.InTrial());
  CHECK(solver.chi2() == chi2_before);
  for (int v = 0; v < n; ++v) {
    CHECK(solver.estimate(v).translation() == before[v].translation());
  }
  // The factor is the checkpoint's, to the rounding of the updates taken back.
  const Eigen::MatrixXd covariance = solver.Covariance(query);
  CHECK((covariance - covariance_before).cwiseAbs().maxCoeff() <=
        kCovarianceTolerance * covariance_before.cwiseAbs().maxCoeff());

  // Tried again and kept: the optimum with them, as a batch solve finds it (to the model
  // tolerance's chi2 where moved poses keep their points).
  solver.Checkpoint();
  REQUIRE(solver.Add(tried).ok);
  solver.Commit();
  std::vector<TestType> estimate(n);
  for (int v = 0; v < n; ++v) estimate[v] = solver.estimate(v);
  const std::vector<char> all(graph.num_edges(), 1);
  if (!lazy) {
    CheckAtBatchOptimum(graph, all, solver, estimate);
  } else {
    double dof = 0.0;
    const double optimum = BatchOptimumChi2(graph, all, estimate, &dof);
    CHECK(solver.ExactChi2() >= optimum * (1.0 - kChi2Tolerance));
    CHECK(solver.ExactChi2() - optimum <= ModelChi2Slack(options, optimum, dof));
  }
}

TEMPLATE_TEST_CASE("Removing loops returns to the optimum without them",
                   "[incremental]",
                   Pose2,
                   Pose3) {
  const auto synthetic = MakeSyntheticGraph<TestType>(NoisyOptions<TestType>(5));
  const PoseGraph<TestType>& graph = synthetic.graph;
  IncrementalSolver<TestType> solver(&graph, ExactOptions());
  std::vector<char> active(graph.num_edges(), 1);
  FeedIncrementally(graph, &solver, active);
  // Every other loop leaves (odometry keeps every pose in the problem).
  std::vector<int> removed;
  for (size_t k = 0; k < synthetic.loop_edges.size(); k += 2) {
    removed.push_back(synthetic.loop_edges[k]);
    active[synthetic.loop_edges[k]] = 0;
  }
  const IncrementalSummary summary = solver.Remove(removed);
  REQUIRE(summary.ok);
  std::vector<TestType> estimate(graph.num_vertices());
  for (int v = 0; v < graph.num_vertices(); ++v) estimate[v] = solver.estimate(v);
  CheckAtBatchOptimum(graph, active, solver, estimate);
}

// Tries `edge` in a trial that must end at most at `target_chi2`, rolls it back and returns what
// the trial did.
template <class Pose>
IncrementalSummary TryAndRollBack(IncrementalSolver<Pose>* solver,
                                  int edge,
                                  double target_chi2 = std::numeric_limits<double>::infinity()) {
  solver->Checkpoint(target_chi2);
  const IncrementalSummary summary = solver->Add({edge});
  solver->Rollback();
  return summary;
}

TEMPLATE_TEST_CASE("A trial whose batch solve does not settle it within its iterations fails",
                   "[incremental]",
                   Pose2,
                   Pose3) {
  auto synthetic = MakeSyntheticGraph<TestType>(NoisyOptions<TestType>(6));
  PoseGraph<TestType>& graph = synthetic.graph;
  const std::vector<char> use(graph.num_edges(), 1);
  const int wrong = AddFarWrongLoop(&graph);
  auto trial = [&](int batch_iterations) {
    IncrementalSolverOptions options = ExactOptions();
    options.trial_batch_max_iterations = batch_iterations;
    IncrementalSolver<TestType> solver(&graph, options);
    std::vector<char> all = use;
    all.push_back(0);
    FeedIncrementally(graph, &solver, all);
    return TryAndRollBack(&solver, wrong);
  };
  const IncrementalSummary settled = trial(100);
  const IncrementalSummary cut = trial(1);
  INFO(settled.message << " / " << cut.message);
  CHECK(settled.ok);
  CHECK(!cut.ok);
  CHECK(cut.message == "did not converge");
}

TEMPLATE_TEST_CASE("A trial fails as soon as its target chi2 is out of its batch solve's reach",
                   "[incremental]",
                   Pose2,
                   Pose3) {
  auto synthetic = MakeSyntheticGraph<TestType>(NoisyOptions<TestType>(6));
  PoseGraph<TestType>& graph = synthetic.graph;
  std::vector<char> use(graph.num_edges(), 1);
  // The wrong loop sends the trial to its batch solve.
  const int wrong = AddFarWrongLoop(&graph);
  use.push_back(0);
  IncrementalSolverOptions options = ExactOptions();
  options.trial_batch_max_iterations = 100;
  IncrementalSolver<TestType> solver(&graph, options);
  FeedIncrementally(graph, &solver, use);
  const double before = solver.chi2();
  auto trial = [&](double target_chi2) { return TryAndRollBack(&solver, wrong, target_chi2); };
  const IncrementalSummary settled = trial(std::numeric_limits<double>::infinity());
  REQUIRE(settled.ok);
  const double increase = settled.chi2 - before;
  REQUIRE(increase > 0.0);
  // Half the increase it settles at: out of reach.
  const IncrementalSummary cut = trial(before + 0.5 * increase);
  INFO(settled.message << " / " << cut.message);
  CHECK(!cut.ok);
  CHECK(cut.message == "the trial's target chi2 is out of reach");
  CHECK(solver.chi2() == before);  // rolled back
  // Twice the increase: reached, as without a target (to the rounding a rollback leaves in the
  // factor).
  const IncrementalSummary reached = trial(before + 2.0 * increase);
  CHECK(reached.ok);
  CHECK(reached.chi2 == Approx(settled.chi2).epsilon(1e-9));
}

TEST_CASE("Reset starts from the given poses, anchored at the first", "[incremental]") {
  const auto synthetic = MakeSyntheticGraph<Pose2>(NoisyOptions<Pose2>(6));
  const PoseGraph<Pose2>& graph = synthetic.graph;
  std::vector<int> vertices;
  for (int v = 0; v < graph.num_vertices(); ++v) vertices.push_back(v);
  std::vector<int> edges;
  for (int e = 0; e < graph.num_edges(); ++e) edges.push_back(e);
  // From the batch optimum moved rigidly: the anchor keeps where it is given.
  std::vector<Pose2> estimate = graph.initial_estimate();
  Optimizer<Pose2> optimizer;
  REQUIRE(optimizer.Solve(graph, std::vector<char>(graph.num_edges(), 1), &estimate)
              .IsSolutionUsable());
  const Pose2 moved(3.0, -2.0, 0.7);
  for (Pose2& pose : estimate) pose = moved * pose;
  IncrementalSolver<Pose2> solver(&graph, IncrementalSolverOptions());
  const IncrementalSummary summary = solver.Reset(vertices, edges, estimate);
  REQUIRE(summary.ok);
  CHECK(summary.iterations == 1);  // already at the optimum
  CHECK(solver.anchor() == 0);
  CHECK((solver.estimate(0).translation() - moved.translation()).norm() == 0.0);
  double translation = 0.0;
  double rotation = 0.0;
  std::vector<Pose2> now(graph.num_vertices());
  for (int v = 0; v < graph.num_vertices(); ++v) now[v] = solver.estimate(v);
  RelativeDifference(estimate, now, 0, &translation, &rotation);
  CHECK(translation < kOptimumToleranceM);
  CHECK(rotation < kOptimumToleranceRad);
}

}  // namespace
}  // namespace irrr
