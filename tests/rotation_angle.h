#ifndef IRRR_TESTS_ROTATION_ANGLE_H_
#define IRRR_TESTS_ROTATION_ANGLE_H_

#include <cmath>

#include "core/pose.h"

namespace irrr {

// A pose's rotation angle in [0, pi].
inline double RotationAngle(const Pose2& pose) { return std::abs(pose.yaw_rad()); }
inline double RotationAngle(const Pose3& pose) {
  return 2.0 * std::atan2(pose.quaternion().vec().norm(), std::abs(pose.quaternion().w()));
}

}  // namespace irrr

#endif  // IRRR_TESTS_ROTATION_ANGLE_H_
