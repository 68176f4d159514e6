#include "tests/synthetic_graph.h"

#include <cmath>
#include <map>
#include <random>
#include <utility>

#include "core/status.h"

namespace irrr::testing {
namespace {

template <class Pose>
typename Pose::Tangent Sigmas(const SyntheticOptions& options) {
  typename Pose::Tangent sigma;
  constexpr int t = Pose::kTranslationDim;
  sigma.template head<t>().setConstant(options.translation_sigma_m);
  sigma.template tail<Pose::kDim - t>().setConstant(options.rotation_sigma_rad);
  return sigma;
}

// Information of a measurement perturbed by Retract(n), n ~ N(0, diag(sigma^2)), in the error
// chart: the SE(3) chart holds half the rotation angle, so its rotation information is 4x.
template <class Pose>
typename Pose::Matrix InformationFor(const SyntheticOptions& options) {
  // A zero-noise graph still needs a finite weight; these are the weights of 1 cm / 0.01 rad.
  constexpr double kNominalTranslationSigmaM = 0.01;
  constexpr double kNominalRotationSigmaRad = 0.01;
  typename Pose::Tangent sigma = Sigmas<Pose>(options);
  constexpr int t = Pose::kTranslationDim;
  for (int k = 0; k < Pose::kDim; ++k) {
    if (sigma(k) <= 0.0) sigma(k) = k < t ? kNominalTranslationSigmaM : kNominalRotationSigmaRad;
  }
  typename Pose::Tangent information = sigma.cwiseProduct(sigma).cwiseInverse();
  if constexpr (Pose::kDim == 6) information.template tail<3>() *= 4.0;
  return (options.information_scale * information).asDiagonal();
}

template <class Pose>
Pose Noisy(const Pose& truth, const SyntheticOptions& options, std::mt19937* rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  const typename Pose::Tangent sigma = Sigmas<Pose>(options);
  typename Pose::Tangent noise;
  for (int k = 0; k < Pose::kDim; ++k) noise(k) = sigma(k) * normal(*rng);
  return truth.Retract(noise);
}

// Ground truth trajectories and which pairs (later, earlier) revisit the same place.
void GridWorld(const SyntheticOptions& options,
               std::mt19937* rng,
               std::vector<Pose2>* poses,
               std::vector<std::pair<int, int>>* revisits) {
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  std::map<std::pair<int, int>, std::vector<int>> visits;
  int x = 0;
  int y = 0;
  int heading = 0;  // quarter turns
  for (int i = 0; i < options.num_poses; ++i) {
    if (i > 0) {
      const double u = uniform(*rng);
      if (u < 0.15) heading = (heading + 1) % 4;
      if (u > 0.85) heading = (heading + 3) % 4;
      // Stay inside a 10 x 10 block so that the robot keeps revisiting places.
      constexpr int kHalfWidth = 5;
      static const int kDx[4] = {1, 0, -1, 0};
      static const int kDy[4] = {0, 1, 0, -1};
      while (std::abs(x + kDx[heading]) > kHalfWidth || std::abs(y + kDy[heading]) > kHalfWidth) {
        heading = (heading + 1) % 4;
      }
      x += kDx[heading];
      y += kDy[heading];
    }
    poses->push_back(Pose2(x, y, heading * M_PI / 2.0));
    for (int j : visits[{x, y}]) {
      if (i - j >= options.min_loop_separation) revisits->push_back({i, j});
    }
    visits[{x, y}].push_back(i);
  }
}

void Helix(const SyntheticOptions& options,
           std::mt19937* rng,
           std::vector<Pose3>* poses,
           std::vector<std::pair<int, int>>* revisits) {
  constexpr int kPosesPerTurn = 40;
  constexpr double kRadiusM = 10.0;
  constexpr double kClimbPerTurnM = 1.0;
  std::uniform_real_distribution<double> wobble(-0.2, 0.2);
  for (int i = 0; i < options.num_poses; ++i) {
    const double angle = 2.0 * M_PI * i / kPosesPerTurn;
    const Eigen::Vector3d position(
        kRadiusM * std::cos(angle), kRadiusM * std::sin(angle), kClimbPerTurnM * i / kPosesPerTurn);
    const Eigen::Quaterniond rotation =
        Eigen::AngleAxisd(angle + M_PI / 2.0, Eigen::Vector3d::UnitZ()) *
        Eigen::AngleAxisd(wobble(*rng), Eigen::Vector3d::UnitY()) *
        Eigen::AngleAxisd(wobble(*rng), Eigen::Vector3d::UnitX());
    poses->push_back(Pose3(rotation.normalized(), position));
    for (int j = i - kPosesPerTurn; j >= 0; j -= kPosesPerTurn) {
      if (i - j >= options.min_loop_separation) revisits->push_back({i, j});
    }
  }
}

}  // namespace

template <class Pose>
SyntheticGraph<Pose> MakeSyntheticGraph(const SyntheticOptions& options) {
  IRRR_CHECK(options.num_sessions >= 1 && options.num_poses >= options.num_sessions);
  std::mt19937 rng(options.seed);
  SyntheticGraph<Pose> out;
  std::vector<std::pair<int, int>> revisits;
  if constexpr (std::is_same_v<Pose, Pose2>) {
    GridWorld(options, &rng, &out.ground_truth, &revisits);
  } else {
    Helix(options, &rng, &out.ground_truth, &revisits);
  }
  const typename Pose::Matrix information = InformationFor<Pose>(options);
  const int per_session = options.num_poses / options.num_sessions;
  Pose dead_reckoning;
  for (int i = 0; i < options.num_poses; ++i) {
    const int session = std::min(i / per_session, options.num_sessions - 1);
    const bool first = session >= out.graph.num_sessions();
    if (first) {
      IRRR_CHECK(out.graph.AddSession(session, nullptr).ok());
      dead_reckoning = Pose();
      IRRR_CHECK(out.graph.AddPose(session, i, i, dead_reckoning, nullptr, nullptr, nullptr).ok());
      continue;
    }
    const Pose odometry =
        Noisy(out.ground_truth[i - 1].Inverse() * out.ground_truth[i], options, &rng);
    dead_reckoning = dead_reckoning * odometry;
    IRRR_CHECK(
        out.graph.AddPose(session, i, i, dead_reckoning, &odometry, &information, nullptr).ok());
  }
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  for (const auto& [later, earlier] : revisits) {
    if (uniform(rng) >= options.loop_probability) continue;
    const Pose measurement =
        Noisy(out.ground_truth[later].Inverse() * out.ground_truth[earlier], options, &rng);
    int edge = -1;
    IRRR_CHECK(out.graph.AddLoop(later, earlier, measurement, information, &edge).ok());
    out.loop_edges.push_back(edge);
  }
  return out;
}

template <class Pose>
void RelativeDifference(const std::vector<Pose>& a,
                        const std::vector<Pose>& b,
                        int anchor,
                        double* max_translation_m,
                        double* max_rotation_rad) {
  IRRR_CHECK(a.size() == b.size());
  *max_translation_m = 0.0;
  *max_rotation_rad = 0.0;
  const Pose a_inverse = a[anchor].Inverse();
  const Pose b_inverse = b[anchor].Inverse();
  for (size_t i = 0; i < a.size(); ++i) {
    const Pose difference = (a_inverse * a[i]).Inverse() * (b_inverse * b[i]);
    const typename Pose::Tangent xi = difference.Log();
    constexpr int t = Pose::kTranslationDim;
    *max_translation_m = std::max(*max_translation_m, difference.translation().norm());
    *max_rotation_rad = std::max(*max_rotation_rad, xi.template tail<Pose::kDim - t>().norm());
  }
}

template SyntheticGraph<Pose2> MakeSyntheticGraph<Pose2>(const SyntheticOptions&);
template SyntheticGraph<Pose3> MakeSyntheticGraph<Pose3>(const SyntheticOptions&);
template void RelativeDifference<Pose2>(
    const std::vector<Pose2>&, const std::vector<Pose2>&, int, double*, double*);
template void RelativeDifference<Pose3>(
    const std::vector<Pose3>&, const std::vector<Pose3>&, int, double*, double*);

}  // namespace irrr::testing
