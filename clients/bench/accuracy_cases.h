#ifndef IRRR_CLIENTS_BENCH_ACCURACY_CASES_H_
#define IRRR_CLIENTS_BENCH_ACCURACY_CASES_H_

// The accuracy benchmark's matrix: which graph each case reads from the shared folder, what it
// is scored against, and the failures generated into it.

#include <string>
#include <vector>

#include "core/outliers.h"

namespace irrr {

enum class CaseKind {
  kSynthetic,  // a clean graph (every loop true) plus generated outliers
  kLabelled,   // a place-recognition graph with a file of its true loops ("i j" per line)
  kUnlabelled  // a place-recognition graph without labels, ATE against GPS
};

enum class ReferenceKind {
  kPoseLines,     // one "x y yaw" line per vertex (Vertigo *_nodes_groundTruth.dat)
  kGraphFile,     // a pose-graph file (edges-only files chained along their odometry)
  kIsamEdges,     // iSAM EDGE2/EDGE3 noise-free edges: chain the sequential ones
  kOracle,        // no ground truth: the oracle's optimum is the reference
  kTimestampGps,  // Bicocca: vertex k <-> timestamps line k, nearest GPS row in time
  kStridedGps,    // Bovisa: the GPS graph's vertex k <-> graph vertex id kGpsStride * k
};

struct Case {
  std::string name;
  CaseKind kind = CaseKind::kSynthetic;
  std::string graph;  // paths relative to the shared folder
  ReferenceKind reference = ReferenceKind::kOracle;
  std::string reference_path;
  std::string labels;      // kLabelled: true loops
  std::string timestamps;  // kTimestampGps: one time per graph vertex
  OutlierMode mode = OutlierMode::kRandom;
  int outliers = 0;
  bool wrong_only = false;  // kLabelled: the true loops removed (a correct answer accepts none)
  // kSynthetic failure families beyond wrong loops (core/outliers.h): odometry re-drawn with
  // `odometry_noise` times the noise its information states (0: as given), and odometry faults.
  double odometry_noise = 0.0;
  int odometry_faults = 0;
};

// Every case of the matrix, in the order the tables list them.
std::vector<Case> AllCases();

}  // namespace irrr

#endif  // IRRR_CLIENTS_BENCH_ACCURACY_CASES_H_
