#ifndef IRRR_CORE_PAIRWISE_CONSISTENCY_H_
#define IRRR_CORE_PAIRWISE_CONSISTENCY_H_

// Which loop hypotheses of a cluster agree with each other, two at a time (beyond the paper; the
// pairwise consistency of PCM, Mangelson et al. 2018). Two links l and m of a cluster join the
// same two stretches of odometry, side A and side B. With each link oriented A -> B (z: the pose
// of its B end in the frame of its A end), the cycle they close with the odometry between their
// ends,
//   e = D(b_l -> b_m)^-1 * z_l^-1 * D(a_l -> a_m) * z_m      (D: dead reckoning along a session)
// is the identity when both are right. Its covariance, to first order, is that of the two links
// and of the two odometry stretches, moved into e's frame by adjoints; the statistic
//   Log(e)' Cov(e)^-1 Log(e)
// is chi-square with Pose::kDim degrees of freedom (times the variance factor). It uses the
// short odometry along each side only, never the long odometry between the sides: a wrong group
// whose links agree with each other cannot hide in a long chain's slack, and one link that
// contradicts the rest stands out against each of them.
//
// Odometry covariances come from prefix sums along each session's dead reckoning
// (OdometryCovariance), so a pair costs the same whatever the distance between its links.

#include <vector>

#include <Eigen/Core>

#include "core/odometry_covariance.h"
#include "core/pose_graph.h"

namespace irrr {

template <class Pose>
class PairwiseConsistency {
 public:
  using Matrix = typename Pose::Matrix;

  // `graph` and `dead_reckoning` (one pose per vertex, each session from the identity) must
  // outlive this object; both may grow, and Update() takes in what was added.
  PairwiseConsistency(const PoseGraph<Pose>* graph, const std::vector<Pose>* dead_reckoning);

  // Extends the odometry prefix sums to every vertex of the graph.
  void Update() { odometry_.Update(); }
  // Everything again from the graph (after an odometry edge's information changed).
  void Recompute() {
    odometry_.Recompute();
    last_links_.clear();
    last_statistics_.clear();
  }

  // The covariances of the dead reckoning it uses.
  const OdometryCovariance<Pose>& odometry() const { return odometry_; }

  // The statistic of links l and m (graph edge indices, loops of one cluster: the same two
  // sessions, the same orientation of sides). Symmetric in l and m; 0 for l == m.
  double Statistic(int l, int m) const;

  // Whether the links agree with each other to rounding (every statistic against the first below
  // `tiny`): a duplicated or synthesized group, which carries no noise of its own.
  bool Noiseless(const std::vector<int>& links, double tiny) const;

  // The variance factor the links' pairwise statistics imply on their own: the median statistic
  // over their pairs (at most kFactorPairs of them, spread evenly) over the chi-square median. A
  // minority of wrong links moves a median little; 0 for fewer than two links. Pairs share links,
  // and the median comes out low (by a third to 40% on synthetic 3D clusters), which errs toward
  // keeping links together.
  double PairwiseFactor(const std::vector<int>& links) const;

  // The links' largest set of pairwise consistent ones (statistic below `threshold`), found
  // greedily (each link tried as a seed; members added by their number of consistent partners),
  // then the largest among the rest, and so on: every link in exactly one subset, subsets largest
  // first, each in the order of `links`.
  std::vector<std::vector<int>> ConsistentSubsets(const std::vector<int>& links,
                                                  double threshold) const;

 private:
  // A link oriented from side A to side B.
  struct Oriented {
    int a = -1;  // the end on side A (the higher session, or the later pose of one session)
    int b = -1;
    Pose z;             // x_a^-1 x_b as measured
    Matrix covariance;  // of z, as a perturbation on its right
  };
  Oriented Orient(int e) const;
  double Statistic(const Oriented& first, const Oriented& second) const;

  // Statistic(links[i], links[j]) at [i * n + j] for i < j, remembered for the last `links`:
  // a cluster's pairs are asked for by its factor, its calibration and Algorithm 1 in turn. A
  // pair's statistic reads only its two links and the dead reckoning, which never change.
  const std::vector<double>& Statistics(const std::vector<int>& links) const;

  const PoseGraph<Pose>* graph_;
  const std::vector<Pose>* dead_reckoning_;
  OdometryCovariance<Pose> odometry_;
  mutable std::vector<int> last_links_;
  mutable std::vector<double> last_statistics_;
};

extern template class PairwiseConsistency<Pose2>;
extern template class PairwiseConsistency<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_PAIRWISE_CONSISTENCY_H_
