#ifndef IRRR_CORE_GOOD_SET_H_
#define IRRR_CORE_GOOD_SET_H_

// The warm engine's estimate: the optimum of odometry plus the accepted loops (the good set),
// kept per component (a group of sessions that accepted loops join, paper III.C), each with its
// own IncrementalSolver and in its own frame: that of its earliest session's first pose, which is
// held at the identity. A session that no accepted loop joins to another is a component of its
// own, in its own frame.
//
// New poses extend their component along odometry (the residual is zero: still the optimum).
// Loops are tried before they are trusted: Try() adds them to the component they lie in (or, for
// loops between two components, to a solver of the two merged, the second moved into the first's
// frame through its most agreed-on link) and leaves the trial open; Commit() keeps it, Rollback()
// returns to the good set before it. Removing loops (a reversal) rebuilds the components.
//
// The estimate is written into the vector given at construction (one pose per vertex).

#include <limits>
#include <memory>
#include <vector>

#include "core/incremental_solver.h"
#include "core/pose_graph.h"
#include "core/test_statistics.h"

namespace irrr {

template <class Pose>
class GoodSet {
 public:
  // `graph` and `estimate` must outlive the good set; `estimate` holds one pose per vertex of the
  // graph, and each new pose's entry is written by AddPose.
  GoodSet(const PoseGraph<Pose>* graph,
          std::vector<Pose>* estimate,
          const IncrementalSolverOptions& options);
  ~GoodSet();

  // Vertex `vertex` (the graph's newest) has arrived: its session's first pose starts a component
  // at the identity; a later one extends its session's component along its odometry.
  void AddPose(int vertex);

  // The component of a session (numbered in no particular order; -1 before its first pose).
  int ComponentOf(int session) const;
  // The sessions of a component, in session order.
  std::vector<int> SessionsOf(int component) const;
  // Every session's component, numbered 0, 1, ... by earliest session.
  std::vector<int> Components() const;

  // The joint marginal covariance of each set of poses, all of one component
  // (IncrementalSolver::Covariances), that of the open trial's if they are in it.
  std::vector<Eigen::MatrixXd> Covariances(const std::vector<std::vector<int>>& sets) const;
  // A' Sigma A for each projection, all of one component (IncrementalSolver::
  // ProjectedCovariances), from the open trial's factorization if its poses are in it.
  std::vector<Eigen::MatrixXd> ProjectedCovariances(
      const std::vector<CovarianceProjection>& projections) const;
  // Each loop's linearized addition alone (LinearizeAddition: its chi2 increase and redundancy
  // number) at the estimate, its ends in one component: J Sigma J' of its end poses from the
  // factorization, a few sparse solves per 32 loops. Not during a trial.
  std::vector<LinearizedAddition> LinearizeEach(const std::vector<int>& loops) const;

  // For each group of loops (all in the good set, or in the open trial, in one component): the
  // chi2 its optimum would lose without them, to first order (LinearizeRemoval), at the estimate
  // (the open trial's, during one).
  std::vector<double> LinearizeRemovals(const std::vector<std::vector<int>>& groups) const;

  // A pose of the estimate (of the open trial's, during one).
  const Pose& Estimate(int vertex) const;

  // What a trial of loops found at the optimum with them.
  struct Trial {
    bool ok = false;        // the optimum was found (false: the trial is not open)
    double increase = 0.0;  // chi2 of the components involved: with the loops minus without
    double dof = 0.0;       // the degrees of freedom the loops add (rows minus new freedom)
    bool merges = false;    // the loops join two components
  };
  // Tries `loops` (all between the poses of at most two components) and leaves the trial open:
  // EdgeChi2 reads the trial's optimum until Commit (which writes it into the estimate) or
  // Rollback. At most one trial at a time. Two components are brought into one frame through the
  // link whose alignment the others agree with best, each link's d^2 capped at `alignment_cap`.
  // A trial of 10 loops or more that the incremental solver does not settle is settled by a batch
  // solve; a smaller one is not open (ok false). A caller that rejects an increase above
  // `max_increase` lets a trial in one component fail as unsettled as soon as its batch solve
  // cannot bring the increase down to it (IncrementalSolver::Checkpoint).
  Trial Try(const std::vector<int>& loops,
            double alignment_cap,
            double max_increase = std::numeric_limits<double>::infinity());
  void Commit();
  void Rollback();

  // d^2 of an edge at the current estimate (of the trial, during one).
  double EdgeChi2(int edge) const;

  // The good set becomes odometry plus `good_loops`: the components are formed anew, each in the
  // frame of its earliest session's first pose (frames that the loops join aligned through their
  // most agreed-on link first), and optimized.
  void Rebuild(const std::vector<int>& good_loops, double alignment_cap);
  // Rebuild, with the components as they were kept aside until Restore puts them back exactly
  // (their solvers and estimate: an attempt that fails leaves the good set as it was, without
  // solving it again) or Release lets them go. Not during a trial; one kept set at a time.
  void RebuildKeeping(const std::vector<int>& good_loops, double alignment_cap);
  void Restore();
  void Release();

  // The solver of a component (its estimate, edges and counters).
  const IncrementalSolver<Pose>& Solver(int component) const;

  struct Counters {
    long trials = 0;
    long merges = 0;
    long rebuilds = 0;
    long solves = 0;      // of the linear systems, over every solver so far
    long iterations = 0;  // Gauss-Newton iterations of trials
  };
  Counters counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

extern template class GoodSet<Pose2>;
extern template class GoodSet<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_GOOD_SET_H_
