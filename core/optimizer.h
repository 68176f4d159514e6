#ifndef IRRR_CORE_OPTIMIZER_H_
#define IRRR_CORE_OPTIMIZER_H_

// Sparse nonlinear least squares over a pose graph (paper eq. 3): minimise
//   D^2(x) = sum over the active edges (odometry and loops) of r_ij(x)' Omega_ij r_ij(x)
// by Gauss-Newton or Levenberg-Marquardt on the normal equations, solved with CHOLMOD.
// Gauss-Newton halves a step that would raise D^2, so neither method ever makes it worse.
//
// iRRR solves one graph again and again with different subsets of loop edges, so the subset is
// an argument of Solve, and an Optimizer keeps its symbolic analysis between calls: a solve whose
// sparsity pattern equals the previous one's reuses the ordering and supernodes.
//
// Gauge: each connected component of the active edges has its earliest pose (first pose of its
// earliest session) held fixed; poses in no active edge are not part of the problem and stay
// where they are. Fixed poses keep their place in the linear system with an identity block, so
// the pattern does not depend on which poses are fixed.

#include <limits>
#include <string>
#include <vector>

#include "core/pose_graph.h"
#include "core/sparse_cholesky.h"
#include "core/status.h"

namespace irrr {

enum class OptimizerAlgorithm { kGaussNewton, kLevenbergMarquardt };

enum class SparsityPattern {
  kActiveEdges,  // the normal equations hold the active edges only (least fill)
  kAllEdges,     // every edge of the graph, inactive ones as explicit zeros: one analysis serves
                 // every subset of the same graph
};

struct OptimizerOptions {
  OptimizerAlgorithm algorithm = OptimizerAlgorithm::kGaussNewton;
  SparsityPattern pattern = SparsityPattern::kActiveEdges;
  int max_iterations = 100;
  // Converged when an accepted step lowers chi2 by less than this fraction of it...
  double function_tolerance = 1e-9;
  // ...or moves no coordinate (metres, radians) by more than this.
  double parameter_tolerance = 1e-9;
  // Levenberg-Marquardt: initial damping relative to the largest diagonal entry of J'WJ.
  double initial_damping = 1e-5;

  // Ok, or a sentence naming the first option out of range.
  Status Validate() const;
};

enum class TerminationType {
  kConvergence,    // a tolerance was met
  kNoConvergence,  // max_iterations reached; the estimate is the last accepted iterate
  // Solve's target chi2 cannot be reached in the iterations left at the rate of the last
  // accepted step; the estimate is the last accepted iterate
  kOutOfReach,
  kFailure,  // the linear solver failed or numbers became non-finite; see message
};

const char* TerminationTypeName(TerminationType type);

struct OptimizerSummary {
  TerminationType termination = TerminationType::kFailure;
  std::string message;
  int iterations = 0;             // linear solves (accepted and rejected steps)
  double initial_chi2 = 0.0;      // D^2 over the active edges at the start
  double final_chi2 = 0.0;        // D^2 over the active edges at the returned estimate
  bool estimate_updated = false;  // whether *estimate differs from what was passed in
  std::vector<double>
      edge_chi2;  // d^2 of every graph edge (active or not) at the returned estimate
  int num_active_edges = 0;
  int num_components = 0;
  int residual_dimension = 0;      // rows: Pose::kDim x active edges
  int free_parameters = 0;         // Pose::kDim x (poses - components)
  int linear_solver_analyses = 0;  // symbolic analyses done in this solve (0 when reused)

  bool IsSolutionUsable() const { return termination != TerminationType::kFailure; }
};

template <class Pose>
class Optimizer {
 public:
  explicit Optimizer(const OptimizerOptions& options = OptimizerOptions()) : options_(options) {}

  // Minimises D^2 over the edges with active[e] != 0 (one entry per graph edge, odometry
  // included: a caller that wants only some sessions leaves the others' odometry out). `estimate`
  // holds one pose per vertex on entry and the result on return; it is changed only by accepted
  // steps, so on failure it holds the last good iterate (see estimate_updated). Options must be
  // valid and sizes must match (checked, aborts otherwise).
  //
  // A caller that only needs chi2 to fall to `target_chi2` (a trial that fails above it) lets
  // the solve give up (kOutOfReach) once that cannot happen in the iterations left at the pace of
  // the last accepted step: loops in conflict with the rest leave Gauss-Newton crawling far above
  // any acceptable chi2. From the second iteration on; infinity (the default) never gives up.
  OptimizerSummary Solve(const PoseGraph<Pose>& graph,
                         const std::vector<char>& active,
                         std::vector<Pose>* estimate,
                         double target_chi2 = std::numeric_limits<double>::infinity());

