#ifndef IRRR_CORE_INTRA_CLUSTER_H_
#define IRRR_CORE_INTRA_CLUSTER_H_

// Algorithm 1 of the paper (intra-cluster consistency): a cluster's links are optimized with the
// odometry that joins them, from dead reckoning, and tested against themselves:
//   graph test  D_G^2 < chi2(alpha, d_G)  at that optimum (the whole cluster);
//   link test   d_l^2 < chi2(alpha, dim)  for each link l.
// Both thresholds are scaled by the variance factor in `thresholds`.

#include <vector>

#include "core/decisions.h"
#include "core/local_problem.h"
#include "core/pairwise_consistency.h"
#include "core/test_statistics.h"

namespace irrr {

// A link's d^2 bounded at this many link thresholds when choosing the link that aligns two
// sessions' frames (so that one wrong link cannot place a session).
constexpr double kAlignmentCap = 10.0;

// The paper's Algorithm 1 as written: a failed graph test rejects the whole cluster
// (kRejectedClusterTest); otherwise each link failing the link test leaves (kRejectedLinkTest)
// and the rest stay (kPending). The graph test's degrees of freedom are the reference code's
// (residual rows) unless `exact_dof` (rows minus free parameters). Sets `in_r` and returns
// whether links remain. Changed loops are appended to `changed` (if not null).
template <class Pose>
bool PaperIntraCluster(LocalProblems<Pose>* problems,
                       const TestThresholds& thresholds,
                       bool exact_dof,
                       int cluster,
                       DecisionBook* book,
                       std::vector<int>* changed);

// The threshold of the pairwise statistic (PairwiseConsistency): the chi-square quantile at 1 -
// 1e-6, scaled by the variance factor. A true link must agree with every other member of its set,
// so a cluster of 100 true links at the tests' 0.999 would lose one link in ten; wrong ones stand
// orders of magnitude above either.
template <class Pose>
double PairwiseThreshold(const TestThresholds& thresholds) {
  return thresholds.variance * ChiSquareQuantile(1.0 - 1e-6, Pose::kDim);
}

// Algorithm 1 of the warm engine (beyond the paper: one wrong link clustered with true ones must
// not take them down with it, nor the reverse). The graph test counts degrees of freedom exactly.
//  - The cluster keeps (`pairwise`, not null) its largest set of pairwise consistent links
//    (PairwiseConsistency::ConsistentSubsets); each other set becomes a cluster of its own.
//  - While the graph test fails, the link with the largest d^2 at the cluster's optimum leaves;
//    when it passes, every link failing the link test leaves; then the cluster is solved again.
//  - Links that left are tried again one by one, most plausible first, and come back when the
//    cluster still passes both tests with them.
//  - Those that stay out form a new cluster (appended to the book), judged the same way: a
//    consistent wrong group clustered in time with true loops is judged on its own.
// Every cluster so made is listed in `splits`. Sets `in_r` and the redundancy (ClusterRedundancy)
// of each; returns whether `cluster` has links left.
template <class Pose>
bool WarmIntraCluster(LocalProblems<Pose>* problems,
                      const PairwiseConsistency<Pose>* pairwise,
                      const TestThresholds& thresholds,
                      int cluster,
                      DecisionBook* book,
                      std::vector<int>* changed,
                      std::vector<int>* splits);

// A sample of the variance factor from a cluster: chi2 and degrees of freedom at `solution`, the
// optimum of its links with the odometry that joins them (Algorithm 1's). None for a single link,
// or when the links agree with each other to rounding (every pairwise statistic against the first
// below kNoiseless per dimension, PairwiseConsistency::Noiseless): a duplicated or synthesized
// constraint carries no noise of its own, and whatever the odometry between its sides must give
// to fit it says nothing of the noise.
constexpr double kNoiseless = 1e-12;
template <class Pose>
RedundancySample ClusterRedundancy(const PairwiseConsistency<Pose>& pairwise,
                                   const std::vector<int>& links,
                                   const LocalSolution& solution);

}  // namespace irrr

#endif  // IRRR_CORE_INTRA_CLUSTER_H_
