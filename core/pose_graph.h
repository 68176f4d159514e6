#ifndef IRRR_CORE_POSE_GRAPH_H_
#define IRRR_CORE_POSE_GRAPH_H_

// A multi-session pose graph (paper section III, algorithm-notes "Graph").
//
// A session is one uninterrupted run of one robot: poses in time order, each joined to the
// previous one by an odometry edge (trusted). A loop hypothesis joins any two poses, in one
// session or in two, and is what iRRR decides about. The graph only grows (an edge's
// information may change); every mutator validates its input and leaves the graph unchanged when
// it returns an error.

#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

#include "core/pose.h"
#include "core/status.h"

namespace irrr {

enum class EdgeKind { kOdometry, kLoop };

// A relative-pose measurement from_T_to with its information matrix (inverse covariance, in the
// error chart of Pose::ErrorVector).
template <class Pose>
struct Edge {
  int from = -1;  // vertex index
  int to = -1;    // vertex index
  Pose measurement;
  typename Pose::Matrix information = Pose::Matrix::Identity();
  EdgeKind kind = EdgeKind::kLoop;
};

struct Vertex {
  int64_t id = 0;      // the caller's identifier (a file's vertex id), unique in the graph
  int session = -1;    // session index
  double stamp = 0.0;  // time of the pose (seconds, or the vertex ordinal for files)
};

struct Session {
  int64_t id = 0;             // the caller's identifier, unique in the graph
  std::vector<int> vertices;  // vertex indices in time order
};

template <class Pose>
class PoseGraph {
 public:
  using Matrix = typename Pose::Matrix;

  // Starts a new session. Fails on a duplicate id.
  Status AddSession(int64_t session_id, int* session_index);

  // Appends a pose to a session with its initial estimate (in any frame; the optimizer only
  // needs a consistent guess). The first pose of a session has no odometry; every later pose
  // must come with the odometry edge previous_T_this. Fails on an unknown session, a duplicate
  // vertex id, a stamp older than the session's last pose, non-finite numbers or an
  // information matrix that is not symmetric positive definite.
  Status AddPose(int session,
                 int64_t vertex_id,
                 double stamp,
                 const Pose& initial_estimate,
                 const Pose* odometry,
                 const Matrix* odometry_information,
                 int* vertex_index);

  // Adds a loop hypothesis from_T_to between two existing vertices. Fails on unknown vertices,
  // a self-loop, non-finite numbers or an information matrix that is not symmetric positive
  // definite. Duplicates are kept as separate measurements.
  Status AddLoop(int from_vertex,
                 int to_vertex,
                 const Pose& measurement,
                 const Matrix& information,
                 int* edge_index);

  // Replaces edge `edge`'s information (an odometry edge found wrong keeps its measurement with
  // far less weight). Fails on an unknown edge or an information matrix that is not symmetric
  // positive definite.
  Status SetInformation(int edge, const Matrix& information);

  int num_vertices() const { return static_cast<int>(vertices_.size()); }
  int num_edges() const { return static_cast<int>(edges_.size()); }
  int num_sessions() const { return static_cast<int>(sessions_.size()); }

  const Vertex& vertex(int index) const { return vertices_[index]; }
  const Edge<Pose>& edge(int index) const { return edges_[index]; }
  const Session& session(int index) const { return sessions_[index]; }
  const std::vector<Edge<Pose>>& edges() const { return edges_; }
  const std::vector<Pose>& initial_estimate() const { return initial_estimate_; }

  // The odometry edge into vertex `index` (from its predecessor in its session), or -1 for a
  // session's first pose.
  int OdometryInto(int index) const { return odometry_into_[index]; }

  // Vertex index for a caller's id, or -1.
  int FindVertex(int64_t vertex_id) const;
  // Session index for a caller's id, or -1.
  int FindSession(int64_t session_id) const;

  // Dead-reckoning estimate: every session starts at the identity and chains its odometry.
  std::vector<Pose> OdometryEstimate() const;

 private:
  std::vector<Vertex> vertices_;
  std::vector<Session> sessions_;
  std::vector<Edge<Pose>> edges_;
  std::vector<Pose> initial_estimate_;
  std::vector<int> odometry_into_;  // per vertex
  std::unordered_map<int64_t, int> vertex_index_;
  std::unordered_map<int64_t, int> session_index_;
};

// Validation of external numbers, shared by the graph, the file readers and the daemon.
// Each returns ok or a sentence naming what is wrong (the caller adds where it came from).
template <class Pose>
Status ValidateInformation(const typename Pose::Matrix& information);
template <class Pose>
Status ValidatePose(const Pose& pose);

extern template class PoseGraph<Pose2>;
extern template class PoseGraph<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_POSE_GRAPH_H_