  // The same with the information of each edge e scaled by weights[e] >= 0 (one entry per graph
  // edge): one step of iteratively reweighted least squares for a robust kernel (robust_solve.h).
  // chi2 and the step acceptance are the weighted ones; summary.edge_chi2 stays unweighted.
  OptimizerSummary SolveWeighted(const PoseGraph<Pose>& graph,
                                 const std::vector<char>& active,
                                 const std::vector<double>& weights,
                                 std::vector<Pose>* estimate);

  const OptimizerOptions& options() const { return options_; }

  // Marginal covariances at a point (the inverse of J'WJ there, in the tangent of Pose::Retract;
  // the information matrices as given, so a caller with a variance factor scales them itself).
  // FactorizeAt linearizes the active edges at `estimate` and factorizes; Covariance then returns
  // the joint covariance of `vertices` (d*m x d*m, in the order given) with a few sparse solves, a
  // pose held fixed by the gauge having zero rows and columns. FactorizeAt returns false when J'WJ
  // is not positive definite there; Covariance, when nothing is factorized. A Solve in between
  // discards the factorization.
  bool FactorizeAt(const PoseGraph<Pose>& graph,
                   const std::vector<char>& active,
                   const std::vector<Pose>& estimate);
  bool Covariance(const std::vector<int>& vertices, Eigen::MatrixXd* covariance);

 private:
  // Sets the block pattern of J'WJ for the given active set; returns false if the previous
  // pattern (and with it the symbolic analysis) could be kept.
  bool PrepareLayout(const PoseGraph<Pose>& graph, const std::vector<char>& active);
  // Writes J'WJ (with identity blocks for fixed poses) into the factorization's values and J'Wr
  // into `gradient`; returns D^2 at `estimate`.
  double Linearize(const PoseGraph<Pose>& graph,
                   const std::vector<char>& active,
                   const std::vector<char>& fixed,
                   const std::vector<Pose>& estimate,
                   Eigen::VectorXd* gradient);
  int ValueIndex(int row_vertex, int column_vertex, int row, int column) const;
  // Edge e's information scale: weights_[e] during SolveWeighted, 1 otherwise.
  double Weight(int e) const { return weights_ == nullptr ? 1.0 : (*weights_)[e]; }

  OptimizerOptions options_;
  SparseCholesky cholesky_;
  std::vector<std::vector<int>> column_neighbors_;  // per vertex c: sorted vertices r < c joined
  std::vector<int> block_column_start_;             // first value index of each block column
  std::vector<int> diagonal_value_index_;           // value index of each scalar diagonal entry
  std::vector<char> covariance_fixed_;  // gauge of the FactorizeAt factorization (empty: none)
  const std::vector<double>* weights_ = nullptr;  // set only while SolveWeighted runs
};

// d^2 = r' Omega r of one edge at `estimate` (paper eq. 2).
template <class Pose>
double EdgeChi2(const Edge<Pose>& edge, const std::vector<Pose>& estimate);
// The same with the edge's endpoints at `from` and `to`.
template <class Pose>
double EdgeChi2(const Edge<Pose>& edge, const Pose& from, const Pose& to);

// The connected component of every session for an active set: active edges between two sessions
// join them (a session with no active edge is a component of its own). Components are numbered 0,
// 1, ... in the order of their earliest session.
template <class Pose>
std::vector<int> SessionComponents(const PoseGraph<Pose>& graph, const std::vector<char>& active);

// Which poses the optimizer holds fixed for a given active set: one anchor per connected
// component of the active edges (its earliest session's earliest pose), and every pose in no
// active edge. Returns one flag per vertex and the number of components (if not null).
template <class Pose>
std::vector<char> GaugeAnchors(const PoseGraph<Pose>& graph,
                               const std::vector<char>& active,
                               int* num_components);

extern template class Optimizer<Pose2>;
extern template class Optimizer<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_OPTIMIZER_H_
