#include "core/trajectory_metrics.h"

#include <cmath>
#include <random>

#include <catch2/catch.hpp>

namespace irrr {
namespace {

std::vector<Pose2> RandomTrajectory2(int n, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-10.0, 10.0);
  std::vector<Pose2> poses;
  for (int i = 0; i < n; ++i) poses.push_back(Pose2(u(rng), u(rng), u(rng)));
  return poses;
}

TEST_CASE("A rigidly moved trajectory has zero ATE", "[trajectory_metrics]") {
  const std::vector<Pose2> reference = RandomTrajectory2(50, 3);
  const Pose2 world_T_other(4.0, -2.0, 2.5);
  std::vector<Pose2> estimate;
  for (const Pose2& p : reference) estimate.push_back(world_T_other * p);
  const TrajectoryError ate = AbsoluteTrajectoryError(estimate, reference);
  CHECK(ate.rmse_m < 1e-12);
  CHECK(ate.errors_m.size() == 50);
}

TEST_CASE("ATE of a known offset equals the offset's spread", "[trajectory_metrics]") {
  // Four corners of a square; the estimate stretches the square by 1 m along x on each side:
  // the best rigid alignment leaves every corner 1 m off.
  std::vector<Pose2> reference = {
      Pose2(0, 0, 0), Pose2(10, 0, 0), Pose2(10, 10, 0), Pose2(0, 10, 0)};
  std::vector<Pose2> estimate = {
      Pose2(-1, 0, 0), Pose2(11, 0, 0), Pose2(11, 10, 0), Pose2(-1, 10, 0)};
  const TrajectoryError ate = AbsoluteTrajectoryError(estimate, reference);
  CHECK(ate.rmse_m == Approx(1.0).epsilon(1e-12));
  CHECK(ate.max_m == Approx(1.0).epsilon(1e-12));
}

TEST_CASE("Components are aligned separately", "[trajectory_metrics]") {
  const std::vector<Pose3> reference = {
      Pose3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 0, 0)),
      Pose3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(1, 0, 0)),
      Pose3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 1, 0)),
      Pose3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(5, 5, 5)),
      Pose3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(6, 5, 5)),
      Pose3(Eigen::Quaterniond::Identity(), Eigen::Vector3d(5, 7, 5))};
  const Pose3 offset(Eigen::Quaterniond(Eigen::AngleAxisd(1.0, Eigen::Vector3d::UnitZ())),
                     Eigen::Vector3d(3, 0, 0));
  std::vector<Pose3> estimate = reference;
  for (int i = 3; i < 6; ++i) estimate[i] = offset * reference[i];
  CHECK(AbsoluteTrajectoryError(estimate, reference, {{0, 1, 2}, {3, 4, 5}}).rmse_m < 1e-12);
  CHECK(AbsoluteTrajectoryError(estimate, reference).rmse_m > 0.1);
}

}  // namespace
}  // namespace irrr
