// libFuzzer target: the pose-graph file readers of core/graph_io.h on any bytes. The bytes are a
// file's text; they go through DetectGraphFile, then ReadGraphFile as 2D and as 3D (strictly, and
// with skip_unknown_tags and skip_invalid_edges), and what reads goes through BuildPoseGraph. A
// malformed file must give an error Status, never a crash, a leak or a sanitizer report. Beyond
// that, the contracts of graph_io.h are checked (IRRR_CHECK aborts, which libFuzzer reports as a
// crash):
//  - a failed read or build leaves its output untouched (empty);
//  - what reads writes back, and write -> read -> write is byte-identical: what the skipping read
//    keeps reads strictly.

#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>
#include <vector>

#include "core/graph_io.h"
#include "core/pose.h"
#include "core/pose_graph.h"
#include "core/status.h"

namespace irrr {
namespace {

template <class Pose>
std::string Written(FileFormat format, const GraphFile<Pose>& file) {
  std::ostringstream out;
  IRRR_CHECK(WriteGraphFile(out, format, file).ok());
  return out.str();
}

template <class Pose>
void ReadAndBuild(const std::string& text, FileFormat format, bool skip) {
  ReadOptions options;
  options.skip_unknown_tags = skip;
  options.skip_invalid_edges = skip;
  std::istringstream in(text);
  GraphFile<Pose> file;
  if (!ReadGraphFile(in, format, options, &file).ok()) {
    IRRR_CHECK(file.vertices.empty() && file.edges.empty() && file.skipped.empty());
    return;
  }
  IRRR_CHECK(skip || file.skipped.empty());

  PoseGraph<Pose> graph;
  std::vector<int> graph_edge_of_file_edge;
  if (BuildPoseGraph(file, &graph, &graph_edge_of_file_edge).ok()) {
    IRRR_CHECK(graph_edge_of_file_edge.size() == file.edges.size());
    Written(format, WithEstimate(file, graph, graph.initial_estimate()));
  } else {
    IRRR_CHECK(graph.num_vertices() == 0 && graph_edge_of_file_edge.empty());
  }

  const std::string first = Written(format, file);
  std::istringstream again(first);
  GraphFile<Pose> reread;
  IRRR_CHECK(ReadGraphFile(again, format, ReadOptions(), &reread).ok());
  IRRR_CHECK(Written(format, reread) == first);
}

}  // namespace
}  // namespace irrr

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using irrr::FileFormat;
  const std::string text(reinterpret_cast<const char*>(data), size);
  std::istringstream in(text);
  FileFormat detected = FileFormat::kG2o;
  int dimension = 0;
  // The detected format, as the tools read files; when detection fails, both (the readers must
  // fail as cleanly, or read a file whose first tag skip_unknown_tags skips).
  std::vector<FileFormat> formats = {FileFormat::kG2o, FileFormat::kToro};
  if (irrr::DetectGraphFile(in, &detected, &dimension).ok()) {
    IRRR_CHECK(dimension == 2 || dimension == 3);
    formats = {detected};
  }
  for (const FileFormat format : formats) {
    for (const bool skip : {false, true}) {
      irrr::ReadAndBuild<irrr::Pose2>(text, format, skip);
      irrr::ReadAndBuild<irrr::Pose3>(text, format, skip);
    }
  }
  return 0;
}
