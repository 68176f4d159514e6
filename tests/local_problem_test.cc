#include "core/local_problem.h"

#include <algorithm>
#include <set>
#include <vector>

#include <catch2/catch.hpp>

#include "core/odometry_covariance.h"
#include "tests/synthetic_graph.h"

namespace irrr {
namespace {

using testing::MakeSyntheticGraph;
using testing::SyntheticOptions;

// The largest set of loops whose ends lie within `window` poses of one loop's ends (one
// cluster's worth), and every fourth loop of the graph (spread over the whole trajectory).
template <class Pose>
std::vector<std::vector<int>> LoopSets(const PoseGraph<Pose>& graph,
                                       const std::vector<int>& loops,
                                       int window) {
  std::vector<int> cluster;
  for (int anchor : loops) {
    const Edge<Pose>& a = graph.edge(anchor);
    std::vector<int> near;
    for (int e : loops) {
      const Edge<Pose>& edge = graph.edge(e);
      if (std::abs(edge.from - a.from) <= window && std::abs(edge.to - a.to) <= window) {
        near.push_back(e);
      }
    }
    if (near.size() > cluster.size()) cluster = near;
  }
  std::vector<int> spread;
  for (size_t k = 0; k < loops.size(); k += 4) spread.push_back(loops[k]);
  return {cluster, spread};
}

// The distinct ends of the loops.
template <class Pose>
int Endpoints(const PoseGraph<Pose>& graph, const std::vector<int>& loops) {
  std::set<int> ends;
  for (int e : loops) {
    ends.insert(graph.edge(e).from);
    ends.insert(graph.edge(e).to);
  }
  return static_cast<int>(ends.size());
}

// Solves each loop set with every pose of the spans and with the odometry between loop ends
// compounded; checks that the compounded problem has only the loop ends as poses and the same
// chi2, degrees of freedom and link chi2 to relative `tolerance`.
template <class Pose>
void CheckCompounded(const SyntheticOptions& options, double tolerance) {
  const auto synthetic = MakeSyntheticGraph<Pose>(options);
  const PoseGraph<Pose>& graph = synthetic.graph;
  const std::vector<Pose> dead_reckoning = graph.OdometryEstimate();
  OdometryCovariance<Pose> chains(&graph, &dead_reckoning);
  chains.Update();
  LocalProblems<Pose> whole(&graph, &dead_reckoning, OptimizerOptions());
  LocalProblems<Pose> compounded(&graph, &dead_reckoning, OptimizerOptions());
  compounded.CompoundChains(&chains);
  REQUIRE(synthetic.loop_edges.size() >= 20);
  for (const std::vector<int>& loops : LoopSets(graph, synthetic.loop_edges, 10)) {
    REQUIRE(loops.size() >= 3);
    const LocalSolution a = whole.Solve(whole.SessionsOf(loops), loops, 1e9);
    const LocalSolution b = compounded.Solve(compounded.SessionsOf(loops), loops, 1e9);
    REQUIRE(a.ok());
    REQUIRE(b.ok());
    INFO(loops.size() << " loops; poses " << a.poses_optimized << " -> " << b.poses_optimized
                      << "; chi2 " << a.chi2 << " -> " << b.chi2);
    CHECK(b.poses_optimized == Endpoints(graph, loops));
    CHECK(a.poses_optimized > b.poses_optimized);
    CHECK(b.dof == a.dof);
    CHECK(a.chi2 > 1.0);
    CHECK(b.chi2 == Approx(a.chi2).epsilon(tolerance));
    for (int e : loops) {
      CHECK(b.summary.edge_chi2[e] ==
            Approx(a.summary.edge_chi2[e]).epsilon(tolerance).margin(1e-6));
    }
  }
}

TEMPLATE_TEST_CASE(
    "Compounded odometry gives a local problem the chi2 of every pose: exactly on a linear "
    "graph, to first order with rotation noise",
    "[local]",
    Pose2,
    Pose3) {
  const int sessions = GENERATE(1, 3);
  INFO(sessions << " session(s)");
  // Rotations known to 1e-7 rad: the problem is linear in the translations, and marginalizing a
  // stretch of odometry into one edge is exact (to the optimizer's convergence).
  SyntheticOptions linear;
  linear.num_poses = 240;
  linear.num_sessions = sessions;
  linear.translation_sigma_m = 0.05;
  linear.rotation_sigma_rad = 1e-7;
  linear.loop_probability = 0.3;
  linear.seed = 5;
  CheckCompounded<TestType>(linear, 1e-4);
  // With 0.01 rad of rotation noise the stretch's covariance is that of its dead reckoning, to
  // first order: within a few percent.
  SyntheticOptions noisy = linear;
  noisy.rotation_sigma_rad = 0.01;
  CheckCompounded<TestType>(noisy, 0.05);
}

}  // namespace
}  // namespace irrr
