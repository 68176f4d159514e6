#ifndef IRRR_CLIENTS_BENCH_REFERENCE_FILES_H_
#define IRRR_CLIENTS_BENCH_REFERENCE_FILES_H_

// The accuracy benchmark's reference files: ground truth as iSAM edge chains, Bicocca's GPS
// associated by time, Bovisa's by vertex id, and the labels of true loops.

#include <string>
#include <vector>

#include "core/pose_graph.h"
#include "core/status.h"

namespace irrr {

// Bicocca: a graph vertex counts toward the ATE only with a GPS fix this close in time.
constexpr double kGpsMatchSeconds = 0.5;
// Bovisa: odometry poses per GPS fix.
constexpr int kGpsStride = 10;

// The reference trajectory for ATE: one pose per vertex, and which vertices have one.
template <class Pose>
struct Reference {
  std::vector<Pose> poses;
  std::vector<char> valid;
  std::string label;  // for the table: "GT", "oracle", "GPS n/N"
};

// Parses iSAM text edges ("EDGE2 i j x y yaw" + 6 sqrt-information entries, "EDGE3 i j x y z roll
// pitch yaw" + 21, rotation Rz(yaw) Ry(pitch) Rx(roll)); only the measurements of sequential edges
// (j = i + 1, the first one of each i) are used. The chain from the identity gives the pose of
// every vertex id 0..n-1; `graph` vertices look theirs up by id.
template <class Pose>
Status ChainIsamEdges(const std::string& path,
                      const PoseGraph<Pose>& graph,
                      std::vector<Pose>* poses);

// Reads numbers per line (commas count as spaces); lines with fewer than `min_fields` numbers
// are an error, blank lines are skipped.
Status ReadNumberRows(const std::string& path,
                      size_t min_fields,
                      std::vector<std::vector<double>>* rows);

// Bicocca: vertex k (by id) has time timestamps[k]; its reference is the GPS row nearest in time,
// if within kGpsMatchSeconds.
Status TimeAssociatedGps(const std::string& timestamps_path,
                         const std::string& gps_path,
                         const PoseGraph<Pose2>& graph,
                         Reference<Pose2>* reference);

// Bovisa: the GPS file (a g2o graph) holds one fix per `stride` odometry poses: its vertex k is
// graph vertex id `stride` * k.
Status StridedGps(const std::string& gps_path,
                  int stride,
                  const PoseGraph<Pose2>& graph,
                  Reference<Pose2>* reference);

// True loops of a labelled graph: unordered vertex-id pairs. Reports labels matching no loop.
Status ReadLabels(const std::string& path,
                  const PoseGraph<Pose2>& graph,
                  std::vector<char>* is_true,
                  int* unmatched_labels);

}  // namespace irrr

#endif  // IRRR_CLIENTS_BENCH_REFERENCE_FILES_H_
