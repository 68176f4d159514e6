#ifndef IRRR_CORE_LOCAL_PROBLEM_H_
#define IRRR_CORE_LOCAL_PROBLEM_H_

// The optimizations of the paper's tests from dead reckoning: odometry plus a set of loops
// (PoseGraphIC of Algorithm 1, PoseGraphPR and PoseGraphJC of Algorithms 2-3), each session
// started from its own dead reckoning, frames that the loops join aligned through their most
// agreed-on link.
//
// Locality: a stretch of a session's odometry that no loop closes (before its first loop endpoint
// or after its last) has zero residual at the optimum, so only each session's span between its
// first and last loop endpoint is optimized. The chi2 values and degrees of freedom returned are
// those of the whole problem (every pose and odometry edge of the sessions involved), so the
// paper's graph test means what the paper says. The warm engine also compounds the odometry
// between consecutive loop endpoints into one edge each (CompoundChains); the paper engine
// optimizes every pose of the spans.

#include <vector>

#include "core/odometry_covariance.h"
#include "core/optimizer.h"
#include "core/pose_graph.h"

namespace irrr {

struct LocalSolution {
  OptimizerSummary summary;  // edge_chi2 indexed like the graph (0 for edges not in the problem)
  double chi2 = 0.0;         // D^2 at the optimum (summary.final_chi2)
  // Residual rows minus free parameters of the whole problem (sessions' odometry and the loops).
  double dof = 0.0;
  int poses_optimized = 0;  // the poses of the problem actually solved (spans or loop endpoints)
  bool ok() const { return summary.IsSolutionUsable(); }
};

template <class Pose>
class LocalProblems {
 public:
  // `graph` and `dead_reckoning` (one pose per vertex, each session from the identity) must
  // outlive this object and may grow between calls.
  LocalProblems(const PoseGraph<Pose>* graph,
                const std::vector<Pose>* dead_reckoning,
                const OptimizerOptions& options);

  // Optimizes the odometry of `sessions` (one flag per session; every session a loop touches must
  // be set) plus the loops, from dead reckoning. `alignment_cap` bounds each link's chi2 when
  // choosing the link that aligns two frames (a single wrong link cannot set a session's frame).
  // With `estimate` (one pose per vertex), the optimum of the sessions is written there: the
  // spans as optimized, the rest chained along odometry, each component in the frame of its
  // earliest session's first pose; other sessions' poses are left alone.
  LocalSolution Solve(const std::vector<char>& sessions,
                      const std::vector<int>& loops,
                      double alignment_cap,
                      std::vector<Pose>* estimate = nullptr);
  // With `chains` (over the same graph and dead reckoning, kept up to date by its owner), the
  // odometry between two consecutive loop endpoints of a span is one edge: the dead reckoning
  // between them with its compounded covariance. Exact for a linear problem (the stretch's
  // interior poses are marginalized), to first order otherwise; the problem shrinks from the
  // spans' poses to the loops' endpoints. Solves asked for an estimate keep every pose.
  void CompoundChains(const OdometryCovariance<Pose>* chains) { chains_ = chains; }

  // The sessions the loops touch.
  std::vector<char> SessionsOf(const std::vector<int>& loops) const;

  // The loops' redundancy among themselves: as Solve, but for loops within one session whose
  // later ends all come after their earlier ends, the odometry between the two sides is left out
  // (the two sides are optimized as two sessions joined only by the loops). What remains is the
  // loops' agreement with each other and with the short odometry along each side, d x (loops - 1)
  // degrees of freedom: noise only, whatever relative pose the loops claim between the sides
  // (the long odometry between them, bent by a wrong claim, says nothing of the noise).
  LocalSolution InternalRedundancy(const std::vector<int>& loops, double alignment_cap);

  int solves() const { return solves_; }
  int iterations() const { return iterations_; }

 private:
  LocalSolution Solve(const std::vector<char>& sessions,
                      const std::vector<int>& loops,
                      double alignment_cap,
                      std::vector<Pose>* estimate,
                      bool split_sides);

  const PoseGraph<Pose>* graph_;
  const std::vector<Pose>* dead_reckoning_;
  const OdometryCovariance<Pose>* chains_ = nullptr;
  Optimizer<Pose> optimizer_;
  // The last problem solved and its solution (a problem is often asked twice in a row).
  struct Last {
    bool valid = false;
    bool split = false;
    double cap = 0.0;
    std::vector<char> sessions;
    std::vector<int> loops;  // sorted
    int num_vertices = 0;
    LocalSolution solution;
  } last_;
  int solves_ = 0;
  int iterations_ = 0;
};

// Brings the frame groups that `loops` join into one frame (the group of the earliest session),
// group by group in increasing group order. A group is placed through the link, among those
// joining it to the groups already placed, that the others agree with best: the one whose
// alignment minimises the sum of the links' d^2, each capped at `cap`.
template <class Pose>
void AlignFrames(const PoseGraph<Pose>& graph,
                 const std::vector<int>& loops,
                 const std::vector<int>& group_of_session,
                 double cap,
                 std::vector<Pose>* estimate);

extern template class LocalProblems<Pose2>;
extern template class LocalProblems<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_LOCAL_PROBLEM_H_
