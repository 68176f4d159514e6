#ifndef IRRR_CORE_ODOMETRY_COVARIANCE_H_
#define IRRR_CORE_ODOMETRY_COVARIANCE_H_

// The covariance of dead reckoning between two poses of a session, to first order. Step k's
// noise, moved into the session's frame by the adjoint of the dead-reckoned pose it ends at, is
// summed along the session; the relative covariance of any stretch is a difference of two sums
// moved into its last pose's frame. A query costs the same whatever the stretch's length.

#include <vector>

#include "core/pose_graph.h"

namespace irrr {

template <class Pose>
class OdometryCovariance {
 public:
  using Matrix = typename Pose::Matrix;

  // `graph` and `dead_reckoning` (one pose per vertex, each session from the identity) must
  // outlive this object; both may grow, and Update() takes in what was added.
  OdometryCovariance(const PoseGraph<Pose>* graph, const std::vector<Pose>* dead_reckoning);

  // Extends the prefix sums to every vertex of the graph.
  void Update();
  // Computes them again from the first vertex (after an odometry edge's information changed).
  void Recompute();

  // The covariance of the dead reckoning from the p-th to the q-th pose of a session, as a
  // perturbation on its right (D(p -> q) * Exp(xi)).
  Matrix Relative(int session, int p, int q) const;

  // A vertex's place in its session.
  int Position(int vertex) const { return position_[vertex]; }

 private:
  const PoseGraph<Pose>* graph_;
  const std::vector<Pose>* dead_reckoning_;
  std::vector<Matrix> prefix_;  // per vertex: the sum of its session's odometry noise up to it
  std::vector<int> position_;   // per vertex: its place in its session
};

extern template class OdometryCovariance<Pose2>;
extern template class OdometryCovariance<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_ODOMETRY_COVARIANCE_H_
