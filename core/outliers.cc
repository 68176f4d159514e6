#include "core/outliers.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <set>
#include <unordered_map>

#include <Eigen/Cholesky>

namespace irrr {
namespace {

// Salts of the odometry streams, so that a seed gives draws unrelated to MakeOutliers' stream of
// the same seed (the tool passes one --seed to all three).
constexpr uint32_t kOdometryNoiseSalt = 0x9e3779b9u;
constexpr uint32_t kOdometryFaultSalt = 0x85ebca6bu;

double Uniform(double lo, double hi, std::mt19937* rng) {
  return std::uniform_real_distribution<double>(lo, hi)(*rng);
}

// A uniformly random unit vector (a normalized standard normal vector). Draws one component at
// a time: the order of a constructor's arguments is unspecified, and the stream must not depend
// on the compiler.
Eigen::Vector3d RandomAxis(std::mt19937* rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  while (true) {
    Eigen::Vector3d v;
    for (int i = 0; i < 3; ++i) v(i) = normal(*rng);
    const double norm = v.norm();
    if (norm > 1e-9) return v / norm;
  }
}

template <class Pose>
Pose RandomMeasurement(double range_m, std::mt19937* rng) {
  std::uniform_real_distribution<double> translation(-range_m, range_m);
  std::uniform_real_distribution<double> angle(-M_PI, M_PI);
  if constexpr (Pose::kDim == 3) {
    return Pose2(translation(*rng), translation(*rng), angle(*rng));
  } else {
    std::normal_distribution<double> normal(0.0, 1.0);
    Eigen::Quaterniond q(normal(*rng), normal(*rng), normal(*rng), normal(*rng));
    q.normalize();
    return Pose3(q, Eigen::Vector3d(translation(*rng), translation(*rng), translation(*rng)));
  }
}

// A perceptual-aliasing claim: translation uniform in the disc or ball of radius `radius_m`
// (rejection from the enclosing cube), rotation within `max_angle_rad`.
template <class Pose>
Pose AliasedMeasurement(double radius_m, double max_angle_rad, std::mt19937* rng) {
  typename Pose::Translation translation;
  do {
    for (int i = 0; i < Pose::kTranslationDim; ++i) translation(i) = Uniform(-1.0, 1.0, rng);
  } while (translation.squaredNorm() > 1.0);
  translation *= radius_m;
  if constexpr (Pose::kDim == 3) {
    return Pose2(translation, Uniform(-max_angle_rad, max_angle_rad, rng));
  } else {
    const Eigen::Vector3d axis = RandomAxis(rng);
    const double angle_rad = Uniform(0.0, max_angle_rad, rng);
    return Pose3(ExpSO3(angle_rad * axis), translation);
  }
}

// A wheel slip or kidnapping: 1-3 m in a random horizontal direction (3D: and up to 0.3 m in z),
// a turn of 0.3-1.0 rad (2D: either sign; 3D: about a random axis).
template <class Pose>
Pose FaultMotion(std::mt19937* rng) {
  const double distance_m = Uniform(1.0, 3.0, rng);
  const double direction_rad = Uniform(-M_PI, M_PI, rng);
  const double angle_rad = Uniform(0.3, 1.0, rng);
  const double x_m = distance_m * std::cos(direction_rad);
  const double y_m = distance_m * std::sin(direction_rad);
  if constexpr (Pose::kDim == 3) {
    const double sign = Uniform(0.0, 1.0, rng) < 0.5 ? -1.0 : 1.0;
    return Pose2(x_m, y_m, sign * angle_rad);
  } else {
    const double z_m = Uniform(-0.3, 0.3, rng);
    const Eigen::Vector3d axis = RandomAxis(rng);
    return Pose3(ExpSO3(angle_rad * axis), Eigen::Vector3d(x_m, y_m, z_m));
  }
}

// The pose whose g2o error vector (Pose::ErrorVector) is `e`; false when there is none (SE(3):
// the quaternion's vector part has norm >= 1).
bool PoseOfErrorVector(const Pose2::Tangent& e, Pose2* pose) {
  *pose = Pose2(e(0), e(1), e(2));
  return true;
}

bool PoseOfErrorVector(const Pose3::Tangent& e, Pose3* pose) {
  const Eigen::Vector3d v = e.tail<3>();
  const double v_squared = v.squaredNorm();
  if (!(v_squared < 1.0)) return false;
  *pose = Pose3(Eigen::Quaterniond(std::sqrt(1.0 - v_squared), v.x(), v.y(), v.z()), e.head<3>());
  return true;
}

// The pose graph of `file` and, for each of its odometry edges, the file edge that holds it.
template <class Pose>
Status ReadOdometry(const GraphFile<Pose>& file,
                    PoseGraph<Pose>* graph,
                    std::vector<int>* file_edge_of_odometry) {
  std::vector<int> graph_edge_of_file_edge;
  if (Status s = BuildPoseGraph(file, graph, &graph_edge_of_file_edge); !s.ok()) return s;
  file_edge_of_odometry->assign(graph->num_edges(), -1);
  for (size_t k = 0; k < graph_edge_of_file_edge.size(); ++k) {
    const int e = graph_edge_of_file_edge[k];
    if (graph->edge(e).kind == EdgeKind::kOdometry) {
      (*file_edge_of_odometry)[e] = static_cast<int>(k);
    }
  }
  return Status::Ok();
}

// Sets every session's vertex estimates (after its first) to its predecessor's composed with the
// file's odometry measurement into it. `graph` was built from `file` (its measurements may have
// changed since; its structure has not).
template <class Pose>
void ChainEstimates(const PoseGraph<Pose>& graph,
                    const std::vector<int>& file_edge_of_odometry,
                    GraphFile<Pose>* file) {
  if (file->vertices.empty()) return;  // edges-only: readers chain the odometry themselves
  std::unordered_map<int64_t, size_t> record_of_id;
  for (size_t k = 0; k < file->vertices.size(); ++k) record_of_id[file->vertices[k].id] = k;
  auto estimate = [&](int vertex) -> Pose& {
    return file->vertices[record_of_id.at(graph.vertex(vertex).id)].estimate;
  };
  for (int s = 0; s < graph.num_sessions(); ++s) {
    const std::vector<int>& vertices = graph.session(s).vertices;
    for (size_t i = 1; i < vertices.size(); ++i) {
      const int odometry = file_edge_of_odometry[graph.OdometryInto(vertices[i])];
      estimate(vertices[i]) = estimate(vertices[i - 1]) * file->edges[odometry].measurement;
    }
  }
}

// A pose is (session, position in the session).
struct Place {
  int session;
  int position;
};

}  // namespace

const char* OutlierModeName(OutlierMode mode) {
  switch (mode) {
    case OutlierMode::kRandom:
      return "random";
    case OutlierMode::kLocal:
      return "local";
    case OutlierMode::kRandomGrouped:
      return "random-grouped";
    case OutlierMode::kLocalGrouped:
      return "local-grouped";
    case OutlierMode::kInterSession:
      return "inter-session";
    case OutlierMode::kAliased:
      return "aliased";
    case OutlierMode::kAliasedGrouped:
      return "aliased-grouped";
  }
  return "unknown";
}

bool IsGrouped(OutlierMode mode) {
  return mode == OutlierMode::kRandomGrouped || mode == OutlierMode::kLocalGrouped ||
         mode == OutlierMode::kInterSession || mode == OutlierMode::kAliasedGrouped;
}

template <class Pose>
Status MakeOutliers(const PoseGraph<Pose>& graph,
                    const OutlierOptions& options,
                    std::vector<OutlierLink<Pose>>* outliers) {
  const bool grouped = IsGrouped(options.mode);
  const bool local =
      options.mode == OutlierMode::kLocal || options.mode == OutlierMode::kLocalGrouped;
  const bool aliased =
      options.mode == OutlierMode::kAliased || options.mode == OutlierMode::kAliasedGrouped;
  const int group = grouped ? std::max(1, options.group_size) : 1;
  if (options.count < 0) return Status::Error("outlier count must be >= 0");
  if (!(options.aliased_translation_m >= 0.0) || !std::isfinite(options.aliased_translation_m)) {
    return Status::Error("aliased translation must be finite and >= 0, got " +
                         std::to_string(options.aliased_translation_m));
  }
  if (!(options.aliased_rotation_rad >= 0.0 && options.aliased_rotation_rad <= M_PI)) {
    return Status::Error("aliased rotation must be in [0, pi], got " +
                         std::to_string(options.aliased_rotation_rad));
  }
  if (options.mode == OutlierMode::kInterSession && graph.num_sessions() < 2) {
    return Status::Error("inter-session outliers need at least two sessions");
  }
  std::vector<int> sessions;  // sessions long enough to hold a group
  for (int s = 0; s < graph.num_sessions(); ++s) {
    if (static_cast<int>(graph.session(s).vertices.size()) >= group + 2) sessions.push_back(s);
  }
  if (sessions.empty() || (options.mode == OutlierMode::kInterSession && sessions.size() < 2)) {
    return Status::Error("the graph's sessions are too short for these outliers");
  }

  typename Pose::Matrix information = Pose::Matrix::Identity();
  bool found_loop = false;
  for (const Edge<Pose>& e : graph.edges()) {
    if (e.kind == EdgeKind::kLoop) {
      information = e.information;
      found_loop = true;
      break;
    }
  }
  if (!found_loop) {
    for (const Edge<Pose>& e : graph.edges()) {
      if (e.kind == EdgeKind::kOdometry) {
        information = e.information;
        break;
      }
    }
  }

  const std::vector<Pose> dead_reckoning = graph.OdometryEstimate();
  std::mt19937 rng(options.seed);
  auto uniform_int = [&rng](int lo, int hi) {  // inclusive
    return std::uniform_int_distribution<int>(lo, hi)(rng);
  };
  auto random_place = [&](int session) {
    const int length = static_cast<int>(graph.session(session).vertices.size());
    return Place{session, uniform_int(0, length - group)};
  };
  auto vertex_of = [&graph](const Place& p, int offset) {
    return graph.session(p.session).vertices[p.position + offset];
  };

  std::vector<OutlierLink<Pose>> out;
  constexpr int kMaxAttempts = 1000000;
  int attempts = 0;
  while (static_cast<int>(out.size()) < options.count) {
    if (++attempts > kMaxAttempts) {
      return Status::Error("could not place the outliers (graph too small for the options)");
    }
    const int session_a = sessions[uniform_int(0, static_cast<int>(sessions.size()) - 1)];
    int session_b = session_a;
    if (options.mode == OutlierMode::kInterSession) {
      session_b = sessions[uniform_int(0, static_cast<int>(sessions.size()) - 1)];
      if (session_b == session_a) continue;
    } else if (!local) {
      session_b = sessions[uniform_int(0, static_cast<int>(sessions.size()) - 1)];
    }
    const Place a = random_place(session_a);
    Place b = random_place(session_b);
    if (local) {
      // b lies before a, between 2 and local_window poses back.
      const int back = uniform_int(2, std::max(2, options.local_window));
      b.position = a.position - back;
      if (b.position < 0) continue;
    }
    if (session_a == session_b && std::abs(a.position - b.position) < 2 + group) continue;

    // The group's claim: the wrong transform between its two places. The other modes' draws stay
    // as they were, so that their seeds give the same links.
    const Pose claimed =
        aliased ? AliasedMeasurement<Pose>(
                      options.aliased_translation_m, options.aliased_rotation_rad, &rng)
                : RandomMeasurement<Pose>(options.translation_range_m, &rng);
    const int from0 = vertex_of(a, 0);
    const int to0 = vertex_of(b, 0);
    for (int m = 0; m < group; ++m) {
      const int from = vertex_of(a, m);
      const int to = vertex_of(b, m);
      OutlierLink<Pose> link;
      link.from = from;
      link.to = to;
      // Consistent with odometry: x_from^-1 x_to = (D_from0^-1 D_from)^-1 * claimed *
      // (D_to0^-1 D_to).
      link.measurement = grouped
                             ? (dead_reckoning[from0].Inverse() * dead_reckoning[from]).Inverse() *
                                   claimed * (dead_reckoning[to0].Inverse() * dead_reckoning[to])
                             : claimed;
      link.information = information;
      out.push_back(link);
    }
  }
  outliers->swap(out);
  return Status::Ok();
}

template <class Pose>
Status SplitIntoSessions(const std::vector<int64_t>& session_starts, GraphFile<Pose>* file) {
  GraphFile<Pose> split = *file;
  const std::set<int64_t> starts(session_starts.begin(), session_starts.end());
  for (int64_t start : starts) {
    const auto odometry =
        std::find_if(split.edges.begin(), split.edges.end(), [start](const FileEdge<Pose>& e) {
          return e.from == start - 1 && e.to == start;
        });
    if (odometry == split.edges.end()) {
      return Status::Error("vertex " + std::to_string(start) +
                           " has no odometry edge from its predecessor");
    }
    split.edges.erase(odometry);
  }
  // Re-base: every vertex from a start up to the next start (or a gap in the ids) is expressed in
  // the frame of that start.
  std::vector<FileVertex<Pose>*> by_id;
  for (FileVertex<Pose>& v : split.vertices) by_id.push_back(&v);
  std::sort(by_id.begin(), by_id.end(), [](const FileVertex<Pose>* a, const FileVertex<Pose>* b) {
    return a->id < b->id;
  });
  Pose session_T_world;
  bool rebasing = false;
  int64_t previous = 0;
  for (size_t k = 0; k < by_id.size(); ++k) {
    FileVertex<Pose>& v = *by_id[k];
    if (k > 0 && v.id != previous + 1) rebasing = false;
    if (starts.count(v.id) != 0) {
      session_T_world = v.estimate.Inverse();
      rebasing = true;
    }
    if (rebasing) v.estimate = session_T_world * v.estimate;
    previous = v.id;
  }
  *file = std::move(split);
  return Status::Ok();
}

template <class Pose>
Status PerturbOdometry(double k, uint32_t seed, GraphFile<Pose>* file) {
  if (!(k > 0.0) || !std::isfinite(k)) {
    return Status::Error("odometry noise factor must be finite and > 0, got " + std::to_string(k));
  }
  PoseGraph<Pose> graph;
  std::vector<int> file_edge_of_odometry;
  if (Status s = ReadOdometry(*file, &graph, &file_edge_of_odometry); !s.ok()) return s;
  GraphFile<Pose> noisy = *file;
  std::vector<int> odometry_edges;
  for (int index : file_edge_of_odometry) {
    if (index >= 0) odometry_edges.push_back(index);
  }
  // File order, so that the draws do not depend on how the graph numbers its edges.
  std::sort(odometry_edges.begin(), odometry_edges.end());
  std::mt19937 rng(seed ^ kOdometryNoiseSalt);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (int index : odometry_edges) {
    FileEdge<Pose>& edge = noisy.edges[index];
    // e = k L n with L L' = Sigma and n standard normal: cov(e) = k^2 Sigma.
    const typename Pose::Matrix covariance = edge.information.inverse();
    const typename Pose::Matrix L = covariance.llt().matrixL();
    Pose error;
    typename Pose::Tangent n;
    do {
      for (int i = 0; i < Pose::kDim; ++i) n(i) = normal(rng);
    } while (!PoseOfErrorVector(typename Pose::Tangent(k * L * n), &error));
    edge.measurement = edge.measurement * error.Inverse();
  }
  ChainEstimates(graph, file_edge_of_odometry, &noisy);
  *file = std::move(noisy);
  return Status::Ok();
}

template <class Pose>
Status InjectOdometryFaults(int count,
                            uint32_t seed,
                            GraphFile<Pose>* file,
                            std::vector<int>* fault_file_edges) {
  if (count < 0) return Status::Error("odometry fault count must be >= 0");
  PoseGraph<Pose> graph;
  std::vector<int> file_edge_of_odometry;
  if (Status s = ReadOdometry(*file, &graph, &file_edge_of_odometry); !s.ok()) return s;
  // Each session's odometry edges (file indices), in file order.
  std::vector<std::vector<int>> candidates(graph.num_sessions());
  int num_odometry = 0;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (file_edge_of_odometry[e] < 0) continue;
    candidates[graph.vertex(graph.edge(e).to).session].push_back(file_edge_of_odometry[e]);
    ++num_odometry;
  }
  if (count > num_odometry) {
    return Status::Error("asked for " + std::to_string(count) + " odometry faults, the graph has " +
                         std::to_string(num_odometry) + " odometry edges");
  }
  for (std::vector<int>& c : candidates) std::sort(c.begin(), c.end());
  candidates.erase(std::remove_if(candidates.begin(),
                                  candidates.end(),
                                  [](const std::vector<int>& c) { return c.empty(); }),
                   candidates.end());

