#ifndef IRRR_CORE_OUTLIERS_H_
#define IRRR_CORE_OUTLIERS_H_

// Failures for experiments, seeded and reproducible (used by irrr-corrupt and the tests): wrong
// loop closures, noisy odometry and faulty odometry edges; and the session split of the paper's
// multi-session experiment (IV.B).

#include <cstdint>
#include <vector>

#include "core/graph_io.h"
#include "core/pose_graph.h"

namespace irrr {

enum class OutlierMode {
  kRandom,          // single links between two random poses, random measurement
  kLocal,           // single links between poses at most `local_window` apart, random measurement
  kRandomGrouped,   // groups of `group_size` links between two random places that agree with each
                    // other and with odometry (an "organized conspiracy")
  kLocalGrouped,    // the same between places at most `local_window` apart
  kInterSession,    // groups as above between two different sessions
  kAliased,         // perceptual aliasing: single links between two random poses (any sessions)
                    // claiming they are nearly the same place (a small measurement)
  kAliasedGrouped,  // groups built as kRandomGrouped whose claim is small as kAliased's
};

// The mode's name as the tools spell it: random, local, random-grouped, local-grouped,
// inter-session, aliased, aliased-grouped.
const char* OutlierModeName(OutlierMode mode);
// Whether the mode writes groups of links that agree with each other.
bool IsGrouped(OutlierMode mode);

struct OutlierOptions {
  OutlierMode mode = OutlierMode::kRandom;
  int count = 100;  // links in all (groups: a multiple of group_size is used, rounded up)
  int group_size = 3;
  int local_window = 50;              // poses
  double translation_range_m = 10.0;  // random measurements: translation in [-r, r] per axis
  // Aliased claims: translation uniform in the disc (2D) or ball (3D) of this radius; rotation
  // uniform within this angle (2D: yaw in [-a, a]; 3D: a uniformly random axis, angle uniform in
  // [0, a]).
  double aliased_translation_m = 1.0;
  double aliased_rotation_rad = 0.3;
  uint32_t seed = 1;
};

template <class Pose>
struct OutlierLink {
  int from = -1;  // vertex indices
  int to = -1;
  Pose measurement;
  typename Pose::Matrix information;
};

// Generates wrong loop closures for `graph`. Grouped links are consistent with the graph's
// dead reckoning: all links of a group claim the same wrong transform between two places (link m
// of a group joins the m-th poses of two runs of group_size consecutive poses; `outliers` holds
// the groups one after the other). Links never join poses of one session closer than 2 +
// (group_size, or 1 for lone links). Their information is that of the graph's first loop edge (of
// its first odometry edge if it has no loop). Fails (`outliers` untouched) on a negative count, an
// aliased translation or rotation bound that is negative or not finite (rotation above pi), a
// graph too small for the request, or kInterSession with one session.
template <class Pose>
Status MakeOutliers(const PoseGraph<Pose>& graph,
                    const OutlierOptions& options,
                    std::vector<OutlierLink<Pose>>* outliers);

// Splits a file's single trajectory into sessions starting at the given vertex ids (each must be
// a vertex with an odometry edge from its predecessor): those odometry edges are deleted and each
// new session's vertex estimates are re-based so that its first pose is the origin, as in the
// paper's Intel experiment. Fails (file untouched) on an id that is not such a vertex.
template <class Pose>
Status SplitIntoSessions(const std::vector<int64_t>& session_starts, GraphFile<Pose>* file);

// Noisy odometry: every odometry edge of `file` (as BuildPoseGraph reads it) gets the measurement
// z' = z * E^-1, where E is the pose whose g2o error vector is e ~ N(0, k^2 Sigma), Sigma the
// inverse of the edge's information (left as it is). Then the residual of z' at poses that satisfy
// z, RelativePoseResidual(z', I, z) = ErrorVector(z'^-1 z) = e, has covariance k^2 Sigma: the file
// reads as odometry k times noisier than its information claims. (In SE(3) a draw whose
// quaternion part has norm >= 1 is drawn again.) Each session's vertex estimates are then chained
// from its first vertex's estimate along the new odometry, as a front end's dead reckoning would
// be; edges-only files have no estimates to chain. Draws come from a stream of their own seeded by
// `seed`. Fails (file untouched) on k <= 0 or not finite, or a file BuildPoseGraph rejects.
template <class Pose>
Status PerturbOdometry(double k, uint32_t seed, GraphFile<Pose>* file);

// Odometry faults (a wheel slip, a kidnapping): `count` distinct odometry edges of `file`, chosen
// at random taking the sessions in turn (so that they spread over the sessions), get the
// measurement z * F, where the extra motion F moves 1 to 3 m in a random horizontal direction (3D:
// and up to 0.3 m in z) and turns by 0.3 to 1.0 rad (2D: either sign; 3D: about a random axis);
// information unchanged. Vertex estimates are chained again as by PerturbOdometry.
// `fault_file_edges` receives the faulty edges' indices in `file.edges`, increasing. Draws come
// from a stream of their own seeded by `seed`. Fails (outputs untouched) on a negative count, more
// faults than odometry edges, or a file BuildPoseGraph rejects.
template <class Pose>
Status InjectOdometryFaults(int count,
                            uint32_t seed,
                            GraphFile<Pose>* file,
                            std::vector<int>* fault_file_edges);

}  // namespace irrr

#endif  // IRRR_CORE_OUTLIERS_H_
