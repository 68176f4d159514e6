#include "core/robust_solve.h"

#include <algorithm>
#include <cmath>

#include "core/optimizer.h"
#include "core/test_statistics.h"

namespace irrr {
namespace {

// The loops' d^2 at `estimate` (odometry entries 0).
template <class Pose>
std::vector<double> LoopChi2(const PoseGraph<Pose>& graph, const std::vector<Pose>& estimate) {
  std::vector<double> chi2(graph.num_edges(), 0.0);
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kLoop) chi2[e] = EdgeChi2(graph.edge(e), estimate);
  }
  return chi2;
}

// DCS's scale of a loop with chi2 `d2` (Agarwal et al. 2013, eq. 15).
double DcsScale(double phi, double d2) { return std::min(1.0, 2.0 * phi / (phi + d2)); }

// GNC-TLS's weight of a loop with chi2 `d2` at control parameter `mu` (Yang et al. 2020, eq. 14).
double TlsWeight(double c2, double mu, double d2) {
  if (d2 <= mu / (mu + 1.0) * c2) return 1.0;
  if (d2 >= (mu + 1.0) / mu * c2) return 0.0;
  return std::sqrt(c2 * mu * (mu + 1.0) / d2) - mu;
}

template <class Pose>
class RobustSolver {
 public:
  RobustSolver(const PoseGraph<Pose>& graph, const RobustOptions& options)
      : graph_(graph), options_(options) {}

  Status Dcs(std::vector<Pose> estimate, RobustResult<Pose>* result) {
    OptimizerOptions step_options;
    step_options.max_iterations = 1;
    step_options.pattern = SparsityPattern::kAllEdges;
    Optimizer<Pose> optimizer(step_options);
    const std::vector<char> active(graph_.num_edges(), 1);
    std::vector<double> information_scale(graph_.num_edges(), 1.0);
    double previous_cost = -1.0;
    int outer = 0;
    int solves = 0;
    bool converged = false;
    for (; outer < options_.dcs_iterations; ++outer) {
      double cost = 0.0;
      for (int e = 0; e < graph_.num_edges(); ++e) {
        const double phi = Phi(e);
        if (phi == 0.0) continue;
        const double chi2 = EdgeChi2(graph_.edge(e), estimate);
        const double s = DcsScale(phi, chi2);
        information_scale[e] = s * s;
        cost += s * s * chi2;
      }
      if (previous_cost >= 0.0 &&
          std::abs(previous_cost - cost) <= options_.function_tolerance * cost) {
        converged = true;
        break;
      }
      previous_cost = cost;
      const OptimizerSummary summary =
          optimizer.SolveWeighted(graph_, active, information_scale, &estimate);
      solves += summary.iterations;
      if (!summary.IsSolutionUsable()) return Status::Error("DCS: " + summary.message);
    }
    Finish(estimate, result);
    for (int e = 0; e < graph_.num_edges(); ++e) {
      const double phi = Phi(e);
      if (phi == 0.0) continue;
      result->weight[e] = DcsScale(phi, result->edge_chi2[e]);
      result->threshold[e] = 3.0 * phi;
    }
    result->outer_iterations = outer;
    result->solver_iterations = solves;
    result->converged = converged;
    result->message =
        converged ? "the robust cost stopped falling" : "the reweighting limit was reached";
    return Status::Ok();
  }

  // DCS's Phi of edge e; 0 for a known inlier.
  double Phi(int e) const {
    return graph_.edge(e).kind == EdgeKind::kLoop ? options_.dcs_phi : options_.dcs_odometry_phi;
  }

