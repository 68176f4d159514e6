#ifndef IRRR_CORE_WARM_ENGINE_H_
#define IRRR_CORE_WARM_ENGINE_H_

// The default decision engine: iRRR on a warm, incremental good-set estimate (algorithm-notes,
// "Where a check starts (revised)" and "Beyond the paper"; docs/decisions.md).
//
// The good set's optimum is kept per component by GoodSet. A closed cluster is judged cheapest
// first, every threshold a chi-square quantile times the estimated variance factor:
//   1. the screen: each link's residual at the current optimum against S = J Sigma J' + Omega^-1,
//      Sigma from the component's factor; links far off leave without any nonlinear solve;
//   2. Algorithm 1 on the cluster's local problem (WarmIntraCluster);
//   3. the joint test at the warm optimum of good set + cluster (a trial on the good set): the
//      chi2 increase against its threshold, the cluster's consistency index and each link's d^2.
//      A cluster that passes joins the good set.
//   4. Algorithm 2's elimination with reversal: a cluster that fails while good clusters are
//      inconsistent too is remembered as their opponent; once the opponents outweigh a suspect,
//      the good set is built again without the suspects and with the opponents that pass (the
//      largest consistent set wins). Clusters accepted under a variance factor far above today's
//      are judged again (Revalidate).
// Until the variance factor is known, clusters wait; a lone link the good set cannot check waits
// for support.

#include <memory>
#include <vector>

#include "core/decisions.h"
#include "core/irrr_options.h"
#include "core/pose_graph.h"

namespace irrr {

template <class Pose>
class WarmEngine {
 public:
  // Everything given must outlive the engine. `estimate` receives the good set's optimum (one pose
  // per vertex), `dead_reckoning` holds each session's odometry chained from the identity.
  // The engine changes the information of the odometry edges it finds faulty in `graph`
  // (WeakenedOdometry).
  WarmEngine(PoseGraph<Pose>* graph,
             const IrrrOptions* options,
             DecisionBook* book,
             std::vector<Pose>* estimate,
             const std::vector<Pose>* dead_reckoning);
  ~WarmEngine();

  // The graph's newest vertex has arrived (after its odometry edge).
  void AddPose(int vertex);
  // A flush or a session's end: clusters waiting for a variance factor are judged with the
  // information as given if none is known by their step.
  void Release();
  // Whether released clusters wait for a step of their own.
  bool HasReleased() const;
  // Whether a step budget (IrrrOptions::step_budget) left decision work for a step of its own.
  bool HasDeferred() const;
  // Judges closed cluster `cluster` (-1: only what waits) against the good set.
  void Step(int cluster, StepResult* result);

  // The odometry edges found faulty (ascending): those the arbiter weakened (WeakenedOdometry), and
  // those the accepted loops refute beyond the odometry's own noise (Baarda's w-test at the good
  // set's optimum). An error between two poses the loops hold shows in every odometry edge between
  // them: a fault is flagged as the stretch of edges it lies in.
  std::vector<int> OdometryFaults() const;
  // The odometry edges the arbiter found faulty (ascending): their information is scaled by
  // kFaultWeight in the graph, as if the session were split there and joined again by its loops.
  std::vector<int> WeakenedOdometry() const;
  // The information graph edge `edge` was given with (before any weakening).
  const typename Pose::Matrix& GivenInformation(int edge) const;
  // Before Restore: the odometry edges a snapshot's engine had weakened are weakened again.
  void RestoreWeakened(const std::vector<int>& edges);

  // Every session's component under the good set, numbered by earliest session.
  std::vector<int> Components() const;

  // After the book and the estimate were restored (a snapshot): the good set is rebuilt from them.
  void Restore();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

extern template class WarmEngine<Pose2>;
extern template class WarmEngine<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_WARM_ENGINE_H_
