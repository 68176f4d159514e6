#ifndef IRRR_CORE_OUTLIERS_H_
#define IRRR_CORE_OUTLIERS_H_

// Wrong loop closures for experiments, seeded and reproducible (used by irrr-corrupt and the
// tests), and the session split of the paper's multi-session experiment (IV.B).

#include <cstdint>
#include <vector>

#include "core/graph_io.h"
#include "core/pose_graph.h"

namespace irrr {

enum class OutlierMode {
  kRandom,         // single links between two random poses, random measurement
  kLocal,          // single links between poses at most `local_window` apart, random measurement
  kRandomGrouped,  // groups of `group_size` links between two random places that agree with each
                   // other and with odometry (an "organized conspiracy")
  kLocalGrouped,   // the same between places at most `local_window` apart
  kInterSession,   // groups as above between two different sessions
};

// The mode's name as the tools spell it: random, local, random-grouped, local-grouped,
// inter-session.
const char* OutlierModeName(OutlierMode mode);
// Whether the mode writes groups of links that agree with each other.
bool IsGrouped(OutlierMode mode);

struct OutlierOptions {
  OutlierMode mode = OutlierMode::kRandom;
  int count = 100;  // links in all (groups: a multiple of group_size is used, rounded up)
  int group_size = 3;
  int local_window = 50;              // poses
  double translation_range_m = 10.0;  // random measurements: translation in [-r, r] per axis
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
// dead reckoning: all links of a group claim the same wrong transform between two places. Links
// never join poses closer than 2 in a session. Their information is that of the graph's first
// loop edge (of its first odometry edge if it has no loop). Fails on a graph too small for the
// request, or kInterSession with one session.
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

}  // namespace irrr

#endif  // IRRR_CORE_OUTLIERS_H_
