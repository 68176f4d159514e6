#include "core/graph_io.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <iomanip>
#include <locale>
#include <map>
#include <sstream>
#include <string>
#include <string_view>
#include <system_error>
#include <type_traits>
#include <unordered_map>
#include <utility>

namespace irrr {
namespace {

// Files print quaternions with about six significant digits; further from unit norm than this
// the numbers are not a rotation.
constexpr double kQuaternionNormTolerance = 1e-3;
// A quaternion this close to unit norm is kept exactly as written, so that write -> read -> write
// is byte-identical (normalizing a unit quaternion again can change its last bit).
constexpr double kAlreadyUnitTolerance = 4e-16;

// Every pose-graph tag this reader knows, so that a tag of the other format or dimension is
// reported as such rather than as unknown.
struct KnownTag {
  const char* tag;
  FileFormat format;
  int dimension;
  bool is_edge;
};
constexpr KnownTag kKnownTags[] = {
    {"VERTEX_SE2", FileFormat::kG2o, 2, false},
    {"EDGE_SE2", FileFormat::kG2o, 2, true},
    {"VERTEX_SE3:QUAT", FileFormat::kG2o, 3, false},
    {"EDGE_SE3:QUAT", FileFormat::kG2o, 3, true},
    {"VERTEX2", FileFormat::kToro, 2, false},
    {"EDGE2", FileFormat::kToro, 2, true},
};

const KnownTag* FindKnownTag(std::string_view tag) {
  for (const KnownTag& known : kKnownTags) {
    if (tag == known.tag) return &known;
  }
  return nullptr;
}

const char* FormatName(FileFormat format) { return format == FileFormat::kToro ? "TORO" : "g2o"; }

// Numbers stored for a pose (x y yaw, or x y z qx qy qz qw) and for an information matrix.
template <class Pose>
constexpr int kPoseNumbers = Pose::kDim == 3 ? 3 : 7;
template <class Pose>
constexpr int kInformationNumbers = (Pose::kDim + 1) * Pose::kDim / 2;

std::string LinePrefix(int line) { return "line " + std::to_string(line) + ": "; }

// Whitespace-separated tokens; '\r' counts as whitespace so that CRLF files read the same.
void Tokenize(const std::string& line, std::vector<std::string_view>* tokens) {
  constexpr const char* kSpace = " \t\r\n\v\f";
  tokens->clear();
  size_t begin = line.find_first_not_of(kSpace);
  while (begin != std::string::npos) {
    const size_t end = std::min(line.find_first_of(kSpace, begin), line.size());
    tokens->emplace_back(line.data() + begin, end - begin);
    begin = line.find_first_not_of(kSpace, end);
  }
}

bool IsDataLine(const std::vector<std::string_view>& tokens) {
  return !tokens.empty() && tokens[0][0] != '#';
}

// from_chars is exact and locale independent but rejects the '+' that strtod accepts.
std::string_view WithoutPlus(std::string_view token) {
  if (token.size() > 1 && token[0] == '+' && token[1] != '-' && token[1] != '+') {
    token.remove_prefix(1);
  }
  return token;
}

// Parses a whole token; the message (without the line) says what is wrong.
template <class T>
Status ParseToken(std::string_view token, const char* what, T* value) {
  const std::string_view digits = WithoutPlus(token);
  const auto [end, error] = std::from_chars(digits.data(), digits.data() + digits.size(), *value);
  if (error == std::errc::result_out_of_range) {
    return Status::Error("'" + std::string(token) + "' is out of range for " + what);
  }
  if (error != std::errc() || end != digits.data() + digits.size()) {
    return Status::Error("'" + std::string(token) + "' is not " + what);
  }
  return Status::Ok();
}

// A pose from its numbers in the file's order (the quaternion as qx qy qz qw).
template <class Pose>
Status PoseFromNumbers(const double* v, Pose* pose) {
  if constexpr (std::is_same_v<Pose, Pose2>) {
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
  return ValidatePose(*pose);
}

// The symmetric information matrix from its stored triangle: g2o's upper triangle row by row, or
// TORO's xx xy yy tt xt yt (index 0 = x, 1 = y, 2 = theta).
template <class Pose>
typename Pose::Matrix InformationFromNumbers(const double* v, FileFormat format) {
  typename Pose::Matrix m;
  if constexpr (std::is_same_v<Pose, Pose2>) {
    if (format == FileFormat::kToro) {
      m << v[0], v[1], v[4],  //
          v[1], v[2], v[5],   //
          v[4], v[5], v[3];
      return m;
    }
  }
  int k = 0;
  for (int r = 0; r < Pose::kDim; ++r) {
    for (int c = r; c < Pose::kDim; ++c) m(r, c) = m(c, r) = v[k++];
  }
  return m;
}

template <class Pose>
void WritePose(std::ostream& out, const Pose& pose) {
  const auto& t = pose.translation();
  if constexpr (std::is_same_v<Pose, Pose2>) {
    out << t.x() << ' ' << t.y() << ' ' << pose.yaw_rad();
  } else {
    const Eigen::Quaterniond& q = pose.quaternion();
    out << t.x() << ' ' << t.y() << ' ' << t.z() << ' ' << q.x() << ' ' << q.y() << ' ' << q.z()
        << ' ' << q.w();
  }
}

template <class Pose>
void WriteInformation(std::ostream& out, FileFormat format, const typename Pose::Matrix& m) {
  if (format == FileFormat::kToro) {
    constexpr int kToroOrder[6][2] = {{0, 0}, {0, 1}, {1, 1}, {2, 2}, {0, 2}, {1, 2}};
    for (const auto& rc : kToroOrder) out << ' ' << m(rc[0], rc[1]);
    return;
  }
  for (int r = 0; r < Pose::kDim; ++r) {
    for (int c = r; c < Pose::kDim; ++c) out << ' ' << m(r, c);
  }
}

template <class Pose>
Status CheckFormatHoldsPose(FileFormat format) {
  if (format == FileFormat::kToro && !std::is_same_v<Pose, Pose2>) {
    return Status::Error(std::string("the TORO format holds 2D graphs only, not ") + Pose::kName);
  }
  return Status::Ok();
}

}  // namespace

Status DetectGraphFile(std::istream& in, FileFormat* format, int* dimension) {
  std::string line;
  std::vector<std::string_view> tokens;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    Tokenize(line, &tokens);
    if (!IsDataLine(tokens) || tokens[0] == "FIX") continue;
    const KnownTag* known = FindKnownTag(tokens[0]);
    if (known == nullptr) {
      return Status::Error(LinePrefix(line_number) + "unknown tag '" + std::string(tokens[0]) +
                           "' (expected a g2o or TORO vertex or edge)");
    }
    *format = known->format;
    *dimension = known->dimension;
    return Status::Ok();
  }
  return Status::Error("empty input: no vertex or edge line in " + std::to_string(line_number) +
                       " lines");
}

template <class Pose>
Status ReadGraphFile(std::istream& in,
                     FileFormat format,
                     const ReadOptions& options,
                     GraphFile<Pose>* out) {
  IRRR_CHECK(out != nullptr);
  if (Status s = CheckFormatHoldsPose<Pose>(format); !s.ok()) return s;
  constexpr int kDimension = Pose::kTranslationDim;
  constexpr int kPose = kPoseNumbers<Pose>;

  GraphFile<Pose> file;
  std::unordered_map<int64_t, int> vertex_line;
  std::string line;
  std::vector<std::string_view> tokens;
  double numbers[kPose + kInformationNumbers<Pose>];
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    Tokenize(line, &tokens);
    if (!IsDataLine(tokens)) continue;
    const std::string where = LinePrefix(line_number);
    const std::string tag(tokens[0]);
    const int found = static_cast<int>(tokens.size()) - 1;

    // g2o's FIX chooses the gauge, which is the optimizer's business; only its ids are checked.
    if (tag == "FIX" && format == FileFormat::kG2o) {
      if (found == 0) return Status::Error(where + "FIX expects at least one vertex id");
      for (int k = 1; k <= found; ++k) {
        int64_t id = 0;
        if (Status s = ParseToken(tokens[k], "a 64-bit integer id", &id); !s.ok()) {
          return Status::Error(where + "FIX: " + s.message());
        }
      }
      continue;
    }
    const KnownTag* known = FindKnownTag(tag);
    if (known == nullptr) {
      if (options.skip_unknown_tags) continue;
      return Status::Error(where + "unknown tag '" + tag + "'");
    }
    if (known->format != format || known->dimension != kDimension) {
      return Status::Error(where + tag + " is a " + FormatName(known->format) + " " +
                           std::to_string(known->dimension) + "D tag, but this is a " +
                           FormatName(format) + " " + std::to_string(kDimension) + "D read");
    }

    const int ids = known->is_edge ? 2 : 1;
    const int expected = ids + kPose + (known->is_edge ? kInformationNumbers<Pose> : 0);
    if (found != expected) {
      return Status::Error(where + tag + " expects " + std::to_string(expected) +
                           " numbers after the tag, found " + std::to_string(found));
    }
    int64_t id[2] = {0, 0};
    for (int k = 0; k < ids; ++k) {
      if (Status s = ParseToken(tokens[1 + k], "a 64-bit integer id", &id[k]); !s.ok()) {
        return Status::Error(where + tag + ": " + s.message());
      }
    }
    const std::string name = tag + " " + std::to_string(id[0]) +
                             (known->is_edge ? " " + std::to_string(id[1]) : std::string());
    // A fault of the line's values: always an error for a vertex; for an edge, unless
    // skip_invalid_edges leaves the line out.
    std::string fault;
    for (int k = 0; k < expected - ids; ++k) {
      if (Status s = ParseToken(tokens[1 + ids + k], "a number", &numbers[k]); !s.ok()) {
        return Status::Error(where + name + ": " + s.message());
      }
      if (!std::isfinite(numbers[k]) && fault.empty()) {
        const char* part = k >= kPose ? "information" : known->is_edge ? "measurement" : "estimate";
        fault = std::string(part) + " has a non-finite number '" +
                std::string(tokens[1 + ids + k]) + "'";
      }
    }

    if (!known->is_edge) {
      if (!fault.empty()) return Status::Error(where + name + ": " + fault);
      const auto [first, inserted] = vertex_line.emplace(id[0], line_number);
      if (!inserted) {
        return Status::Error(where + "duplicate vertex id " + std::to_string(id[0]) +
                             " (first on line " + std::to_string(first->second) + ")");
      }
      FileVertex<Pose> vertex;
      vertex.id = id[0];
      vertex.line = line_number;
      if (Status s = PoseFromNumbers(numbers, &vertex.estimate); !s.ok()) {
        return Status::Error(where + name + ": estimate: " + s.message());
      }
      file.vertices.push_back(vertex);
      continue;
    }
    FileEdge<Pose> edge;
    edge.from = id[0];
    edge.to = id[1];
    edge.line = line_number;
    if (fault.empty() && id[0] == id[1]) fault = "self-loop";
    if (fault.empty()) {
      if (Status s = PoseFromNumbers(numbers, &edge.measurement); !s.ok()) {
        fault = "measurement: " + s.message();
      }
    }
    if (fault.empty()) {
      edge.information = InformationFromNumbers<Pose>(numbers + kPose, format);
      if (Status s = ValidateInformation<Pose>(edge.information); !s.ok()) fault = s.message();
    }
    if (fault.empty()) {
      file.edges.push_back(edge);
      continue;
    }
    const std::string message = where + name + ": " + fault;
    if (!options.skip_invalid_edges) return Status::Error(message);
    file.skipped.push_back(SkippedLine{line_number, message});
  }
  if (in.bad()) return Status::Error("read error after line " + std::to_string(line_number));

