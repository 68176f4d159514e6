#include "core/graph_io.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <iomanip>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <unordered_map>

namespace irrr {
namespace {

// Quaternions in files carry about six significant digits; further off than this the numbers are
// not a rotation.
constexpr double kQuaternionNormTolerance = 1e-3;
// Closer to unit norm than this a quaternion is left as written, so that write -> read -> write is
// byte-identical.
constexpr double kAlreadyUnitTolerance = 4e-16;

enum class Tag { kVertex, kEdge, kFix, kUnknown };

// What the tags of one format and dimension are called, and how many numbers follow them.
struct Dialect {
  const char* vertex;
  const char* edge;
  int vertex_numbers;  // after the id
  int edge_numbers;    // after the two ids
};

template <class Pose>
Dialect DialectFor(FileFormat format) {
  if constexpr (Pose::kDim == 3) {
    return format == FileFormat::kToro ? Dialect{"VERTEX2", "EDGE2", 3, 9}
                                       : Dialect{"VERTEX_SE2", "EDGE_SE2", 3, 9};
  } else {
    return Dialect{"VERTEX_SE3:QUAT", "EDGE_SE3:QUAT", 7, 28};
  }
}

std::string LinePrefix(int line) { return "line " + std::to_string(line) + ": "; }

std::vector<std::string> Tokens(const std::string& line) {
  std::istringstream stream(line);
  std::vector<std::string> tokens;
  std::string token;
  while (stream >> token) tokens.push_back(token);
  return tokens;
}

bool IsSkipped(const std::vector<std::string>& tokens) {
  return tokens.empty() || tokens[0][0] == '#';
}

bool ParseId(const std::string& token, int64_t* value) {
  errno = 0;
  char* end = nullptr;
  const long long parsed = std::strtoll(token.c_str(), &end, 10);
  if (errno != 0 || end == token.c_str() || *end != '\0') return false;
  *value = parsed;
  return true;
}

bool ParseNumber(const std::string& token, double* value) {
  char* end = nullptr;
  *value = std::strtod(token.c_str(), &end);
  return end != token.c_str() && *end == '\0';
}

// The pose stored as numbers after an id: x y yaw, or x y z qx qy qz qw.
template <class Pose>
Status PoseFromNumbers(const double* v, Pose* pose) {
  for (int k = 0; k < (Pose::kDim == 3 ? 3 : 7); ++k) {
    if (!std::isfinite(v[k])) return Status::Error("non-finite number in the pose");
  }
  if constexpr (Pose::kDim == 3) {
    *pose = Pose2(v[0], v[1], v[2]);
  } else {
    Eigen::Quaterniond q(v[6], v[3], v[4], v[5]);
    const double norm = q.norm();
    if (std::abs(norm - 1.0) > kQuaternionNormTolerance) {
      std::ostringstream s;
      s << "quaternion norm " << norm << " is not 1";
      return Status::Error(s.str());
    }
    if (std::abs(norm - 1.0) > kAlreadyUnitTolerance) q.normalize();
    *pose = Pose3(q, Eigen::Vector3d(v[0], v[1], v[2]));
  }
  return Status::Ok();
}

// Information from the numbers after the measurement: g2o's upper triangle row by row, or TORO's
// xx xy yy tt xt yt.
template <class Pose>
typename Pose::Matrix InformationFromNumbers(const double* v, FileFormat format) {
  typename Pose::Matrix m;
  constexpr int d = Pose::kDim;
  if (format == FileFormat::kToro) {
    m << v[0], v[1], v[4], v[1], v[2], v[5], v[4], v[5], v[3];
    return m;
  }
  int k = 0;
  for (int r = 0; r < d; ++r) {
    for (int c = r; c < d; ++c) m(r, c) = m(c, r) = v[k++];
  }
  return m;
}

// The tag's dimension if it is a known pose-graph tag of any format: used to say "3D tag in a
// 2D read" rather than "unknown tag".
int KnownTagDimension(const std::string& tag) {
  if (tag == "VERTEX_SE2" || tag == "EDGE_SE2" || tag == "VERTEX2" || tag == "EDGE2") return 2;
  if (tag == "VERTEX_SE3:QUAT" || tag == "EDGE_SE3:QUAT") return 3;
  return 0;
}

}  // namespace

Status DetectGraphFile(std::istream& in, FileFormat* format, int* dimension) {
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    const std::vector<std::string> tokens = Tokens(line);
    if (IsSkipped(tokens) || tokens[0] == "FIX") continue;
    const std::string& tag = tokens[0];
    if (tag == "VERTEX_SE2" || tag == "EDGE_SE2") {
      *format = FileFormat::kG2o;
      *dimension = 2;
    } else if (tag == "VERTEX_SE3:QUAT" || tag == "EDGE_SE3:QUAT") {
      *format = FileFormat::kG2o;
      *dimension = 3;
    } else if (tag == "VERTEX2" || tag == "EDGE2") {
      *format = FileFormat::kToro;
      *dimension = 2;
    } else {
      return Status::Error(LinePrefix(line_number) + "unknown tag '" + tag +
                           "' (expected a g2o or TORO vertex or edge)");
    }
    return Status::Ok();
  }
  return Status::Error("no vertex or edge line found (empty file?)");
}

