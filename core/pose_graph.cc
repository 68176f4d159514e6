#include "core/pose_graph.h"

#include <cmath>
#include <sstream>

#include <Eigen/Eigenvalues>

namespace irrr {
namespace {

// Information matrices arrive as printed decimals; asymmetry below this fraction of the largest
// entry is rounding, above it a wrong matrix.
constexpr double kSymmetryTolerance = 1e-9;
// A stored unit quaternion may have drifted by rounding; beyond this it is not a rotation.
constexpr double kUnitQuaternionTolerance = 1e-6;
// Eigenvalues of a singular matrix come out of rounding as +-6e-16 of the largest one, so a
// positive smallest eigenvalue alone does not prove definiteness; below this fraction of the
// largest the matrix is numerically singular. Real datasets go down to 4e-12 (Intel, Carlone's
// g2o copy).
constexpr double kMinEigenvalueRatio = 1e-14;

std::string Describe(const Vertex& v) {
  std::ostringstream s;
  s << "vertex " << v.id;
  return s.str();
}

}  // namespace

template <class Pose>
Status ValidateInformation(const typename Pose::Matrix& information) {
  if (!information.allFinite()) return Status::Error("information matrix has non-finite entries");
  const double scale = information.cwiseAbs().maxCoeff();
  if ((information - information.transpose()).cwiseAbs().maxCoeff() > kSymmetryTolerance * scale) {
    return Status::Error("information matrix is not symmetric");
  }
  Eigen::SelfAdjointEigenSolver<typename Pose::Matrix> eigen(information, Eigen::EigenvaluesOnly);
  if (eigen.info() != Eigen::Success ||
      !(eigen.eigenvalues().minCoeff() >
        kMinEigenvalueRatio * eigen.eigenvalues().cwiseAbs().maxCoeff())) {
    std::ostringstream s;
    s << "information matrix is not positive definite (smallest eigenvalue "
      << eigen.eigenvalues().minCoeff() << ")";
    return Status::Error(s.str());
  }
  return Status::Ok();
}

template <class Pose>
Status ValidatePose(const Pose& pose) {
  if (!pose.IsFinite()) return Status::Error("pose has non-finite numbers");
  if constexpr (std::is_same_v<Pose, Pose3>) {
    if (std::abs(pose.quaternion().norm() - 1.0) > kUnitQuaternionTolerance) {
      return Status::Error("quaternion is not of unit norm");
    }
  }
  return Status::Ok();
}

template <class Pose>
Status PoseGraph<Pose>::AddSession(int64_t session_id, int* session_index) {
  if (session_index_.count(session_id) != 0) {
    return Status::Error("session " + std::to_string(session_id) + " exists already");
  }
  const int index = num_sessions();
  sessions_.push_back(Session{session_id, {}});
  session_index_.emplace(session_id, index);
  if (session_index != nullptr) *session_index = index;
  return Status::Ok();
}

template <class Pose>
Status PoseGraph<Pose>::AddPose(int session,
                                int64_t vertex_id,
                                double stamp,
                                const Pose& initial_estimate,
                                const Pose* odometry,
                                const Matrix* odometry_information,
                                int* vertex_index) {
  const std::string what = "vertex " + std::to_string(vertex_id);
  if (session < 0 || session >= num_sessions()) {
    return Status::Error(what + ": unknown session index " + std::to_string(session));
  }
  if (vertex_index_.count(vertex_id) != 0) return Status::Error(what + ": duplicate vertex id");
  if (!std::isfinite(stamp)) return Status::Error(what + ": non-finite stamp");
  if (Status s = ValidatePose(initial_estimate); !s.ok()) {
    return Status::Error(what + ": initial estimate: " + s.message());
  }
  const Session& owner = sessions_[session];
  const bool first = owner.vertices.empty();
  if (first && odometry != nullptr) {
    return Status::Error(what + ": the first pose of a session has no odometry edge");
  }
  if (!first) {
    if (odometry == nullptr || odometry_information == nullptr) {
      return Status::Error(what + ": missing odometry edge from the previous pose");
    }
    if (stamp < vertices_[owner.vertices.back()].stamp) {
      return Status::Error(what + ": stamp is older than the session's previous pose");
    }
    if (Status s = ValidatePose(*odometry); !s.ok()) {
      return Status::Error(what + ": odometry: " + s.message());
    }
    if (Status s = ValidateInformation<Pose>(*odometry_information); !s.ok()) {
      return Status::Error(what + ": odometry: " + s.message());
    }
  }

  const int index = num_vertices();
  odometry_into_.push_back(first ? -1 : num_edges());
  if (!first) {
    Edge<Pose> edge;
    edge.from = owner.vertices.back();
    edge.to = index;
    edge.measurement = *odometry;
    edge.information = *odometry_information;
    edge.kind = EdgeKind::kOdometry;
    edges_.push_back(edge);
  }
  vertices_.push_back(Vertex{vertex_id, session, stamp});
  sessions_[session].vertices.push_back(index);
  initial_estimate_.push_back(initial_estimate);
  vertex_index_.emplace(vertex_id, index);
  if (vertex_index != nullptr) *vertex_index = index;
  return Status::Ok();
}

template <class Pose>
Status PoseGraph<Pose>::AddLoop(int from_vertex,
                                int to_vertex,
                                const Pose& measurement,
                                const Matrix& information,
                                int* edge_index) {
  if (from_vertex < 0 || from_vertex >= num_vertices() || to_vertex < 0 ||
      to_vertex >= num_vertices()) {
    return Status::Error("loop " + std::to_string(from_vertex) + " -> " +
                         std::to_string(to_vertex) + ": unknown vertex index");
  }
  const std::string what =
      "loop " + Describe(vertices_[from_vertex]) + " -> " + Describe(vertices_[to_vertex]);
  if (from_vertex == to_vertex) return Status::Error(what + ": self-loop");
  if (Status s = ValidatePose(measurement); !s.ok()) {
    return Status::Error(what + ": measurement: " + s.message());
  }
  if (Status s = ValidateInformation<Pose>(information); !s.ok()) {
    return Status::Error(what + ": " + s.message());
  }
  Edge<Pose> edge;
  edge.from = from_vertex;
  edge.to = to_vertex;
  edge.measurement = measurement;
  edge.information = information;
  edge.kind = EdgeKind::kLoop;
  if (edge_index != nullptr) *edge_index = num_edges();
  edges_.push_back(edge);
  return Status::Ok();
}

template <class Pose>
Status PoseGraph<Pose>::SetInformation(int edge, const Matrix& information) {
  if (edge < 0 || edge >= num_edges()) {
    return Status::Error("edge " + std::to_string(edge) + ": unknown edge index");
  }
  if (Status s = ValidateInformation<Pose>(information); !s.ok()) {
    return Status::Error("edge " + std::to_string(edge) + ": " + s.message());
  }
  edges_[edge].information = information;
  return Status::Ok();
}

template <class Pose>
int PoseGraph<Pose>::FindVertex(int64_t vertex_id) const {
  const auto it = vertex_index_.find(vertex_id);
  return it == vertex_index_.end() ? -1 : it->second;
}

template <class Pose>
int PoseGraph<Pose>::FindSession(int64_t session_id) const {
  const auto it = session_index_.find(session_id);
  return it == session_index_.end() ? -1 : it->second;
}

template <class Pose>
std::vector<Pose> PoseGraph<Pose>::OdometryEstimate() const {
  std::vector<Pose> estimate(vertices_.size());
  for (const Edge<Pose>& e : edges_) {
    // Odometry edges are stored in the order their poses arrived, so `from` is already chained.
    if (e.kind == EdgeKind::kOdometry) estimate[e.to] = estimate[e.from] * e.measurement;
  }
  return estimate;
}

template Status ValidateInformation<Pose2>(const Pose2::Matrix&);
template Status ValidateInformation<Pose3>(const Pose3::Matrix&);
template Status ValidatePose<Pose2>(const Pose2&);
template Status ValidatePose<Pose3>(const Pose3&);
template class PoseGraph<Pose2>;
template class PoseGraph<Pose3>;

}  // namespace irrr
