#ifndef IRRR_CORE_INCREMENTAL_SOLVER_H_
#define IRRR_CORE_INCREMENTAL_SOLVER_H_

// One component's good-set estimate, kept at its optimum while poses and loops come and go
// (algorithm-notes, "Where a check starts (revised)"): the warm engine's estimate, the source of
// its marginal covariances, and the place where it tries a cluster before trusting it.
//
// The problem is the usual one (paper eq. 3): minimise sum_e r_e(x)' Omega_e r_e(x) over the
// poses of the component, its anchor (the first pose of its earliest session) held fixed. It is
// kept as a Gauss-Newton linear system
//   H delta = b,   H = sum_e J_e' Omega_e J_e,   b = -sum_e J_e' Omega_e r_e,
// with every edge linearized at the linearization points x_lin of its poses, and the estimate is
// x = x_lin (+) delta (Pose::Retract). H is held as a sparse LDL' factorization (CHOLMOD,
// simplicial) that is modified rather than recomputed: an edge added or removed is a rank-d update
// or downdate of the factor, a new pose a row added to it. After a change the system is solved
// again, and the poses whose step from their linearization point has grown past a threshold are
// relinearized (their edges' old terms replaced by new ones), until none has: Gauss-Newton to
// convergence, paying for the part of the graph that moved (as iSAM2's fluid relinearization does
// with a Bayes tree). Poses that moved stay at their old linearization points while the quadratic
// model there still predicts their edges' residuals (model_tolerance): a loop that shifts a
// stretch of the map by centimetres moves hundreds of poses past the thresholds without bending
// any edge. When most of the graph moves, or the factor has filled in past its fill-reducing
// order, everything is linearized anew and factorized under a fresh ordering.
//
// Marginal covariances come from the same factor: with P A P' = L D L', the covariance of
// variables i and j is y_i' D^-1 y_j, y = L^-1 P e; y is nonzero only on the elimination-tree path
// from i to the root, so a few poses cost a few short sparse solves. A projection A' Sigma A (a
// set of edges' J Sigma J', A = J') is Y' D^-1 Y with Y = L^-1 P A: one solve per column of A.
//
// A change can be tried and taken back: Checkpoint() starts a trial, Rollback() returns to the
// checkpoint (estimate, linear system and factor), Commit() keeps the trial.
//
// Core runs no threads; an IncrementalSolver is not safe to use from two threads at once.

#include <limits>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "core/pose_graph.h"
#include "core/status.h"

namespace irrr {

struct IncrementalSolverOptions {
  // A pose is relinearized when its step from its linearization point exceeds either bound
  // (radians of rotation, units of translation, as the graph's measurements). The error the
  // stale Jacobians leave in the estimate is of the order of these times the steps themselves.
  double relinearize_rotation_rad = 1e-3;
  double relinearize_translation = 1e-2;
  // ... unless the quadratic model still predicts the residuals of the edges of the poses past
  // them: the sum of squared (whitened) differences between their exact and model residuals is
  // at most this times D^2 per degree of freedom (of the problem before the change). The
  // estimate then sits within about this many degrees of freedom's D^2 of the exact optimum
  // (measured up to 1.4 times it: the edges of poses within the bounds add their share), which
  // in the poses is millimetres along their weakest directions. 0 relinearizes whatever moved
  // past the bounds. At 0.1 City10000 + 1000 runs in half the time, with the same decisions on
  // every benchmark row.
  double model_tolerance = 0.1;
  // Gauss-Newton iterations of one Optimize (each: a solve, and relinearization of what moved).
  int max_iterations = 30;
  // The same during a trial, which turns to a batch solve half way and fails ("did not
  // converge") if that does not settle it: a change that does not settle bends the problem far (a
  // wrong loop), and its trial is rolled back anyway. True clusters settle in 2 to 4 (Manhattan),
  // the first loop of a long exploration after a batch solve.
  int trial_max_iterations = 12;
  // The batch solve a trial turns to stops after this many iterations: loops that conflict with
  // the problem leave it with large residuals, where Gauss-Newton crawls (83 iterations for 1%
  // of chi2 on a wrong group of the demo's file), and a trial not settled by then fails. It fails
  // sooner when its target chi2 (Checkpoint) is out of reach in the iterations left.
  int trial_batch_max_iterations = 15;
  // Free places for new poses, as a fraction of the poses at a rebuild (at least kMinSpare).
  double spare_fraction = 0.5;
  // A rebuild (a fresh fill-reducing order) is due when the factor has grown past this many times
  // its size after the last one (new poses and loops fill in against the old order).
  double refill_ratio = 2.0;