template <class Pose>
Status ReadGraphFile(std::istream& in,
                     FileFormat format,
                     const ReadOptions& options,
                     GraphFile<Pose>* out) {
  if (format == FileFormat::kToro && Pose::kDim != 3) {
    return Status::Error("the TORO format holds 2D graphs only");
  }
  const Dialect dialect = DialectFor<Pose>(format);
  GraphFile<Pose> file;
  std::unordered_map<int64_t, int> vertex_line;
  std::string line;
  int line_number = 0;
  std::vector<double> numbers;
  while (std::getline(in, line)) {
    ++line_number;
    const std::string where = LinePrefix(line_number);
    const std::vector<std::string> tokens = Tokens(line);
    if (IsSkipped(tokens)) continue;
    const std::string& tag = tokens[0];
    Tag kind = Tag::kUnknown;
    if (tag == dialect.vertex) kind = Tag::kVertex;
    if (tag == dialect.edge) kind = Tag::kEdge;
    if (tag == "FIX" && format == FileFormat::kG2o) kind = Tag::kFix;
    if (kind == Tag::kUnknown) {
      const int dimension = KnownTagDimension(tag);
      if (dimension != 0) {
        return Status::Error(where + "tag " + tag + " does not belong in a " +
                             (format == FileFormat::kToro ? "TORO" : "g2o") + " " +
                             std::to_string(Pose::kTranslationDim) + "D file");
      }
      if (options.skip_unknown_tags) continue;
      return Status::Error(where + "unknown tag '" + tag + "'");
    }

    const int ids = kind == Tag::kEdge ? 2 : 1;
    const int expected = kind == Tag::kVertex ? dialect.vertex_numbers
                         : kind == Tag::kEdge ? dialect.edge_numbers
                                              : 0;
    const int found = static_cast<int>(tokens.size()) - 1 - ids;
    if (found != expected) {
      return Status::Error(where + tag + " expects " + std::to_string(ids) +
                           (ids == 1 ? " id and " : " ids and ") + std::to_string(expected) +
                           " numbers, found " + std::to_string(std::max(0, found + ids)) +
                           " fields");
    }
    int64_t id[2] = {0, 0};
    for (int k = 0; k < ids; ++k) {
      if (!ParseId(tokens[1 + k], &id[k])) {
        return Status::Error(where + tag + ": '" + tokens[1 + k] + "' is not an integer id");
      }
    }
    numbers.assign(expected, 0.0);
    for (int k = 0; k < expected; ++k) {
      if (!ParseNumber(tokens[1 + ids + k], &numbers[k])) {
        return Status::Error(where + tag + ": '" + tokens[1 + ids + k] + "' is not a number");
      }
    }

    if (kind == Tag::kFix) continue;
    if (kind == Tag::kVertex) {
      const auto [it, inserted] = vertex_line.emplace(id[0], line_number);
      if (!inserted) {
        return Status::Error(where + "duplicate vertex id " + std::to_string(id[0]) +
                             " (first on line " + std::to_string(it->second) + ")");
      }
      FileVertex<Pose> vertex;
      vertex.id = id[0];
      vertex.line = line_number;
      if (Status s = PoseFromNumbers(numbers.data(), &vertex.estimate); !s.ok()) {
        return Status::Error(where + "vertex " + std::to_string(id[0]) + ": " + s.message());
      }
      file.vertices.push_back(vertex);
      continue;
    }

    const std::string edge_name = tag + " " + std::to_string(id[0]) + " " + std::to_string(id[1]);
    if (id[0] == id[1]) return Status::Error(where + edge_name + ": self-loop");
    FileEdge<Pose> edge;
    edge.from = id[0];
    edge.to = id[1];
    edge.line = line_number;
    if (Status s = PoseFromNumbers(numbers.data(), &edge.measurement); !s.ok()) {
      return Status::Error(where + edge_name + ": measurement: " + s.message());
    }
    edge.information =
        InformationFromNumbers<Pose>(numbers.data() + (Pose::kDim == 3 ? 3 : 7), format);
    if (Status s = ValidateInformation<Pose>(edge.information); !s.ok()) {
      return Status::Error(where + edge_name + ": " + s.message());
    }
    file.edges.push_back(edge);
  }
  if (in.bad()) return Status::Error("read error after line " + std::to_string(line_number));

  if (!file.vertices.empty()) {
    for (const FileEdge<Pose>& edge : file.edges) {
      for (const int64_t end : {edge.from, edge.to}) {
        if (vertex_line.count(end) == 0) {
          return Status::Error(LinePrefix(edge.line) + "edge " + std::to_string(edge.from) +
                               " -> " + std::to_string(edge.to) + ": vertex " +
                               std::to_string(end) + " is not declared");
        }
      }
    }
  }
  *out = std::move(file);
  return Status::Ok();
}