  // Yang et al. 2020, Algorithm 1 with known inliers (the odometry), as GTSAM's GncOptimizer
  // runs it: mu from the residuals of the dead reckoning (Remark 5), the first weights from the
  // trusting solve, then weights and weighted solves while mu grows. Every weighted solve starts
  // again from the dead reckoning, so a fold that an early, poorly weighted solve fell into is not
  // carried on. Stops when the weights are binary or the weighted cost stops changing.
  Status GncTls(RobustResult<Pose>* result) {
    OptimizerOptions inner_options;
    inner_options.max_iterations = options_.gnc_inner_iterations;
    inner_options.function_tolerance = 1e-6;
    inner_options.pattern = SparsityPattern::kAllEdges;
    // Levenberg-Marquardt, as GTSAM's usual base optimizer: from the dead reckoning, Gauss-Newton's
    // halved steps can settle in a fold that satisfies a wrong loop (Manhattan + 100 random).
    inner_options.algorithm = OptimizerAlgorithm::kLevenbergMarquardt;
    Optimizer<Pose> optimizer(inner_options);
    const double c2 = ChiSquareQuantile(options_.inlier_probability, Pose::kDim);
    const std::vector<Pose> dead_reckoning = graph_.OdometryEstimate();
    std::vector<Pose> estimate = dead_reckoning;
    std::vector<double> weight(graph_.num_edges(), 1.0);
    std::vector<char> active(graph_.num_edges(), 1);
    int solves = 0;
    double cost = 0.0;
    auto solve = [&]() -> Status {
      estimate = dead_reckoning;
      const OptimizerSummary summary = optimizer.SolveWeighted(graph_, active, weight, &estimate);
      solves += summary.iterations;
      if (!summary.IsSolutionUsable()) return Status::Error("GNC: " + summary.message);
      cost = summary.final_chi2;
      return Status::Ok();
    };
    // Remark 5: the surrogate is convex for mu <= c^2 / (2 max d^2 - c^2), d^2 at the start.
    const double max_chi2 = [&] {
      const std::vector<double> start = LoopChi2(graph_, dead_reckoning);
      return *std::max_element(start.begin(), start.end());
    }();
    if (Status s = solve(); !s.ok()) return s;
    std::vector<double> chi2 = LoopChi2(graph_, estimate);
    int outer = 0;
    bool converged = 2.0 * max_chi2 <= c2;  // every loop an inlier from the start
    double mu = converged ? 1.0 : std::max(1e-6, c2 / (2.0 * max_chi2 - c2));
    while (!converged && outer < options_.gnc_max_outer_iterations) {
      ++outer;
      bool binary = true;
      for (int e = 0; e < graph_.num_edges(); ++e) {
        if (graph_.edge(e).kind != EdgeKind::kLoop) continue;
        weight[e] = TlsWeight(c2, mu, chi2[e]);
        // A loop at weight 0 leaves the problem: in a graph of several sessions it may be all
        // that joins two of them, and a zero-information edge would leave their gauge free.
        active[e] = weight[e] > 0.0 ? 1 : 0;
        binary = binary && std::min(weight[e], 1.0 - weight[e]) <= options_.gnc_weight_tolerance;
      }
      const double previous_cost = cost;
      if (Status s = solve(); !s.ok()) return s;
      chi2 = LoopChi2(graph_, estimate);
      converged = binary || std::abs(cost - previous_cost) <=
                                options_.gnc_cost_tolerance * std::max(previous_cost, 1e-7);
      if (!converged) mu *= options_.gnc_mu_step;
    }
    Finish(estimate, result);
    for (int e = 0; e < graph_.num_edges(); ++e) {
      if (graph_.edge(e).kind != EdgeKind::kLoop) continue;
      result->weight[e] = weight[e];
      result->threshold[e] = c2;
    }
    result->outer_iterations = outer;
    result->solver_iterations = solves;
    result->converged = converged;
    result->message =
        converged ? "the weights or the cost converged" : "the outer iteration limit was reached";
    return Status::Ok();
  }

 private:
  // The parts of the result both kernels fill the same way.
  void Finish(const std::vector<Pose>& estimate, RobustResult<Pose>* result) const {
    result->estimate = estimate;
    result->weight.assign(graph_.num_edges(), 1.0);
    result->threshold.assign(graph_.num_edges(), 0.0);
    result->edge_chi2.resize(graph_.num_edges());
    for (int e = 0; e < graph_.num_edges(); ++e) {
      result->edge_chi2[e] = EdgeChi2(graph_.edge(e), estimate);
    }
  }

  const PoseGraph<Pose>& graph_;
  const RobustOptions& options_;
};

}  // namespace

const char* RobustKernelName(RobustKernel kernel) {
  switch (kernel) {
    case RobustKernel::kDcs:
      return "dcs";
    case RobustKernel::kGncTls:
      return "gnc";
  }
  return "unknown";
}

Status RobustOptions::Validate() const {
  if (!(dcs_phi > 0.0)) return Status::Error("dcs_phi must be > 0");
  if (!(dcs_odometry_phi >= 0.0 && std::isfinite(dcs_odometry_phi))) {
    return Status::Error("dcs_odometry_phi must be >= 0 and finite");
  }
  if (dcs_iterations < 1) return Status::Error("dcs_iterations must be at least 1");
  if (!(function_tolerance >= 0.0)) return Status::Error("function_tolerance must be >= 0");
  if (!(inlier_probability > 0.0 && inlier_probability < 1.0)) {
    return Status::Error("inlier_probability must be in (0, 1)");
  }
  if (!(gnc_mu_step > 1.0)) return Status::Error("gnc_mu_step must be > 1");
  if (gnc_max_outer_iterations < 1) {
    return Status::Error("gnc_max_outer_iterations must be at least 1");
  }
  if (!(gnc_weight_tolerance >= 0.0 && gnc_weight_tolerance < 0.5)) {
    return Status::Error("gnc_weight_tolerance must be in [0, 0.5)");
  }
  if (!(gnc_cost_tolerance >= 0.0)) return Status::Error("gnc_cost_tolerance must be >= 0");
  if (gnc_inner_iterations < 1) return Status::Error("gnc_inner_iterations must be at least 1");
  return Status::Ok();
}

template <class Pose>
Status RobustSolve(const PoseGraph<Pose>& graph,
                   const RobustOptions& options,
                   const std::vector<Pose>& initial_estimate,
                   RobustResult<Pose>* result) {
  if (Status s = options.Validate(); !s.ok()) return s;
  if (static_cast<int>(initial_estimate.size()) != graph.num_vertices()) {
    return Status::Error("the initial estimate has " + std::to_string(initial_estimate.size()) +
                         " poses, the graph " + std::to_string(graph.num_vertices()));
  }
  RobustSolver<Pose> solver(graph, options);
  RobustResult<Pose> out;
  const Status s = options.kernel == RobustKernel::kDcs ? solver.Dcs(initial_estimate, &out)
                                                        : solver.GncTls(&out);
  if (s.ok()) *result = std::move(out);
  return s;
}

template Status RobustSolve<Pose2>(const PoseGraph<Pose2>&,
                                   const RobustOptions&,
                                   const std::vector<Pose2>&,
                                   RobustResult<Pose2>*);
template Status RobustSolve<Pose3>(const PoseGraph<Pose3>&,
                                   const RobustOptions&,
                                   const std::vector<Pose3>&,
                                   RobustResult<Pose3>*);

}  // namespace irrr
