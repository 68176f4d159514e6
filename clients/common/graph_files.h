#ifndef IRRR_CLIENTS_COMMON_GRAPH_FILES_H_
#define IRRR_CLIENTS_COMMON_GRAPH_FILES_H_

// Paths, atomic writes and ground-truth files for the command-line tools (core reads and writes
// streams only).

#include <cstdio>
#include <functional>
#include <ostream>
#include <string>
#include <vector>

#include "core/graph_io.h"
#include "core/pose_graph.h"
#include "core/status.h"

namespace irrr {

// Format and dimension of a pose-graph file, from its first data line.
Status InspectGraphFile(const std::string& path, FileFormat* format, int* dimension);

// Reads and builds a graph file. Errors name the path and the line.
template <class Pose>
Status LoadPoseGraph(const std::string& path,
                     FileFormat format,
                     const ReadOptions& options,
                     GraphFile<Pose>* file,
                     PoseGraph<Pose>* graph,
                     std::vector<int>* graph_edge_of_file_edge);

// Names on `out` each edge line ReadOptions::skip_invalid_edges left out of `path` (the first
// 20, then how many more), as "TOOL: skipped PATH: line N: ...".
void PrintSkippedLines(std::FILE* out,
                       const std::string& tool,
                       const std::string& path,
                       const std::vector<SkippedLine>& skipped);

// TORO for *.graph, g2o otherwise.
FileFormat FormatForPath(const std::string& path);

// Writes to `path`.tmp, flushes, and renames over `path`, so readers never see half a file.
Status WriteFileAtomically(const std::string& path,
                           const std::function<Status(std::ostream&)>& write);

// Ground-truth poses for the vertices of `graph`, from either a pose-graph file (vertices by id;
// an edges-only file is chained along its odometry) or a text file with one pose per line in
// vertex order ("x y yaw" in 2D, as Vertigo's *_nodes_groundTruth.dat).
template <class Pose>
Status LoadGroundTruth(const std::string& path,
                       const PoseGraph<Pose>& graph,
                       std::vector<Pose>* ground_truth);

}  // namespace irrr

#endif  // IRRR_CLIENTS_COMMON_GRAPH_FILES_H_