template <class Pose>
Status WriteGraphFile(std::ostream& out, FileFormat format, const GraphFile<Pose>& file) {
  if (format == FileFormat::kToro && Pose::kDim != 3) {
    return Status::Error("the TORO format holds 2D graphs only");
  }
  const Dialect dialect = DialectFor<Pose>(format);
  std::ostringstream text;
  text << std::setprecision(17);
  auto write_pose = [&text](const Pose& pose) {
    if constexpr (Pose::kDim == 3) {
      text << pose.translation().x() << ' ' << pose.translation().y() << ' ' << pose.yaw_rad();
    } else {
      const Eigen::Quaterniond& q = pose.quaternion();
      text << pose.translation().x() << ' ' << pose.translation().y() << ' '
           << pose.translation().z() << ' ' << q.x() << ' ' << q.y() << ' ' << q.z() << ' '
           << q.w();
    }
  };
  for (const FileVertex<Pose>& vertex : file.vertices) {
    text << dialect.vertex << ' ' << vertex.id << ' ';
    write_pose(vertex.estimate);
    text << '\n';
  }
  for (const FileEdge<Pose>& edge : file.edges) {
    text << dialect.edge << ' ' << edge.from << ' ' << edge.to << ' ';
    write_pose(edge.measurement);
    const typename Pose::Matrix& m = edge.information;
    if (format == FileFormat::kToro) {
      text << ' ' << m(0, 0) << ' ' << m(0, 1) << ' ' << m(1, 1) << ' ' << m(2, 2) << ' ' << m(0, 2)
           << ' ' << m(1, 2);
    } else {
      for (int r = 0; r < Pose::kDim; ++r) {
        for (int c = r; c < Pose::kDim; ++c) text << ' ' << m(r, c);
      }
    }
    text << '\n';
  }
  out << text.str();
  if (!out) return Status::Error("write failed");
  return Status::Ok();
}

