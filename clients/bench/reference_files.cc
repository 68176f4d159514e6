#include "clients/bench/reference_files.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <set>
#include <sstream>
#include <utility>

#include <fmt/core.h>
#include <Eigen/Geometry>

#include "clients/common/graph_files.h"

namespace irrr {

// Parses iSAM text edges ("EDGE2 i j x y yaw" + 6 sqrt-information entries, "EDGE3 i j x y z roll
// pitch yaw" + 21, rotation Rz(yaw) Ry(pitch) Rx(roll)); only the measurements of sequential edges
// (j = i + 1, the first one of each i) are used. The chain from the identity gives the pose of
// every vertex id 0..n-1; `graph` vertices look theirs up by id.
template <class Pose>
Status ChainIsamEdges(const std::string& path,
                      const PoseGraph<Pose>& graph,
                      std::vector<Pose>* poses) {
  std::ifstream in(path);
  if (!in) return Status::Error(path + ": cannot open");
  const std::string tag = Pose::kDim == 3 ? "EDGE2" : "EDGE3";
  const size_t fields = Pose::kDim == 3 ? 3 : 6;
  std::vector<Pose> step;
  std::vector<char> have;
  std::string line;
  int line_number = 0;
  while (std::getline(in, line)) {
    ++line_number;
    std::istringstream tokens(line);
    std::string first;
    if (!(tokens >> first) || first[0] == '#') continue;
    if (first != tag && !(Pose::kDim == 3 && first == "ODOMETRY")) {
      return Status::Error(fmt::format("{}: line {}: expected {}", path, line_number, tag));
    }
    int64_t i = 0;
    int64_t j = 0;
    std::vector<double> v(fields);
    if (!(tokens >> i >> j)) {
      return Status::Error(fmt::format("{}: line {}: expected vertex ids", path, line_number));
    }
    for (double& x : v) {
      if (!(tokens >> x) || !std::isfinite(x)) {
        return Status::Error(fmt::format("{}: line {}: bad measurement", path, line_number));
      }
    }
    if (j != i + 1 || i < 0) continue;
    if (static_cast<int64_t>(step.size()) <= i) {
      step.resize(i + 1);
      have.resize(i + 1, 0);
    }
    if (have[i]) continue;
    have[i] = 1;
    if constexpr (Pose::kDim == 3) {
      step[i] = Pose2(v[0], v[1], v[2]);
    } else {
      const Eigen::Quaterniond q = Eigen::AngleAxisd(v[5], Eigen::Vector3d::UnitZ()) *
                                   Eigen::AngleAxisd(v[4], Eigen::Vector3d::UnitY()) *
                                   Eigen::AngleAxisd(v[3], Eigen::Vector3d::UnitX());
      step[i] = Pose3(q.normalized(), Eigen::Vector3d(v[0], v[1], v[2]));
    }
  }
  std::vector<Pose> chain(1);
  for (size_t i = 0; i < step.size() && have[i]; ++i) chain.push_back(chain.back() * step[i]);
  std::vector<Pose> out(graph.num_vertices());
  for (int k = 0; k < graph.num_vertices(); ++k) {
    const int64_t id = graph.vertex(k).id;
    if (id < 0 || id >= static_cast<int64_t>(chain.size())) {
      return Status::Error(
          fmt::format("{}: the sequential edges do not reach vertex {}", path, id));
    }
    out[k] = chain[id];
  }
  poses->swap(out);
  return Status::Ok();
}

// Reads numbers per line (commas count as spaces); lines with fewer than `min_fields` numbers
// are an error, blank lines are skipped.
Status ReadNumberRows(const std::string& path,
                      size_t min_fields,
                      std::vector<std::vector<double>>* rows) {
  std::ifstream in(path);
  if (!in) return Status::Error(path + ": cannot open");
  std::string line;
  int line_number = 0;
  std::vector<std::vector<double>> out;
  while (std::getline(in, line)) {
    ++line_number;
    std::replace(line.begin(), line.end(), ',', ' ');
    std::istringstream tokens(line);
    std::vector<double> row;
    double x = 0.0;
    while (tokens >> x) row.push_back(x);
    if (row.empty()) continue;
    if (row.size() < min_fields || !tokens.eof()) {
      return Status::Error(fmt::format(
          "{}: line {}: expected {} numbers", path, line_number, static_cast<int>(min_fields)));
    }
    out.push_back(std::move(row));
  }
  rows->swap(out);
  return Status::Ok();
}

// Bicocca: vertex k (by id) has time timestamps[k]; its reference is the GPS row nearest in time,
// if within kGpsMatchSeconds.
Status TimeAssociatedGps(const std::string& timestamps_path,
                         const std::string& gps_path,
                         const PoseGraph<Pose2>& graph,
                         Reference<Pose2>* reference) {
  std::vector<std::vector<double>> times;
  std::vector<std::vector<double>> gps;
  if (Status s = ReadNumberRows(timestamps_path, 1, &times); !s.ok()) return s;
  if (Status s = ReadNumberRows(gps_path, 4, &gps); !s.ok()) return s;
  std::sort(gps.begin(), gps.end());
  reference->poses.assign(graph.num_vertices(), Pose2());
  reference->valid.assign(graph.num_vertices(), 0);
  int matched = 0;
  for (int k = 0; k < graph.num_vertices(); ++k) {
    const int64_t id = graph.vertex(k).id;
    if (id < 0 || id >= static_cast<int64_t>(times.size())) {
      return Status::Error(fmt::format("{}: no time for vertex {}", timestamps_path, id));
    }
    const double t = times[id][0];
    auto after = std::lower_bound(
        gps.begin(), gps.end(), t, [](const auto& row, double time) { return row[0] < time; });
    const std::vector<double>* best = nullptr;
    if (after != gps.end()) best = &*after;
    if (after != gps.begin() && (best == nullptr || t - (*(after - 1))[0] < (*best)[0] - t)) {
      best = &*(after - 1);
    }
    if (best == nullptr || std::abs((*best)[0] - t) > kGpsMatchSeconds) continue;
    reference->poses[k] = Pose2((*best)[1], (*best)[2], (*best)[3]);
    reference->valid[k] = 1;
    ++matched;
  }
  reference->label = fmt::format("GPS {}/{}", matched, graph.num_vertices());
  return Status::Ok();
}

Status StridedGps(const std::string& gps_path,
                  int stride,
                  const PoseGraph<Pose2>& graph,
                  Reference<Pose2>* reference) {
  GraphFile<Pose2> file;
  PoseGraph<Pose2> gps;
  std::vector<int> unused;
  if (Status s = LoadPoseGraph(gps_path, FileFormat::kG2o, ReadOptions(), &file, &gps, &unused);
      !s.ok()) {
    return s;
  }
  reference->poses.assign(graph.num_vertices(), Pose2());
  reference->valid.assign(graph.num_vertices(), 0);
  int matched = 0;
  for (int k = 0; k < gps.num_vertices(); ++k) {
    const int v = graph.FindVertex(gps.vertex(k).id * stride);
    if (v < 0) continue;
    reference->poses[v] = gps.initial_estimate()[k];
    reference->valid[v] = 1;
    ++matched;
  }
  if (matched == 0) return Status::Error(gps_path + ": no fix matches a graph vertex");
  reference->label = fmt::format("GPS {}/{}", matched, graph.num_vertices());
  return Status::Ok();
}

// True loops of a labelled graph: unordered vertex-id pairs. Reports labels matching no loop.
Status ReadLabels(const std::string& path,
                  const PoseGraph<Pose2>& graph,
                  std::vector<char>* is_true,
                  int* unmatched_labels) {
  std::vector<std::vector<double>> rows;
  if (Status s = ReadNumberRows(path, 2, &rows); !s.ok()) return s;
  std::set<std::pair<int64_t, int64_t>> pairs;
  for (const auto& row : rows) {
    const auto a = static_cast<int64_t>(row[0]);
    const auto b = static_cast<int64_t>(row[1]);
    pairs.insert({std::min(a, b), std::max(a, b)});
  }
  std::set<std::pair<int64_t, int64_t>> seen;
  is_true->assign(graph.num_edges(), 0);
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose2>& edge = graph.edge(e);
    if (edge.kind != EdgeKind::kLoop) continue;
    const int64_t a = graph.vertex(edge.from).id;
    const int64_t b = graph.vertex(edge.to).id;
    const std::pair<int64_t, int64_t> key{std::min(a, b), std::max(a, b)};
    if (pairs.count(key) != 0) {
      (*is_true)[e] = 1;
      seen.insert(key);
    }
  }
  *unmatched_labels = static_cast<int>(pairs.size() - seen.size());
  return Status::Ok();
}

template Status ChainIsamEdges<Pose2>(const std::string&,
                                      const PoseGraph<Pose2>&,
                                      std::vector<Pose2>*);
template Status ChainIsamEdges<Pose3>(const std::string&,
                                      const PoseGraph<Pose3>&,
                                      std::vector<Pose3>*);

}  // namespace irrr
