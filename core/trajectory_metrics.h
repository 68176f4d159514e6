#ifndef IRRR_CORE_TRAJECTORY_METRICS_H_
#define IRRR_CORE_TRAJECTORY_METRICS_H_

// Absolute trajectory error (algorithm-notes, "Scoring"): translation RMSE after the rigid
// alignment (rotation and translation, no scale; Umeyama 1991) of each group of poses to the
// reference trajectory.

#include <vector>

#include "core/pose.h"

namespace irrr {

struct TrajectoryError {
  double rmse_m = 0.0;
  double mean_m = 0.0;
  double max_m = 0.0;
  std::vector<double> errors_m;  // per pose, in the order of the groups' indices
};

// `groups` lists pose indices aligned together (one group per connected component); every index
// must be valid for both trajectories, which must be of equal size (checked, aborts otherwise).
template <class Pose>
TrajectoryError AbsoluteTrajectoryError(const std::vector<Pose>& estimate,
                                        const std::vector<Pose>& reference,
                                        const std::vector<std::vector<int>>& groups);

// All poses as one group.
template <class Pose>
TrajectoryError AbsoluteTrajectoryError(const std::vector<Pose>& estimate,
                                        const std::vector<Pose>& reference);

}  // namespace irrr

#endif  // IRRR_CORE_TRAJECTORY_METRICS_H_