  Status Validate() const;
};

// A' Sigma A, with Sigma the joint marginal covariance of `vertices` (in the problem, d*m x d*m in
// their order, as Covariance gives it) and A d*m x k: the covariance of k linear functions of the
// poses, such as a set of edges' residuals (A = J').
struct CovarianceProjection {
  std::vector<int> vertices;
  Eigen::MatrixXd A;
};

// What one change of the problem did.
struct IncrementalSummary {
  bool ok = false;       // false: the system could not be solved (see message); the problem is
                         // as the call left it, its estimate the last one that was solved
  int iterations = 0;    // solves of the linear system
  int relinearized = 0;  // poses relinearized
  int rebuilds = 0;      // fresh linearizations and factorizations
  double chi2 = 0.0;     // D^2 of the problem's edges at the estimate (quadratic model)
  std::string message;
};

template <class Pose>
class IncrementalSolver {
 public:
  using Matrix = typename Pose::Matrix;

  // `graph` must outlive the solver; edges and vertices are its indices. Options must be valid.
  IncrementalSolver(const PoseGraph<Pose>* graph, const IncrementalSolverOptions& options);
  ~IncrementalSolver();
  IncrementalSolver(const IncrementalSolver&) = delete;
  IncrementalSolver& operator=(const IncrementalSolver&) = delete;

  // Replaces the problem: the poses `vertices` (the first is the anchor, held fixed), the edges
  // `edges` (each joining two of them), started from `estimate` (indexed like the graph's
  // vertices; only these poses are read). Linearizes there, factorizes and optimizes. The
  // estimate should be near the optimum (a batch solve's or a previous one's): this runs Gauss-
  // Newton without a line search. Ends any trial.
  IncrementalSummary Reset(const std::vector<int>& vertices,
                           const std::vector<int>& edges,
                           const std::vector<Pose>& estimate);

  // Adds pose `vertex`, reached from pose `from` (in the problem) by odometry edge `edge`: its
  // estimate is from's composed with the measurement, so the residual is zero and the estimate
  // is still the optimum. O(1) but for the factor's row.
  void Extend(int vertex, int edge);

  // Adds loop edges between poses of the problem, or removes edges it holds, and returns to the
  // optimum.
  IncrementalSummary Add(const std::vector<int>& edges);
  IncrementalSummary Remove(const std::vector<int>& edges);

  // A trial: Checkpoint() remembers the problem; Rollback() returns to it exactly (the estimate
  // and the linear system bit for bit, the factor to rounding), Commit() forgets it. Extend may
  // not be called during a trial. Checkpoint during a trial is a broken invariant.
  //
  // A trial whose outcome matters only if its chi2 ends at most `target_chi2` fails ("out of
  // reach") as soon as its batch solve finds that it cannot get there in its iterations.
  void Checkpoint(double target_chi2 = std::numeric_limits<double>::infinity());
  void Rollback();
  void Commit();
  bool InTrial() const;

  // The joint marginal covariance of `vertices` (each in the problem) at the estimate: the
  // inverse of H (at the linearization points, which the quadratic model ties to the estimate),
  // d*m x d*m in the order given, in the tangent of Pose::Retract; the anchor has zero rows and
  // columns. The information matrices as given: a caller with a variance
  // factor scales it.
  Eigen::MatrixXd Covariance(const std::vector<int>& vertices) const;
  // The joint marginal covariance of each set of vertices, as Covariance would give it, from one
  // recovery for their union: each set costs the products of its own columns, not the union's.
  std::vector<Eigen::MatrixXd> Covariances(const std::vector<std::vector<int>>& sets) const;
  // A' Sigma A for each projection, from one recovery for the union of their poses: the k columns
  // of A cost k solves along the poses' paths where Sigma itself would cost d*m (A = J' of one
  // edge: d instead of 2d).
  std::vector<Eigen::MatrixXd> ProjectedCovariances(
      const std::vector<CovarianceProjection>& projections) const;

  bool Contains(int vertex) const;
  int anchor() const;
  const Pose& estimate(int vertex) const;  // vertex must be in the problem
  // The point its edges are linearized at in H (the covariances' tangent); within the
  // relinearization bounds or the model tolerance of the estimate.
  const Pose& linearization_point(int vertex) const;
  const std::vector<int>& vertices() const;
  const std::vector<int>& edges() const;  // in the order added
  // D^2 at the estimate (of the quadratic model at the linearization points: close to the exact
  // value while the model predicts the residuals, model_tolerance).
  double chi2() const;
  // The exact D^2 of the problem's edges at the estimate.
  double ExactChi2() const;
  // Degrees of freedom of the problem: d per edge, less d per pose but the anchor.
  double DegreesOfFreedom() const;

  // Work counters, for the benchmarks.
  struct Counters {
    long solves = 0;
    long updates = 0;  // rank-d updates and downdates, and rows added
    long rebuilds = 0;
    long relinearized = 0;
    long batch_solves = 0;  // fallbacks to a batch solve (large corrections)
  };
  const Counters& counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

extern template class IncrementalSolver<Pose2>;
extern template class IncrementalSolver<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_INCREMENTAL_SOLVER_H_
