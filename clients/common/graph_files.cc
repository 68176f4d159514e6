#include "clients/common/graph_files.h"

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <sstream>

namespace irrr {

Status InspectGraphFile(const std::string& path, FileFormat* format, int* dimension) {
  std::ifstream in(path);
  if (!in) return Status::Error(path + ": cannot open");
  if (Status s = DetectGraphFile(in, format, dimension); !s.ok()) {
    return Status::Error(path + ": " + s.message());
  }
  return Status::Ok();
}

template <class Pose>
Status LoadPoseGraph(const std::string& path,
                     FileFormat format,
                     const ReadOptions& options,
                     GraphFile<Pose>* file,
                     PoseGraph<Pose>* graph,
                     std::vector<int>* graph_edge_of_file_edge) {
  std::ifstream in(path);
  if (!in) return Status::Error(path + ": cannot open");
  if (Status s = ReadGraphFile(in, format, options, file); !s.ok()) {
    return Status::Error(path + ": " + s.message());
  }
  if (Status s = BuildPoseGraph(*file, graph, graph_edge_of_file_edge); !s.ok()) {
    return Status::Error(path + ": " + s.message());
  }
  return Status::Ok();
}

void PrintSkippedLines(std::FILE* out,
                       const std::string& tool,
                       const std::string& path,
                       const std::vector<SkippedLine>& skipped) {
  constexpr size_t kShown = 20;
  for (size_t k = 0; k < std::min(kShown, skipped.size()); ++k) {
    std::fprintf(
        out, "%s: skipped %s: %s\n", tool.c_str(), path.c_str(), skipped[k].message.c_str());
  }
  if (skipped.size() > kShown) {
    std::fprintf(out,
                 "%s: skipped %zu more invalid edge lines of %s\n",
                 tool.c_str(),
                 skipped.size() - kShown,
                 path.c_str());
  }
}

FileFormat FormatForPath(const std::string& path) {
  const std::string suffix = ".graph";
  const bool toro = path.size() >= suffix.size() &&
                    path.compare(path.size() - suffix.size(), suffix.size(), suffix) == 0;
  return toro ? FileFormat::kToro : FileFormat::kG2o;
}

Status WriteFileAtomically(const std::string& path,
                           const std::function<Status(std::ostream&)>& write) {
  const std::string temporary = path + ".tmp";
  {
    std::ofstream out(temporary, std::ios::trunc);
    if (!out) return Status::Error(temporary + ": cannot create");
    if (Status s = write(out); !s.ok()) {
      std::remove(temporary.c_str());
      return Status::Error(path + ": " + s.message());
    }
    out.flush();
    if (!out) {
      std::remove(temporary.c_str());
      return Status::Error(temporary + ": write failed");
    }
  }
  if (std::rename(temporary.c_str(), path.c_str()) != 0) {
    std::remove(temporary.c_str());
    return Status::Error(path + ": cannot rename " + temporary + " over it");
  }
  return Status::Ok();
}

namespace {

// One pose per line, in vertex order: "x y yaw" (SE(2)) or "x y z qx qy qz qw" (SE(3)).
template <class Pose>
Status ReadPoseLines(const std::string& path, std::vector<Pose>* poses) {
  std::ifstream in(path);
  if (!in) return Status::Error(path + ": cannot open");
  std::string line;
  int line_number = 0;
  std::vector<Pose> out;
  while (std::getline(in, line)) {
    ++line_number;
    std::istringstream fields(line);
    std::vector<double> v;
    double value;
    while (fields >> value) v.push_back(value);
    if (v.empty()) continue;
    if constexpr (Pose::kDim == 3) {
      if (v.size() != 3) {
        return Status::Error(path + ": line " + std::to_string(line_number) + ": expected x y yaw");
      }
      out.push_back(Pose2(v[0], v[1], v[2]));
    } else {
      if (v.size() != 7) {
        return Status::Error(path + ": line " + std::to_string(line_number) +
                             ": expected x y z qx qy qz qw");
      }
      out.push_back(Pose3(Eigen::Quaterniond(v[6], v[3], v[4], v[5]).normalized(),
                          Eigen::Vector3d(v[0], v[1], v[2])));
    }
  }
  poses->swap(out);
  return Status::Ok();
}

}  // namespace

template <class Pose>
Status LoadGroundTruth(const std::string& path,
                       const PoseGraph<Pose>& graph,
                       std::vector<Pose>* ground_truth) {
  FileFormat format;
  int dimension = 0;
  std::vector<Pose> poses(graph.num_vertices());
  if (InspectGraphFile(path, &format, &dimension).ok()) {
    if (dimension != Pose::kTranslationDim) {
      return Status::Error(path + ": ground truth is " + std::to_string(dimension) +
                           "D, the graph is not");
    }
    GraphFile<Pose> file;
    PoseGraph<Pose> reference;
    std::vector<int> unused;
    if (Status s = LoadPoseGraph(path, format, ReadOptions(), &file, &reference, &unused);
        !s.ok()) {
      return s;
    }
    for (int v = 0; v < graph.num_vertices(); ++v) {
      const int k = reference.FindVertex(graph.vertex(v).id);
      if (k < 0) {
        return Status::Error(path + ": no ground truth for vertex " +
                             std::to_string(graph.vertex(v).id));
      }
      poses[v] = reference.initial_estimate()[k];
    }
  } else {
    std::vector<Pose> lines;
    if (Status s = ReadPoseLines(path, &lines); !s.ok()) return s;
    if (static_cast<int>(lines.size()) != graph.num_vertices()) {
      return Status::Error(path + ": " + std::to_string(lines.size()) + " poses for " +
                           std::to_string(graph.num_vertices()) + " vertices");
    }
    poses = lines;
  }
  ground_truth->swap(poses);
  return Status::Ok();
}

template Status LoadPoseGraph<Pose2>(const std::string&,
                                     FileFormat,
                                     const ReadOptions&,
                                     GraphFile<Pose2>*,
                                     PoseGraph<Pose2>*,
                                     std::vector<int>*);
template Status LoadPoseGraph<Pose3>(const std::string&,
                                     FileFormat,
                                     const ReadOptions&,
                                     GraphFile<Pose3>*,
                                     PoseGraph<Pose3>*,
                                     std::vector<int>*);
template Status LoadGroundTruth<Pose2>(const std::string&,
                                       const PoseGraph<Pose2>&,
                                       std::vector<Pose2>*);
template Status LoadGroundTruth<Pose3>(const std::string&,
                                       const PoseGraph<Pose3>&,
                                       std::vector<Pose3>*);

}  // namespace irrr
