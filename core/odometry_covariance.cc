#include "core/odometry_covariance.h"

#include <algorithm>

namespace irrr {

template <class Pose>
OdometryCovariance<Pose>::OdometryCovariance(const PoseGraph<Pose>* graph,
                                             const std::vector<Pose>* dead_reckoning)
    : graph_(graph), dead_reckoning_(dead_reckoning) {}

template <class Pose>
void OdometryCovariance<Pose>::Update() {
  const PoseGraph<Pose>& graph = *graph_;
  const Matrix M = TangentOfErrorVector<Pose>();
  for (int v = static_cast<int>(prefix_.size()); v < graph.num_vertices(); ++v) {
    const int odometry = graph.OdometryInto(v);
    if (odometry < 0) {
      prefix_.push_back(Matrix::Zero());
      position_.push_back(0);
      continue;
    }
    const int previous = graph.edge(odometry).from;
    // Step k's noise, in the session's frame: Ad(x_k+1) M C M' Ad(x_k+1)'.
    const Matrix adjoint = Adjoint((*dead_reckoning_)[v]) * M;
    const Matrix covariance = graph.edge(odometry).information.inverse();
    prefix_.push_back(prefix_[previous] + adjoint * covariance * adjoint.transpose());
    position_.push_back(position_[previous] + 1);
  }
}

template <class Pose>
void OdometryCovariance<Pose>::Recompute() {
  prefix_.clear();
  position_.clear();
  Update();
}

template <class Pose>
typename OdometryCovariance<Pose>::Matrix OdometryCovariance<Pose>::Relative(int session,
                                                                             int p,
                                                                             int q) const {
  const std::vector<int>& vertices = graph_->session(session).vertices;
  const std::vector<Pose>& x = *dead_reckoning_;
  if (p == q) return Matrix::Zero();
  const int first = std::min(p, q);
  const int last = std::max(p, q);
  // D(first -> last), perturbed on its right: Ad(x_last)^-1 (S_last - S_first) Ad(x_last)^-T.
  const Matrix to_last = Adjoint(x[vertices[last]].Inverse());
  const Matrix forward =
      to_last * (prefix_[vertices[last]] - prefix_[vertices[first]]) * to_last.transpose();
  if (p < q) return forward;
  // D(p -> q) = D(q -> p)^-1: (T Exp(e))^-1 = T^-1 Exp(-Ad(T) e).
  const Matrix adjoint = Adjoint(x[vertices[q]].Inverse() * x[vertices[p]]);
  return adjoint * forward * adjoint.transpose();
}

template class OdometryCovariance<Pose2>;
template class OdometryCovariance<Pose3>;

}  // namespace irrr
