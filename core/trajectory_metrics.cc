#include "core/trajectory_metrics.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include <Eigen/Geometry>

#include "core/status.h"

namespace irrr {

template <class Pose>
TrajectoryError AbsoluteTrajectoryError(const std::vector<Pose>& estimate,
                                        const std::vector<Pose>& reference,
                                        const std::vector<std::vector<int>>& groups) {
  constexpr int kDim = Pose::kTranslationDim;
  IRRR_CHECK(estimate.size() == reference.size());
  TrajectoryError result;
  double sum_squared = 0.0;
  for (const std::vector<int>& group : groups) {
    const int count = static_cast<int>(group.size());
    if (count == 0) continue;
    Eigen::Matrix<double, kDim, Eigen::Dynamic> source(kDim, count);
    Eigen::Matrix<double, kDim, Eigen::Dynamic> target(kDim, count);
    for (int k = 0; k < count; ++k) {
      IRRR_CHECK(group[k] >= 0 && group[k] < static_cast<int>(estimate.size()));
      source.col(k) = estimate[group[k]].translation();
      target.col(k) = reference[group[k]].translation();
    }
    // With one point the rotation is undetermined and the translation alone aligns it.
    const Eigen::Matrix<double, kDim + 1, kDim + 1> reference_T_estimate =
        count > 1 ? Eigen::umeyama(source, target, /*with_scaling=*/false)
                  : Eigen::Matrix<double, kDim + 1, kDim + 1>::Identity();
    for (int k = 0; k < count; ++k) {
      Eigen::Matrix<double, kDim, 1> aligned =
          reference_T_estimate.template topLeftCorner<kDim, kDim>() * source.col(k) +
          reference_T_estimate.template topRightCorner<kDim, 1>();
      if (count == 1) aligned = target.col(k);
      const double error = (aligned - target.col(k)).norm();
      result.errors_m.push_back(error);
      sum_squared += error * error;
      result.max_m = std::max(result.max_m, error);
    }
  }
  if (!result.errors_m.empty()) {
    const double n = static_cast<double>(result.errors_m.size());
    result.rmse_m = std::sqrt(sum_squared / n);
    result.mean_m = std::accumulate(result.errors_m.begin(), result.errors_m.end(), 0.0) / n;
  }
  return result;
}

template <class Pose>
TrajectoryError AbsoluteTrajectoryError(const std::vector<Pose>& estimate,
                                        const std::vector<Pose>& reference) {
  std::vector<int> all(estimate.size());
  std::iota(all.begin(), all.end(), 0);
  return AbsoluteTrajectoryError(estimate, reference, std::vector<std::vector<int>>{all});
}

template TrajectoryError AbsoluteTrajectoryError<Pose2>(const std::vector<Pose2>&,
                                                        const std::vector<Pose2>&,
                                                        const std::vector<std::vector<int>>&);
template TrajectoryError AbsoluteTrajectoryError<Pose3>(const std::vector<Pose3>&,
                                                        const std::vector<Pose3>&,
                                                        const std::vector<std::vector<int>>&);
template TrajectoryError AbsoluteTrajectoryError<Pose2>(const std::vector<Pose2>&,
                                                        const std::vector<Pose2>&);
template TrajectoryError AbsoluteTrajectoryError<Pose3>(const std::vector<Pose3>&,
                                                        const std::vector<Pose3>&);

}  // namespace irrr