  GraphFile<Pose> faulty = *file;
  std::vector<int> chosen;
  std::mt19937 rng(seed ^ kOdometryFaultSalt);
  // Sessions in turn; an edge drawn is swapped out of its session's candidates, so that no edge
  // is drawn twice, and a session with none left drops out of the turn.
  size_t turn = 0;
  for (int f = 0; f < count; ++f) {
    turn %= candidates.size();
    std::vector<int>& c = candidates[turn];
    const int pick = std::uniform_int_distribution<int>(0, static_cast<int>(c.size()) - 1)(rng);
    const int index = c[pick];
    c[pick] = c.back();
    c.pop_back();
    FileEdge<Pose>& edge = faulty.edges[index];
    edge.measurement = edge.measurement * FaultMotion<Pose>(&rng);
    chosen.push_back(index);
    if (c.empty()) {
      candidates.erase(candidates.begin() + turn);
    } else {
      ++turn;
    }
  }
  std::sort(chosen.begin(), chosen.end());
  ChainEstimates(graph, file_edge_of_odometry, &faulty);
  *file = std::move(faulty);
  fault_file_edges->swap(chosen);
  return Status::Ok();
}

template Status MakeOutliers<Pose2>(const PoseGraph<Pose2>&,
                                    const OutlierOptions&,
                                    std::vector<OutlierLink<Pose2>>*);
template Status MakeOutliers<Pose3>(const PoseGraph<Pose3>&,
                                    const OutlierOptions&,
                                    std::vector<OutlierLink<Pose3>>*);
template Status SplitIntoSessions<Pose2>(const std::vector<int64_t>&, GraphFile<Pose2>*);
template Status SplitIntoSessions<Pose3>(const std::vector<int64_t>&, GraphFile<Pose3>*);
template Status PerturbOdometry<Pose2>(double, uint32_t, GraphFile<Pose2>*);
template Status PerturbOdometry<Pose3>(double, uint32_t, GraphFile<Pose3>*);
template Status InjectOdometryFaults<Pose2>(int, uint32_t, GraphFile<Pose2>*, std::vector<int>*);
template Status InjectOdometryFaults<Pose3>(int, uint32_t, GraphFile<Pose3>*, std::vector<int>*);

}  // namespace irrr
