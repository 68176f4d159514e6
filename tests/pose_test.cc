#include "core/pose.h"

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include <catch2/catch.hpp>

#include "tests/rotation_angle.h"

namespace irrr {
namespace {

constexpr double kPi = M_PI;

// Central-difference step: truncation error ~h^2 |r'''| ~ 1e-11 and rounding ~eps |r| / h ~ 1e-9
// for 10 m poses, both far below kJacobianTolerance.
constexpr double kDifferenceStep = 1e-6;
// Analytic vs central-difference Jacobian entries, absolute + relative to the entry: a wrong term
// is off by O(|entry|), while truncation and rounding stay below 1e-8.
constexpr double kJacobianTolerance = 1e-6;
// With 1e4 m coordinates every retracted pose rounds at ulp(1e4) ~ 2e-12 m, i.e. 2e-6 of the
// step, so central differences carry noise of a few 1e-6.
constexpr double kLargeTranslationJacobianTolerance = 1e-5;
// Residual rotations are kept below this so that central differences never straddle the chart's
// discontinuity (SE(2) yaw wraps at +-pi; the SE(3) quaternion flips sign at qw = 0, i.e. at pi).
constexpr double kMaxResidualAngleRad = 2.5;
constexpr int kNumRandomJacobianCases = 2000;   // measurement/from/to triples per pose type
constexpr int kMinCheckedJacobianCases = 1000;  // after skipping residuals beyond the limit
// Products, inverses and trigonometry of 10 m poses round at ~1e-15 relative; 1e-12 leaves room
// for a few dozen operations.
constexpr double kCompositionTolerance = 1e-12;
// Exp/Log round trips of 10 m poses go through V(phi) and its inverse, whose conditioning grows
// towards pi; observed errors stay below 1e-13.
constexpr double kRoundTripTolerance = 1e-10;
// A residual of a perfectly consistent triple is zero up to the rounding of 10 m poses.
constexpr double kZeroResidualTolerance = 1e-12;
// Hand-computed values are typed with 16 significant digits.
constexpr double kHandComputedTolerance = 1e-15;
// Relative accuracy of Exp/Log near the identity: the Taylor branch is exact to double precision
// below 1e-4 rad, so a 1e-9 rad rotation must come back to ~1e-16 relative, not ~1e-7.
constexpr double kSmallAngleRelativeTolerance = 1e-12;

// ---- Per-type helpers (SE(2) uses x, y of a 3D translation and z of a rotation vector) ----

template <class Pose>
Pose MakePose(const Eigen::Vector3d& translation_m, const Eigen::Vector3d& rotation_vector);

template <>
Pose2 MakePose<Pose2>(const Eigen::Vector3d& translation_m,
                      const Eigen::Vector3d& rotation_vector) {
  return Pose2(translation_m.x(), translation_m.y(), rotation_vector.z());
}

// Built with Eigen's AngleAxis, independent of ExpSO3.
template <>
Pose3 MakePose<Pose3>(const Eigen::Vector3d& translation_m,
                      const Eigen::Vector3d& rotation_vector) {
  const double angle_rad = rotation_vector.norm();
  const Eigen::Vector3d axis =
      angle_rad > 0.0 ? Eigen::Vector3d(rotation_vector / angle_rad) : Eigen::Vector3d::UnitZ();
  return Pose3(Eigen::Quaterniond(Eigen::AngleAxisd(angle_rad, axis)), translation_m);
}

template <class Pose>
typename Pose::Tangent MakeTangent(const Eigen::Vector3d& rho, const Eigen::Vector3d& phi);

template <>
Pose2::Tangent MakeTangent<Pose2>(const Eigen::Vector3d& rho, const Eigen::Vector3d& phi) {
  return Pose2::Tangent(rho.x(), rho.y(), phi.z());
}

template <>
Pose3::Tangent MakeTangent<Pose3>(const Eigen::Vector3d& rho, const Eigen::Vector3d& phi) {
  Pose3::Tangent xi;
  xi << rho, phi;
  return xi;
}

// The pose (Exp_SO(phi), rho) that Retract composes on the right.
Pose2 TangentPose(const Pose2::Tangent& delta) { return Pose2(delta(0), delta(1), delta(2)); }
Pose3 TangentPose(const Pose3::Tangent& delta) {
  return Pose3(ExpSO3(delta.tail<3>()), delta.head<3>());
}

// Rotation axes to try: SE(2) has only z; SE(3) the coordinate axes and an oblique one.
template <class Pose>
std::vector<Eigen::Vector3d> TestAxes() {
  if (Pose::kDim == 3) return {Eigen::Vector3d::UnitZ()};
  return {Eigen::Vector3d::UnitX(),
          Eigen::Vector3d::UnitY(),
          Eigen::Vector3d::UnitZ(),
          Eigen::Vector3d(1.0, -2.0, 3.0).normalized()};
}

// Largest entry of the difference of rotation matrices and translations (independent of Log).
template <class Pose>
double PoseDifference(const Pose& a, const Pose& b) {
  return std::max((a.rotation() - b.rotation()).cwiseAbs().maxCoeff(),
                  (a.translation() - b.translation()).cwiseAbs().maxCoeff());
}

Eigen::Vector3d RandomUnitVector(std::mt19937& rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  Eigen::Vector3d v(normal(rng), normal(rng), normal(rng));
  return v.normalized();
}

Eigen::Vector3d RandomVector(std::mt19937& rng, double half_width) {
  std::uniform_real_distribution<double> uniform(-half_width, half_width);
  return Eigen::Vector3d(uniform(rng), uniform(rng), uniform(rng));
}

// Rotation angle uniform in [0, max_angle_rad], random axis (SE(2): random sign).
template <class Pose>
Pose RandomPose(std::mt19937& rng, double translation_m, double max_angle_rad) {
  std::uniform_real_distribution<double> angle(0.0, max_angle_rad);
  return MakePose<Pose>(RandomVector(rng, translation_m), angle(rng) * RandomUnitVector(rng));
}

// Any rotation: SE(2) yaw uniform in [-pi, pi]; SE(3) a uniformly random quaternion of either
// sign (so qw < 0 occurs).
template <class Pose>
Pose FullyRandomPose(std::mt19937& rng, double translation_m);

template <>
Pose2 FullyRandomPose<Pose2>(std::mt19937& rng, double translation_m) {
  std::uniform_real_distribution<double> yaw(-kPi, kPi);
  const Eigen::Vector3d t = RandomVector(rng, translation_m);
  return Pose2(t.x(), t.y(), yaw(rng));
}

template <>
Pose3 FullyRandomPose<Pose3>(std::mt19937& rng, double translation_m) {
  std::normal_distribution<double> normal(0.0, 1.0);
  Eigen::Quaterniond q(normal(rng), normal(rng), normal(rng), normal(rng));
  q.normalize();
  return Pose3(q, RandomVector(rng, translation_m));
}

// Tangent with |phi| uniform in [0, max_angle_rad].
template <class Pose>
typename Pose::Tangent RandomTangent(std::mt19937& rng, double rho_m, double max_angle_rad) {
  std::uniform_real_distribution<double> angle(0.0, max_angle_rad);
  return MakeTangent<Pose>(RandomVector(rng, rho_m), angle(rng) * RandomUnitVector(rng));
}

// Residual difference with the SE(2) yaw compared modulo 2 pi.
Pose2::Tangent ResidualDifference(const Pose2::Tangent& a, const Pose2::Tangent& b) {
  Pose2::Tangent d = a - b;
  d(2) = NormalizeAngle(d(2));
  return d;
}
Pose3::Tangent ResidualDifference(const Pose3::Tangent& a, const Pose3::Tangent& b) {
  return a - b;
}

template <class Pose>
typename Pose::Matrix CentralDifferenceJacobian(const Pose& measurement,
                                                const Pose& from,
                                                const Pose& to,
                                                bool perturb_from) {
  typename Pose::Matrix jacobian;
  for (int k = 0; k < Pose::kDim; ++k) {
    typename Pose::Tangent step = Pose::Tangent::Zero();
    step(k) = kDifferenceStep;
    const Pose from_plus = perturb_from ? from.Retract(step) : from;
    const Pose from_minus = perturb_from ? from.Retract(-step) : from;
    const Pose to_plus = perturb_from ? to : to.Retract(step);
    const Pose to_minus = perturb_from ? to : to.Retract(-step);
    const typename Pose::Tangent r_plus =
        RelativePoseResidual(measurement, from_plus, to_plus, nullptr, nullptr);
    const typename Pose::Tangent r_minus =
        RelativePoseResidual(measurement, from_minus, to_minus, nullptr, nullptr);
    jacobian.col(k) = ResidualDifference(r_plus, r_minus) / (2.0 * kDifferenceStep);
  }
  return jacobian;
}

// Largest |analytic - numeric| / (1 + |analytic|) over the entries.
template <class Matrix>
double JacobianError(const Matrix& analytic, const Matrix& numeric) {
  return ((analytic - numeric).array().abs() / (1.0 + analytic.array().abs())).maxCoeff();
}

// Checks both analytic Jacobians against central differences.
template <class Pose>
void CheckJacobians(const Pose& measurement, const Pose& from, const Pose& to, double tolerance) {
  typename Pose::Matrix J_r_from;
  typename Pose::Matrix J_r_to;
  const typename Pose::Tangent r = RelativePoseResidual(measurement, from, to, &J_r_from, &J_r_to);
  const typename Pose::Tangent r_plain =
      RelativePoseResidual(measurement, from, to, nullptr, nullptr);
  const typename Pose::Matrix numeric_from =
      CentralDifferenceJacobian(measurement, from, to, /*perturb_from=*/true);
  const typename Pose::Matrix numeric_to =
      CentralDifferenceJacobian(measurement, from, to, /*perturb_from=*/false);
  INFO("residual " << r.transpose());
  INFO("J_r_from analytic\n" << J_r_from << "\nnumeric\n" << numeric_from);
  INFO("J_r_to analytic\n" << J_r_to << "\nnumeric\n" << numeric_to);
  CHECK(r == r_plain);
  CHECK(JacobianError(J_r_from, numeric_from) <= tolerance);
  CHECK(JacobianError(J_r_to, numeric_to) <= tolerance);
}

// Twist matrix of xi, for the independent matrix-exponential reference.
Eigen::Matrix3d Hat(const Pose2::Tangent& xi) {
  Eigen::Matrix3d m = Eigen::Matrix3d::Zero();
  m(0, 1) = -xi(2);
  m(1, 0) = xi(2);
  m(0, 2) = xi(0);
  m(1, 2) = xi(1);
  return m;
}
Eigen::Matrix4d Hat(const Pose3::Tangent& xi) {
  Eigen::Matrix4d m = Eigen::Matrix4d::Zero();
  m.topLeftCorner<3, 3>() = Skew(xi.tail<3>());
  m.topRightCorner<3, 1>() = xi.head<3>();
  return m;
}

// Matrix exponential by scaling and squaring of the Taylor series: an independent reference for
// Exp (no closed forms, no small-angle branches).
template <class Matrix>
Matrix MatrixExponential(const Matrix& m) {
  int squarings = 0;
  double norm = m.cwiseAbs().rowwise().sum().maxCoeff();
  while (norm > 0.5) {
    norm *= 0.5;
    ++squarings;
  }
  const Matrix scaled = m / std::pow(2.0, squarings);
  Matrix result = Matrix::Identity();
  Matrix term = Matrix::Identity();
  for (int k = 1; k <= 20; ++k) {  // 0.5^20 / 20! ~ 4e-25
    term = (term * scaled / k).eval();
    result += term;
  }
  for (int i = 0; i < squarings; ++i) result = (result * result).eval();
  return result;
}

template <class Pose>
auto Homogeneous(const Pose& pose) {
  constexpr int n = Pose::kTranslationDim;
  Eigen::Matrix<double, n + 1, n + 1> m = Eigen::Matrix<double, n + 1, n + 1>::Identity();
  m.template topLeftCorner<n, n>() = pose.rotation();
  m.template topRightCorner<n, 1>() = pose.translation();
  return m;
}

// ---- 1. Jacobians on random triples ----

TEMPLATE_TEST_CASE("Residual Jacobians equal central differences on thousands of random triples",
                   "[pose]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  const uint32_t seed = 20240601;
  INFO("seed " << seed << ", " << Pose::kName);
  std::mt19937 rng(seed);
  int num_checked = 0;
  int num_near_measurement = 0;
  for (int i = 0; i < kNumRandomJacobianCases; ++i) {
    INFO("case " << i);
    const Pose measurement = FullyRandomPose<Pose>(rng, 10.0);
    const Pose from = FullyRandomPose<Pose>(rng, 10.0);
    Pose to;
    if (i % 2 == 0) {
      // A residual of moderate size: noise up to 1 rad and 1 m on top of the measurement.
      to = from * measurement * RandomPose<Pose>(rng, 1.0, 1.0);
      ++num_near_measurement;
    } else {
      to = FullyRandomPose<Pose>(rng, 10.0);
      if (RotationAngle(measurement.Inverse() * (from.Inverse() * to)) > kMaxResidualAngleRad) {
        continue;
      }
    }
    ++num_checked;
    CheckJacobians(measurement, from, to, kJacobianTolerance);
  }
  INFO("checked " << num_checked << ", of which near the measurement " << num_near_measurement);
  REQUIRE(num_checked >= kMinCheckedJacobianCases);
  REQUIRE(num_checked > num_near_measurement + kNumRandomJacobianCases / 4);
}

// ---- 2. Jacobians at the edge cases ----

TEMPLATE_TEST_CASE(
    "Residual Jacobians equal central differences at identity, tiny and near-pi "
    "rotations and 1e4 m translations",
    "[pose]",
    Pose2,
    Pose3) {
  using Pose = TestType;
  INFO(Pose::kName);
  const std::vector<double> from_angles = {
      0.0, 1e-9, -1e-9, kPi - 1e-6, -kPi + 1e-6, kPi, -kPi, 0.7};
  // Measurement angles: with from near pi and measurement 2e-6, `to` crosses from +pi to -pi.
  const std::vector<double> measurement_angles = {0.0, 1e-9, 2e-6, -2e-6, kPi - 1e-6, kPi, -1.3};
  const std::vector<double> noise_angles = {0.0, 1e-9, -0.4};
  struct Translations {
    Eigen::Vector3d from, measurement, noise;
    double tolerance;
  };
  const std::vector<Translations> translations = {
      {Eigen::Vector3d::Zero(),
       Eigen::Vector3d::Zero(),
       Eigen::Vector3d::Zero(),
       kJacobianTolerance},
      {Eigen::Vector3d(1.0, -2.0, 0.5),
       Eigen::Vector3d(-0.3, 0.8, 2.0),
       Eigen::Vector3d(0.1, 0.2, -0.3),
       kJacobianTolerance},
      {Eigen::Vector3d(1e4, -1e4, 1e4),
       Eigen::Vector3d(-1e4, 2e4, 1e4),
       Eigen::Vector3d(0.1, 0.2, -0.3),
       kLargeTranslationJacobianTolerance},
  };
  int num_checked = 0;
  for (const Eigen::Vector3d& axis : TestAxes<Pose>()) {
    for (const Translations& t : translations) {
      for (double from_angle : from_angles) {
        for (double measurement_angle : measurement_angles) {
          for (double noise_angle : noise_angles) {
            INFO("axis " << axis.transpose() << " from angle " << from_angle
                         << " measurement angle " << measurement_angle << " noise angle "
                         << noise_angle << " from translation " << t.from.transpose());
            const Pose from = MakePose<Pose>(t.from, from_angle * axis);
            const Pose measurement = MakePose<Pose>(t.measurement, measurement_angle * axis);
            const Pose noise = MakePose<Pose>(t.noise, noise_angle * axis);
            CheckJacobians(measurement, from, Pose(from * measurement * noise), t.tolerance);
            // The residual's own rotation near zero and near the noise, with `to` given directly.
            CheckJacobians(measurement, from, from * measurement, t.tolerance);
            ++num_checked;
          }
        }
      }
    }
  }
  // Every pose at the identity.
  CheckJacobians(Pose(), Pose(), Pose(), kJacobianTolerance);
  // `to` itself at exactly pi, from at identity, residual zero.
  CheckJacobians(MakePose<Pose>(Eigen::Vector3d(1.0, 2.0, 3.0), kPi * TestAxes<Pose>().back()),
                 Pose(),
                 MakePose<Pose>(Eigen::Vector3d(1.0, 2.0, 3.0), kPi * TestAxes<Pose>().back()),
                 kJacobianTolerance);
  REQUIRE(num_checked > 0);
}

// ---- 3. Exp / Log ----

TEMPLATE_TEST_CASE("Exp(Log(T)) == T and Log(Exp(xi)) == xi for random poses and tangents",
                   "[pose]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  const uint32_t seed = 7;
  INFO("seed " << seed << ", " << Pose::kName);
  std::mt19937 rng(seed);
  for (int i = 0; i < 1000; ++i) {
    INFO("case " << i);
    const Pose pose = FullyRandomPose<Pose>(rng, 10.0);
    CHECK(PoseDifference(Pose::Exp(pose.Log()), pose) <= kRoundTripTolerance);
    CHECK(RotationAngle(pose) <= kPi);
    const typename Pose::Tangent xi = RandomTangent<Pose>(rng, 10.0, kPi - 1e-6);
    CHECK((Pose::Exp(xi).Log() - xi).cwiseAbs().maxCoeff() <= kRoundTripTolerance);
  }
}

TEMPLATE_TEST_CASE("Exp agrees with the matrix exponential of the twist", "[pose]", Pose2, Pose3) {
  using Pose = TestType;
  const uint32_t seed = 8;
  INFO("seed " << seed << ", " << Pose::kName);
  std::mt19937 rng(seed);
  for (int i = 0; i < 200; ++i) {
    INFO("case " << i);
    const typename Pose::Tangent xi = RandomTangent<Pose>(rng, 10.0, kPi);
    const auto expected = MatrixExponential(Hat(xi));
    CHECK((Homogeneous(Pose::Exp(xi)) - expected).cwiseAbs().maxCoeff() <= kRoundTripTolerance);
  }
}

TEMPLATE_TEST_CASE("Exp and Log round-trip at identity, 1e-9 rad and near pi",
                   "[pose]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  INFO(Pose::kName);
  const std::vector<Eigen::Vector3d> rhos = {
      Eigen::Vector3d::Zero(), Eigen::Vector3d(1.0, -2.0, 3.0), Eigen::Vector3d(1e4, 1e3, -1e4)};
  // Log(Exp(xi)) == xi only where the angle is below pi (Log returns |phi| <= pi).
  const std::vector<double> tangent_angles = {0.0, 1e-9, -1e-9, kPi - 1e-6, -(kPi - 1e-6)};
  // Poses may also sit at exactly +-pi.
  std::vector<double> pose_angles = tangent_angles;
  pose_angles.push_back(kPi);
  pose_angles.push_back(-kPi);
  for (const Eigen::Vector3d& axis : TestAxes<Pose>()) {
    for (const Eigen::Vector3d& rho : rhos) {
      // Large translations scale the rounding of the translation part.
      const double tolerance = kRoundTripTolerance * std::max(1.0, rho.norm());
      for (double angle : tangent_angles) {
        INFO("axis " << axis.transpose() << " rho " << rho.transpose() << " angle " << angle);
        const typename Pose::Tangent xi = MakeTangent<Pose>(rho, angle * axis);
        const typename Pose::Tangent back = Pose::Exp(xi).Log();
        CHECK((back - xi).cwiseAbs().maxCoeff() <= tolerance);
        // Tiny rotations come back with full relative precision.
        if (angle != 0.0 && std::abs(angle) < 1e-6) {
          CHECK((back.template tail<Pose::kDim - Pose::kTranslationDim>() -
                 xi.template tail<Pose::kDim - Pose::kTranslationDim>())
                    .norm() <= kSmallAngleRelativeTolerance * std::abs(angle));
        }
      }
      for (double angle : pose_angles) {
        INFO("axis " << axis.transpose() << " t " << rho.transpose() << " angle " << angle);
        const Pose pose = MakePose<Pose>(rho, angle * axis);
        CHECK(PoseDifference(Pose::Exp(pose.Log()), pose) <= tolerance);
        CHECK(pose.Log().template tail<Pose::kDim - Pose::kTranslationDim>().norm() <= kPi);
      }
    }
  }
  // The identity maps to exactly zero and back.
  CHECK(Pose().Log() == Pose::Tangent::Zero());
  CHECK(PoseDifference(Pose::Exp(Pose::Tangent::Zero()), Pose()) == 0.0);
}

TEST_CASE("Pose3 Exp(Log(T)) == T across the quaternion sign flip at qw = 0", "[pose]") {
  const Eigen::Vector3d axis = Eigen::Vector3d(1.0, -2.0, 3.0).normalized();
  const Eigen::Vector3d translation(4.0, -5.0, 6.0);
  for (double w : {0.0, 1e-9, -1e-9, 1e-3, -1e-3}) {
    INFO("qw " << w);
    const double s = std::sqrt(1.0 - w * w);
    const Pose3 pose(Eigen::Quaterniond(w, s * axis.x(), s * axis.y(), s * axis.z()), translation);
    const Pose3 negated(Eigen::Quaterniond(-w, -s * axis.x(), -s * axis.y(), -s * axis.z()),
                        translation);
    CHECK(PoseDifference(Pose3::Exp(pose.Log()), pose) <= kRoundTripTolerance);
    CHECK(PoseDifference(Pose3::Exp(negated.Log()), pose) <= kRoundTripTolerance);
    CHECK(pose.Log().tail<3>().norm() <= kPi);
  }
}

// ---- 4. Group axioms ----

TEMPLATE_TEST_CASE("Random poses satisfy the group axioms and Retract composes on the right",
                   "[pose]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  const uint32_t seed = 11;
  INFO("seed " << seed << ", " << Pose::kName);
  std::mt19937 rng(seed);
  const Pose identity;
  for (int i = 0; i < 1000; ++i) {
    INFO("case " << i);
    const Pose a = FullyRandomPose<Pose>(rng, 10.0);
    const Pose b = FullyRandomPose<Pose>(rng, 10.0);
    const Pose c = FullyRandomPose<Pose>(rng, 10.0);
    const typename Pose::Tangent delta = RandomTangent<Pose>(rng, 10.0, kPi);
    const typename Pose::Translation point =
        RandomVector(rng, 10.0).template head<Pose::kTranslationDim>();

    CHECK(PoseDifference(a * a.Inverse(), identity) <= kCompositionTolerance);
    CHECK(PoseDifference(a.Inverse() * a, identity) <= kCompositionTolerance);
    CHECK(PoseDifference((a * b) * c, a * (b * c)) <= kCompositionTolerance);
    CHECK(PoseDifference(a * identity, a) <= kCompositionTolerance);
    CHECK(PoseDifference(identity * a, a) <= kCompositionTolerance);
    CHECK(((a * b) * point - a * (b * point)).cwiseAbs().maxCoeff() <= kCompositionTolerance);
    CHECK((a.Inverse() * (a * point) - point).cwiseAbs().maxCoeff() <= kCompositionTolerance);
    CHECK((a * point - (a.rotation() * point + a.translation())).cwiseAbs().maxCoeff() <=
          kCompositionTolerance);

    // x (+) [rho; phi] = x * Pose(Exp_SO(phi), rho): the translation moves by R * rho.
    const Pose retracted = a.Retract(delta);
    CHECK(PoseDifference(retracted, a * TangentPose(delta)) <= kCompositionTolerance);
    CHECK((retracted.translation() -
           (a.translation() + a.rotation() * delta.template head<Pose::kTranslationDim>()))
              .cwiseAbs()
              .maxCoeff() <= kCompositionTolerance);
    CHECK(PoseDifference(a.Retract(Pose::Tangent::Zero()), a) <= kCompositionTolerance);

    // x * Exp(Log(x^-1 * y)) == y.
    CHECK(PoseDifference(a * Pose::Exp((a.Inverse() * b).Log()), b) <= kRoundTripTolerance);
  }
}

// ---- 5. ErrorVector and NormalizeAngle ----

TEST_CASE("A Pose3 with qw < 0 has the same error vector as its negated quaternion", "[pose]") {
  const uint32_t seed = 12;
  INFO("seed " << seed);
  std::mt19937 rng(seed);
  int num_negative = 0;
  for (int i = 0; i < 1000; ++i) {
    INFO("case " << i);
    const Pose3 pose = FullyRandomPose<Pose3>(rng, 10.0);
    const Eigen::Quaterniond& q = pose.quaternion();
    const Pose3 negated(Eigen::Quaterniond(-q.w(), -q.x(), -q.y(), -q.z()), pose.translation());
    CHECK(pose.ErrorVector() == negated.ErrorVector());
    CHECK(pose.ErrorVector().head<3>() == pose.translation());
    // The canonical half has qw >= 0: the vector part is q.vec() or -q.vec().
    const Eigen::Vector3d expected_vec = q.w() < 0.0 ? Eigen::Vector3d(-q.vec()) : q.vec();
    CHECK(pose.ErrorVector().tail<3>() == expected_vec);
    if (q.w() < 0.0) ++num_negative;
  }
  REQUIRE(num_negative > 100);
  // A hand-picked case: 90 degrees about z with qw < 0.
  const double h = std::sqrt(0.5);
  const Pose3 pose(Eigen::Quaterniond(-h, 0.0, 0.0, -h), Eigen::Vector3d(1.0, 2.0, 3.0));
  Pose3::Tangent expected;
  expected << 1.0, 2.0, 3.0, 0.0, 0.0, h;
  CHECK(pose.ErrorVector() == expected);
}

TEST_CASE("NormalizeAngle keeps yaw in [-pi, pi]", "[pose]") {
  CHECK(std::abs(NormalizeAngle(3.0 * kPi)) == Approx(kPi).epsilon(kHandComputedTolerance));
  CHECK(std::abs(NormalizeAngle(-3.0 * kPi)) == Approx(kPi).epsilon(kHandComputedTolerance));
  CHECK(NormalizeAngle(-7.0) == Approx(-7.0 + 2.0 * kPi).epsilon(kHandComputedTolerance));
  CHECK(NormalizeAngle(7.0) == Approx(7.0 - 2.0 * kPi).epsilon(kHandComputedTolerance));
  CHECK(NormalizeAngle(kPi) == kPi);
  CHECK(NormalizeAngle(-kPi) == -kPi);
  CHECK(NormalizeAngle(0.0) == 0.0);
  CHECK(NormalizeAngle(1e-9) == 1e-9);
  CHECK(NormalizeAngle(kPi - 1e-6) == kPi - 1e-6);
  CHECK(NormalizeAngle(kPi + 1e-6) == Approx(-kPi + 1e-6).epsilon(kHandComputedTolerance));

  const uint32_t seed = 13;
  INFO("seed " << seed);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> angle(-1e3, 1e3);
  for (int i = 0; i < 1000; ++i) {
    const double a = angle(rng);
    INFO("angle " << a);
    const double n = NormalizeAngle(a);
    CHECK(n >= -kPi);
    CHECK(n <= kPi);
    // Same direction: a - n is a multiple of 2 pi.
    CHECK(std::abs(std::remainder(a - n, 2.0 * kPi)) <= kCompositionTolerance);
    // Pose2 stores yaw normalized and its error vector reports it.
    const Pose2 pose(1.0, 2.0, a);
    CHECK(pose.yaw_rad() == n);
    CHECK(pose.ErrorVector() == Pose2::Tangent(1.0, 2.0, n));
  }
}

// ---- 6. The residual's value ----

TEMPLATE_TEST_CASE(
    "The residual is zero when to == from * measurement and otherwise equals the "
    "error vector of measurement^-1 * from^-1 * to",
    "[pose]",
    Pose2,
    Pose3) {
  using Pose = TestType;
  const uint32_t seed = 14;
  INFO("seed " << seed << ", " << Pose::kName);
  std::mt19937 rng(seed);
  for (int i = 0; i < 1000; ++i) {
    INFO("case " << i);
    const Pose measurement = FullyRandomPose<Pose>(rng, 10.0);
    const Pose from = FullyRandomPose<Pose>(rng, 10.0);
    const Pose to = FullyRandomPose<Pose>(rng, 10.0);
    CHECK(RelativePoseResidual(measurement, from, Pose(from * measurement), nullptr, nullptr)
              .cwiseAbs()
              .maxCoeff() <= kZeroResidualTolerance);
    const typename Pose::Tangent r = RelativePoseResidual(measurement, from, to, nullptr, nullptr);
    const typename Pose::Tangent expected =
        (measurement.Inverse() * (from.Inverse() * to)).ErrorVector();
    CHECK(ResidualDifference(r, expected).cwiseAbs().maxCoeff() <= kCompositionTolerance);
  }
}

// ---- 7. SO(3) ----

TEST_CASE("ExpSO3 and LogSO3 round-trip, including 1e-9 rad and near pi", "[pose]") {
  const uint32_t seed = 15;
  INFO("seed " << seed);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> angle(0.0, kPi - 1e-6);
  std::vector<Eigen::Vector3d> rotation_vectors;
  for (int i = 0; i < 1000; ++i) rotation_vectors.push_back(angle(rng) * RandomUnitVector(rng));
  for (const Eigen::Vector3d& axis : TestAxes<Pose3>()) {
    for (double a : {0.0, 1e-9, -1e-9, 1e-5, 1e-4, 2e-4, kPi - 1e-6, -(kPi - 1e-6)}) {
      rotation_vectors.push_back(a * axis);
    }
  }
  for (const Eigen::Vector3d& phi : rotation_vectors) {
    INFO("phi " << phi.transpose());
    const Eigen::Quaterniond q = ExpSO3(phi);
    CHECK(std::abs(q.norm() - 1.0) <= kCompositionTolerance);
    CHECK(q.w() >= 0.0);  // |phi| <= pi
    // Against Eigen's AngleAxis.
    const double theta = phi.norm();
    const Eigen::Matrix3d expected = theta > 0.0
                                         ? Eigen::AngleAxisd(theta, phi / theta).toRotationMatrix()
                                         : Eigen::Matrix3d::Identity();
    CHECK((q.toRotationMatrix() - expected).cwiseAbs().maxCoeff() <= kCompositionTolerance);
    const Eigen::Vector3d back = LogSO3(q);
    CHECK((back - phi).norm() <= kCompositionTolerance);
    // Small rotations keep their full relative precision (no 1e-8 floor from a closed form).
    if (theta < 1e-3) CHECK((back - phi).norm() <= kSmallAngleRelativeTolerance * theta);
    // Both signs of the quaternion give the same rotation vector.
    const Eigen::Quaterniond negated(-q.w(), -q.x(), -q.y(), -q.z());
    CHECK((LogSO3(negated) - back).norm() <= kCompositionTolerance);
  }
  // Exactly pi: the rotation vector is +-pi * axis; either is the same rotation.
  for (const Eigen::Vector3d& axis : TestAxes<Pose3>()) {
    INFO("axis " << axis.transpose());
    const Eigen::Quaterniond q(0.0, axis.x(), axis.y(), axis.z());
    const Eigen::Vector3d phi = LogSO3(q);
    CHECK(std::abs(phi.norm() - kPi) <= kCompositionTolerance);
    CHECK(std::abs(std::abs(phi.dot(axis)) - kPi) <= kCompositionTolerance);
    CHECK((ExpSO3(phi).toRotationMatrix() - q.toRotationMatrix()).cwiseAbs().maxCoeff() <=
          kCompositionTolerance);
  }
}

TEST_CASE("Skew(v) * w equals the cross product v x w", "[pose]") {
  const uint32_t seed = 16;
  INFO("seed " << seed);
  std::mt19937 rng(seed);
  for (int i = 0; i < 100; ++i) {
    const Eigen::Vector3d v = RandomVector(rng, 10.0);
    const Eigen::Vector3d w = RandomVector(rng, 10.0);
    CHECK((Skew(v) * w - v.cross(w)).cwiseAbs().maxCoeff() <= kCompositionTolerance);
    CHECK(Skew(v).transpose() == -Skew(v));
  }
}

// ---- 8. Hand-computed residuals ----

TEST_CASE("The SE(2) residual matches hand-computed values", "[pose]") {
  const Pose2 from(1.0, 2.0, kPi / 2.0);
  const Pose2 to(1.0, 3.0, kPi / 2.0);
  // from^-1 * to: Ri' (tj - ti) = R(-pi/2) (0, 1) = (1, 0), yaw 0, which is the measurement:
  // the residual is zero (up to cos(pi/2) = 6e-17 in double).
  Pose2::Matrix J_r_from;
  Pose2::Matrix J_r_to;
  const Pose2::Tangent zero =
      RelativePoseResidual(Pose2(1.0, 0.0, 0.0), from, to, nullptr, nullptr);
  CHECK(zero.cwiseAbs().maxCoeff() <= kHandComputedTolerance);

  // measurement (0.5, 0, 0.1): r_t = R(-0.1) ((1, 0) - (0.5, 0)) = (0.5 cos 0.1, -0.5 sin 0.1)
  //   = (0.4975020826390129, -0.04991670832341408), r_yaw = pi/2 - pi/2 - 0.1 = -0.1.
  // J_r_from = [-R(-0.1), -R(-0.1) S (1, 0)] with S (1, 0) = (0, 1), R(-0.1) (0, 1) =
  //   (sin 0.1, cos 0.1) = (0.09983341664682815, 0.9950041652780258); last row (0, 0, -1).
  // J_r_to = [R(-0.1) R(-pi/2) R(pi/2) = R(-0.1), 0; 0 0 1].
  const Pose2 measurement(0.5, 0.0, 0.1);
  const Pose2::Tangent r = RelativePoseResidual(measurement, from, to, &J_r_from, &J_r_to);
  const double c = 0.9950041652780258;   // cos 0.1
  const double s = 0.09983341664682815;  // sin 0.1
  CHECK(r(0) == Approx(0.4975020826390129).margin(kHandComputedTolerance));
  CHECK(r(1) == Approx(-0.04991670832341408).margin(kHandComputedTolerance));
  CHECK(r(2) == Approx(-0.1).margin(kHandComputedTolerance));
  Pose2::Matrix expected_from;
  expected_from << -c, -s, -s, s, -c, -c, 0.0, 0.0, -1.0;
  Pose2::Matrix expected_to;
  expected_to << c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0;
  INFO("J_r_from\n" << J_r_from << "\nJ_r_to\n" << J_r_to);
  CHECK((J_r_from - expected_from).cwiseAbs().maxCoeff() <= kHandComputedTolerance);
  CHECK((J_r_to - expected_to).cwiseAbs().maxCoeff() <= kHandComputedTolerance);
}

TEST_CASE("The SE(3) residual matches hand-computed values", "[pose]") {
  // from = identity, to = 90 degrees about z at (1, 0, 0), measurement = identity:
  // r = [1, 0, 0, 0, 0, sin(pi/4)].
  const double h = std::sqrt(0.5);
  const Pose3 to(Eigen::Quaterniond(h, 0.0, 0.0, h), Eigen::Vector3d(1.0, 0.0, 0.0));
  Pose3::Tangent expected;
  expected << 1.0, 0.0, 0.0, 0.0, 0.0, h;
  const Pose3::Tangent r = RelativePoseResidual(Pose3(), Pose3(), to, nullptr, nullptr);
  CHECK((r - expected).cwiseAbs().maxCoeff() <= kHandComputedTolerance);
  // The same `to` written with qw < 0 gives the same residual.
  const Pose3 to_negated(Eigen::Quaterniond(-h, 0.0, 0.0, -h), Eigen::Vector3d(1.0, 0.0, 0.0));
  CHECK((RelativePoseResidual(Pose3(), Pose3(), to_negated, nullptr, nullptr) - expected)
            .cwiseAbs()
            .maxCoeff() <= kHandComputedTolerance);
}

}  // namespace
}  // namespace irrr

