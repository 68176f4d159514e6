#include "core/time_reversal.h"

#include "core/status.h"

namespace irrr {

// The edge's residual is e = ErrorVector(D), D = z^-1 * (x_from^-1 * x_to) (RelativePoseResidual).
// Near the identity D = Exp(T e), T = TangentOfErrorVector. The inverted edge (to -> from,
// measurement z^-1) has
//   D' = z * (x_to^-1 * x_from) = z * (z * D)^-1 = z * D^-1 * z^-1 = Exp(-Adjoint(z) * T e),
// with Adjoint as pose.h defines it (z Exp(xi) z^-1 = Exp(Adjoint(z) xi)); so e' = -M e with
// M = T^-1 Adjoint(z) T, to first order in e. The information Omega' = M^-T Omega M^-1 is the
// inverse of e''s covariance M Omega^-1 M^T, and gives e'^T Omega' e' = e^T Omega e: the same d^2.
// M^-1 is written T^-1 Adjoint(z^-1) T, exact rather than a numerical inverse, so that inverting
// twice gives Omega back to rounding. tests/time_reversal_test.cc checks the convention
// numerically (the other sign, Adjoint(z^-1) for Adjoint(z), misses by orders of magnitude).
template <class Pose>
typename Pose::Matrix InvertedInformation(const Pose& measurement,
                                          const typename Pose::Matrix& information) {
  using Matrix = typename Pose::Matrix;
  const Matrix T = TangentOfErrorVector<Pose>();
  const Matrix M_inverse = T.inverse() * Adjoint(measurement.Inverse()) * T;
  const Matrix inverted = M_inverse.transpose() * information * M_inverse;
  return 0.5 * (inverted + inverted.transpose());
}

template <class Pose>
ReversedGraph<Pose> TimeReversed(const PoseGraph<Pose>& graph) {
  ReversedGraph<Pose> out;
  out.vertex_of.assign(graph.num_vertices(), -1);
  out.edge_of.assign(graph.num_edges(), -1);
  // Which vertex takes each index: the pose at position k of a session of n poses takes the
  // index of the one at position n - 1 - k.
  std::vector<int> position(graph.num_vertices(), -1);
  for (int s = 0; s < graph.num_sessions(); ++s) {
    IRRR_CHECK(out.graph.AddSession(graph.session(s).id, nullptr).ok());
    const std::vector<int>& vertices = graph.session(s).vertices;
    for (size_t k = 0; k < vertices.size(); ++k) position[vertices[k]] = static_cast<int>(k);
  }
  for (int index = 0; index < graph.num_vertices(); ++index) {
    const int s = graph.vertex(index).session;
    const std::vector<int>& vertices = graph.session(s).vertices;
    const int n = static_cast<int>(vertices.size());
    const int k = n - 1 - position[index];
    const int v = vertices[k];  // the original vertex that takes this index
    const Vertex& vertex = graph.vertex(v);
    const double stamp =
        graph.vertex(vertices.back()).stamp + graph.vertex(vertices.front()).stamp - vertex.stamp;
    // The reversed session reaches v from its time successor, over the edge v -> successor.
    const int odometry = k + 1 < n ? graph.OdometryInto(vertices[k + 1]) : -1;
    Pose measurement;
    typename Pose::Matrix information;
    if (odometry >= 0) {
      const Edge<Pose>& edge = graph.edge(odometry);
      IRRR_CHECK(edge.from == v);
      measurement = edge.measurement.Inverse();
      information = InvertedInformation(edge.measurement, edge.information);
    }
    int reversed = -1;
    const Status status = out.graph.AddPose(s,
                                            vertex.id,
                                            stamp,
                                            graph.initial_estimate()[v],
                                            odometry >= 0 ? &measurement : nullptr,
                                            odometry >= 0 ? &information : nullptr,
                                            &reversed);
    IRRR_CHECK(status.ok());
    out.vertex_of[v] = reversed;
    if (odometry >= 0) out.edge_of[odometry] = out.graph.OdometryInto(reversed);
  }
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose>& edge = graph.edge(e);
    if (edge.kind != EdgeKind::kLoop) continue;
    const Status status = out.graph.AddLoop(out.vertex_of[edge.from],
                                            out.vertex_of[edge.to],
                                            edge.measurement,
                                            edge.information,
                                            &out.edge_of[e]);
    IRRR_CHECK(status.ok());
  }
  return out;
}

template Pose2::Matrix InvertedInformation<Pose2>(const Pose2&, const Pose2::Matrix&);
template Pose3::Matrix InvertedInformation<Pose3>(const Pose3&, const Pose3::Matrix&);
template ReversedGraph<Pose2> TimeReversed<Pose2>(const PoseGraph<Pose2>&);
template ReversedGraph<Pose3> TimeReversed<Pose3>(const PoseGraph<Pose3>&);

}  // namespace irrr