template <class Pose>
Status BuildPoseGraph(const GraphFile<Pose>& file,
                      PoseGraph<Pose>* graph,
                      std::vector<int>* graph_edge_of_file_edge) {
  // Vertex ids in increasing order, with the file's estimate where there is one.
  std::map<int64_t, const FileVertex<Pose>*> vertices;
  for (const FileVertex<Pose>& v : file.vertices) vertices.emplace(v.id, &v);
  if (file.vertices.empty()) {
    for (const FileEdge<Pose>& e : file.edges) {
      vertices.emplace(e.from, nullptr);
      vertices.emplace(e.to, nullptr);
    }
  }
  // The odometry of vertex i is the first edge (i-1, i) in file order.
  std::unordered_map<int64_t, int> odometry_of;
  for (int k = 0; k < static_cast<int>(file.edges.size()); ++k) {
    const FileEdge<Pose>& e = file.edges[k];
    if (e.from != std::numeric_limits<int64_t>::max() && e.to == e.from + 1) {
      odometry_of.emplace(e.to, k);
    }
  }

  PoseGraph<Pose> built;
  std::vector<int> edge_map(file.edges.size(), -1);
  int session = -1;
  int ordinal = 0;
  Pose dead_reckoning;
  int64_t previous_id = 0;
  for (const auto& [id, record] : vertices) {
    const auto odometry = odometry_of.find(id);
    const bool continues = ordinal > 0 && previous_id == id - 1 && odometry != odometry_of.end();
    const std::string where = record != nullptr
                                  ? LinePrefix(record->line)
                                  : std::string("vertex ") + std::to_string(id) + ": ";
    Status status = Status::Ok();
    if (!continues) {
      status = built.AddSession(built.num_sessions(), &session);
      dead_reckoning = Pose();
      if (status.ok()) {
        status = built.AddPose(session,
                               id,
                               ordinal,
                               record ? record->estimate : dead_reckoning,
                               nullptr,
                               nullptr,
                               nullptr);
      }
    } else {
      const FileEdge<Pose>& edge = file.edges[odometry->second];
      dead_reckoning = dead_reckoning * edge.measurement;
      edge_map[odometry->second] = built.num_edges();
      status = built.AddPose(session,
                             id,
                             ordinal,
                             record ? record->estimate : dead_reckoning,
                             &edge.measurement,
                             &edge.information,
                             nullptr);
      if (!status.ok()) {
        return Status::Error(LinePrefix(edge.line) + status.message());
      }
    }
    if (!status.ok()) return Status::Error(where + status.message());
    previous_id = id;
    ++ordinal;
  }
  for (int k = 0; k < static_cast<int>(file.edges.size()); ++k) {
    if (edge_map[k] >= 0) continue;
    const FileEdge<Pose>& e = file.edges[k];
    const int from = built.FindVertex(e.from);
    const int to = built.FindVertex(e.to);
    if (from < 0 || to < 0) {
      return Status::Error(LinePrefix(e.line) + "edge " + std::to_string(e.from) + " -> " +
                           std::to_string(e.to) + ": vertex " +
                           std::to_string(from < 0 ? e.from : e.to) + " is not declared");
    }
    if (Status s = built.AddLoop(from, to, e.measurement, e.information, &edge_map[k]); !s.ok()) {
      return Status::Error(LinePrefix(e.line) + s.message());
    }
  }
  *graph = std::move(built);
  *graph_edge_of_file_edge = std::move(edge_map);
  return Status::Ok();
}

template <class Pose>
GraphFile<Pose> WithEstimate(const GraphFile<Pose>& file,
                             const PoseGraph<Pose>& graph,
                             const std::vector<Pose>& estimate) {
  GraphFile<Pose> out = file;
  if (out.vertices.empty()) {
    std::vector<int> order(graph.num_vertices());
    for (int v = 0; v < graph.num_vertices(); ++v) order[v] = v;
    std::sort(order.begin(), order.end(), [&graph](int a, int b) {
      return graph.vertex(a).id < graph.vertex(b).id;
    });
    for (int v : order) out.vertices.push_back(FileVertex<Pose>{graph.vertex(v).id, Pose(), 0});
  }
  for (FileVertex<Pose>& vertex : out.vertices) {
    const int index = graph.FindVertex(vertex.id);
    IRRR_CHECK(index >= 0 && index < static_cast<int>(estimate.size()));
    vertex.estimate = estimate[index];
  }
  return out;
}

template Status ReadGraphFile<Pose2>(std::istream&,
                                     FileFormat,
                                     const ReadOptions&,
                                     GraphFile<Pose2>*);
template Status ReadGraphFile<Pose3>(std::istream&,
                                     FileFormat,
                                     const ReadOptions&,
                                     GraphFile<Pose3>*);
template Status WriteGraphFile<Pose2>(std::ostream&, FileFormat, const GraphFile<Pose2>&);
template Status WriteGraphFile<Pose3>(std::ostream&, FileFormat, const GraphFile<Pose3>&);
template Status BuildPoseGraph<Pose2>(const GraphFile<Pose2>&,
                                      PoseGraph<Pose2>*,
                                      std::vector<int>*);
template Status BuildPoseGraph<Pose3>(const GraphFile<Pose3>&,
                                      PoseGraph<Pose3>*,
                                      std::vector<int>*);
template GraphFile<Pose2> WithEstimate<Pose2>(const GraphFile<Pose2>&,
                                              const PoseGraph<Pose2>&,
                                              const std::vector<Pose2>&);
template GraphFile<Pose3> WithEstimate<Pose3>(const GraphFile<Pose3>&,
                                              const PoseGraph<Pose3>&,
                                              const std::vector<Pose3>&);

}  // namespace irrr