namespace irrr {
namespace {

// Conjugation by T moves a perturbation across T: Log(T Exp(xi) T^-1) = Ad(T) xi + O(|xi|^2).
// With |xi| = 1e-6 and 10 m poses the second-order term is ~1e-11.
constexpr double kFirstOrderTolerance = 1e-9;

TEMPLATE_TEST_CASE("Adjoint moves a small perturbation across a pose", "[pose]", Pose2, Pose3) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  for (int k = 0; k < 200; ++k) {
    typename TestType::Tangent xi;
    typename TestType::Tangent small;
    for (int i = 0; i < TestType::kDim; ++i) {
      xi(i) = 10.0 * uniform(rng);
      small(i) = 1e-6 * uniform(rng);
    }
    const TestType T = TestType::Exp(xi);
    const typename TestType::Tangent moved = (T * TestType::Exp(small) * T.Inverse()).Log();
    CHECK((moved - Adjoint(T) * small).norm() < kFirstOrderTolerance);
  }
}

TEMPLATE_TEST_CASE("TangentOfErrorVector reads a small error in g2o's chart as a tangent",
                   "[pose]",
                   Pose2,
                   Pose3) {
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  for (int k = 0; k < 200; ++k) {
    typename TestType::Tangent small;
    for (int i = 0; i < TestType::kDim; ++i) small(i) = 1e-6 * uniform(rng);
    const typename TestType::Tangent chart = TestType::Exp(small).ErrorVector();
    CHECK((TangentOfErrorVector<TestType>() * chart - small).norm() < kFirstOrderTolerance);
  }
}

}  // namespace
}  // namespace irrr