  // Vertices may be declared after the edges that use them, so endpoints are checked at the end.
  if (!file.vertices.empty()) {
    std::vector<FileEdge<Pose>> declared;
    declared.reserve(file.edges.size());
    for (const FileEdge<Pose>& edge : file.edges) {
      const bool has_from = vertex_line.count(edge.from) != 0;
      const bool has_to = vertex_line.count(edge.to) != 0;
      if (has_from && has_to) {
        declared.push_back(edge);
        continue;
      }
      const std::string message = LinePrefix(edge.line) + "edge " + std::to_string(edge.from) +
                                  " -> " + std::to_string(edge.to) + ": vertex " +
                                  std::to_string(has_from ? edge.to : edge.from) +
                                  " is not declared";
      if (!options.skip_invalid_edges) return Status::Error(message);
      file.skipped.push_back(SkippedLine{edge.line, message});
    }
    file.edges = std::move(declared);
    std::stable_sort(file.skipped.begin(),
                     file.skipped.end(),
                     [](const SkippedLine& a, const SkippedLine& b) { return a.line < b.line; });
  }
  *out = std::move(file);
  return Status::Ok();
}

template <class Pose>
Status WriteGraphFile(std::ostream& out, FileFormat format, const GraphFile<Pose>& file) {
  if (Status s = CheckFormatHoldsPose<Pose>(format); !s.ok()) return s;
  const char* vertex_tag = nullptr;
  const char* edge_tag = nullptr;
  for (const KnownTag& known : kKnownTags) {
    if (known.format == format && known.dimension == Pose::kTranslationDim) {
      (known.is_edge ? edge_tag : vertex_tag) = known.tag;
    }
  }
  IRRR_CHECK(vertex_tag != nullptr && edge_tag != nullptr);

  // The text goes to a local stream first so that a failing format leaves `out` untouched, and
  // the caller's stream flags (precision, locale) do not matter.
  std::ostringstream text;
  text.imbue(std::locale::classic());
  text << std::setprecision(17);
  for (const FileVertex<Pose>& vertex : file.vertices) {
    text << vertex_tag << ' ' << vertex.id << ' ';
    WritePose(text, vertex.estimate);
    text << '\n';
  }
  for (const FileEdge<Pose>& edge : file.edges) {
    text << edge_tag << ' ' << edge.from << ' ' << edge.to << ' ';
    WritePose(text, edge.measurement);
    WriteInformation<Pose>(text, format, edge.information);
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
  IRRR_CHECK(graph != nullptr && graph_edge_of_file_edge != nullptr);
  IRRR_CHECK(graph->num_vertices() == 0 && graph->num_sessions() == 0);
  const int num_file_edges = static_cast<int>(file.edges.size());

  // Vertex ids in increasing order, with the file's record (null for edges-only files).
  std::map<int64_t, const FileVertex<Pose>*> vertices;
  for (const FileVertex<Pose>& v : file.vertices) {
    const auto [first, inserted] = vertices.emplace(v.id, &v);
    if (!inserted) {
      return Status::Error(LinePrefix(v.line) + "duplicate vertex id " + std::to_string(v.id) +
                           " (first on line " + std::to_string(first->second->line) + ")");
    }
  }
  if (file.vertices.empty()) {
    for (const FileEdge<Pose>& e : file.edges) {
      vertices.emplace(e.from, nullptr);
      vertices.emplace(e.to, nullptr);
    }
  }
  // The odometry of vertex i is the first edge (i-1, i) in file order.
  std::unordered_map<int64_t, int> odometry_of;
  for (int k = 0; k < num_file_edges; ++k) {
    const FileEdge<Pose>& e = file.edges[k];
    if (e.from < e.to && e.to - 1 == e.from) odometry_of.emplace(e.to, k);
  }

  PoseGraph<Pose> built;
  std::vector<int> edge_map(num_file_edges, -1);
  int session = -1;
  int ordinal = 0;
  int64_t previous_id = 0;
  Pose dead_reckoning;
  for (const auto& [id, record] : vertices) {
    // A vertex's own estimate is checked first so that an error is blamed on the right line.
    if (record != nullptr) {
      if (Status s = ValidatePose(record->estimate); !s.ok()) {
        return Status::Error(LinePrefix(record->line) + "vertex " + std::to_string(id) +
                             ": estimate: " + s.message());
      }
    }
    // Ids are sorted, so vertex i-1 exists exactly when it is the previous one.
    const auto found = odometry_of.find(id);
    const bool continues = ordinal > 0 && found != odometry_of.end() && previous_id == id - 1;
    const FileEdge<Pose>* odometry = continues ? &file.edges[found->second] : nullptr;
    if (odometry != nullptr) {
      dead_reckoning = dead_reckoning * odometry->measurement;
      edge_map[found->second] = built.num_edges();  // AddPose appends the odometry edge
    } else {
      dead_reckoning = Pose();
      const Status added = built.AddSession(built.num_sessions(), &session);
      IRRR_CHECK(added.ok());  // session ids 0, 1, ... are unique
    }
    const Status status = built.AddPose(session,
                                        id,
                                        static_cast<double>(ordinal),
                                        record != nullptr ? record->estimate : dead_reckoning,
                                        odometry != nullptr ? &odometry->measurement : nullptr,
                                        odometry != nullptr ? &odometry->information : nullptr,
                                        nullptr);
    if (!status.ok()) {
      const int line = odometry != nullptr ? odometry->line : record != nullptr ? record->line : 0;
      return Status::Error(LinePrefix(line) + status.message());
    }
    previous_id = id;
    ++ordinal;
  }

  for (int k = 0; k < num_file_edges; ++k) {
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
  IRRR_CHECK(static_cast<int>(estimate.size()) == graph.num_vertices());
  GraphFile<Pose> out = file;
  if (out.vertices.empty()) {
    std::vector<int64_t> ids;
    ids.reserve(graph.num_vertices());
    for (int v = 0; v < graph.num_vertices(); ++v) ids.push_back(graph.vertex(v).id);
    std::sort(ids.begin(), ids.end());
    for (const int64_t id : ids) {
      FileVertex<Pose> vertex;
      vertex.id = id;
      out.vertices.push_back(vertex);
    }
  }
  for (FileVertex<Pose>& vertex : out.vertices) {
    const int index = graph.FindVertex(vertex.id);
    IRRR_CHECK(index >= 0);  // the graph was built from these records
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
