#ifndef IRRR_CORE_GRAPH_IO_H_
#define IRRR_CORE_GRAPH_IO_H_

// Pose-graph files: g2o (2D VERTEX_SE2/EDGE_SE2, 3D VERTEX_SE3:QUAT/EDGE_SE3:QUAT) and TORO 2D
// (VERTEX2/EDGE2). Stream based: opening files and atomic writes belong to the clients.
//
// Reading is in two steps. ReadGraphFile turns text into records exactly as the file has them
// (ids, file order, line numbers); BuildPoseGraph turns records into a PoseGraph (sessions,
// odometry, loop hypotheses, initial estimate). Nothing half-read is ever returned: on error the
// output is untouched and the message names the line and what is wrong.

#include <cstdint>
#include <istream>
#include <ostream>
#include <string>
#include <vector>

#include "core/pose.h"
#include "core/pose_graph.h"
#include "core/status.h"

namespace irrr {

enum class FileFormat {
  kG2o,   // VERTEX_SE2 / EDGE_SE2 (information: upper triangle row by row), or the SE3:QUAT tags
  kToro,  // VERTEX2 / EDGE2 (information order xx xy yy tt xt yt), 2D only
};

template <class Pose>
struct FileVertex {
  int64_t id = 0;
  Pose estimate;
  int line = 0;  // 1-based line number in the input (0 for records not read from a file)
};

template <class Pose>
struct FileEdge {
  int64_t from = 0;
  int64_t to = 0;
  Pose measurement;  // from_T_to
  typename Pose::Matrix information = Pose::Matrix::Identity();
  int line = 0;
};

// An edge line left out by ReadOptions::skip_invalid_edges, with the error it would have been.
struct SkippedLine {
  int line = 0;
  std::string message;  // "line N: EDGE_SE2 1 1: self-loop"
};

// A file's content in file order. `vertices` is empty for edges-only files.
template <class Pose>
struct GraphFile {
  std::vector<FileVertex<Pose>> vertices;
  std::vector<FileEdge<Pose>> edges;
  std::vector<SkippedLine> skipped;  // in line order; empty unless skip_invalid_edges
};

struct ReadOptions {
  // Lines whose tag is not understood (EQUIV, VERTEX_XY, ...) are an error unless this is set.
  bool skip_unknown_tags = false;
  // An edge line that is well formed (its tag and count of numbers) but not a valid edge (a
  // self-loop, a non-finite number, a measurement or information matrix that is not valid, or an
  // end vertex the file does not declare) is an error unless this is set; then it is left out and
  // listed in GraphFile::skipped. Public datasets carry such lines (New College: nine EDGE_SE2
  // 1 1; Cubicle: information matrices that are not positive definite).
  bool skip_invalid_edges = false;
};

// Reads lines until the first data line and reports the format and dimension (2 or 3) its tag
// implies. Consumes the stream: callers rewind or reopen. Fails on an empty file or an unknown
// first tag.
Status DetectGraphFile(std::istream& in, FileFormat* format, int* dimension);

// Parses a whole stream. Blank lines and lines starting with '#' are skipped; g2o FIX lines are
// ignored (the gauge is chosen by the optimizer). Fails, naming the 1-based line, on: a tag of the
// wrong format or dimension, missing or extra fields, a token that is not a number, non-finite
// numbers, a quaternion of non-unit norm, an information matrix that is not positive definite, a
// duplicate vertex id, an edge to an undeclared vertex (when the file declares vertices), and a
// self-loop (the edge faults among these are skipped instead with skip_invalid_edges). Unit
// quaternions are normalized to the unit sphere.
template <class Pose>
Status ReadGraphFile(std::istream& in,
                     FileFormat format,
                     const ReadOptions& options,
                     GraphFile<Pose>* out);

// Writes records in their order, with 17 significant digits so that reading gives back the same
// doubles. TORO is 2D only. Fails (writing nothing) on a format that cannot hold the pose type.
template <class Pose>
Status WriteGraphFile(std::ostream& out, FileFormat format, const GraphFile<Pose>& file);

// Builds a PoseGraph from records (algorithm-notes, "Files as input"):
//  - vertices in increasing id order; a session starts at every vertex i with no edge (i-1, i);
//    sessions get ids 0, 1, ... in that order; a vertex's stamp is its ordinal in id order;
//  - the first edge (i-1, i) is that pose's odometry; every other edge, including a second
//    (i-1, i) edge and an edge (i, i-1), is a loop hypothesis, added in file order;
//  - initial estimate: the file's vertex estimates, or, for edges-only files, each session
//    chained from the identity along its odometry.
// `graph_edge_of_file_edge[k]` receives the graph edge index of file edge k. `graph` must be
// empty; on error it is left empty and the message names the offending line.
template <class Pose>
Status BuildPoseGraph(const GraphFile<Pose>& file,
                      PoseGraph<Pose>* graph,
                      std::vector<int>* graph_edge_of_file_edge);

// The records of `file` with every vertex's estimate replaced by `estimate` (indexed like the
// graph's vertices); edges-only files gain one vertex record per graph vertex, in id order.
template <class Pose>
GraphFile<Pose> WithEstimate(const GraphFile<Pose>& file,
                             const PoseGraph<Pose>& graph,
                             const std::vector<Pose>& estimate);

}  // namespace irrr

#endif  // IRRR_CORE_GRAPH_IO_H_
