#include "core/pose.h"

#include <cmath>

namespace irrr {
namespace {

// Below this rotation angle the closed forms of Exp/Log divide by ~0; their Taylor series are
// used instead (second-order terms keep them exact to double precision at 1e-4 rad and below).
constexpr double kSmallAngleRad = 1e-4;

// The 2D generator of rotations: S * [x, y] = [-y, x].
Eigen::Matrix2d RotationGenerator2() {
  Eigen::Matrix2d s;
  s << 0.0, -1.0, 1.0, 0.0;
  return s;
}

// V(theta) of the SE(2) exponential, t = V * rho: [[a, -b], [b, a]], a = sin(t)/t,
// b = (1 - cos(t))/t.
void Se2VCoefficients(double theta, double* a, double* b) {
  if (std::abs(theta) < kSmallAngleRad) {
    const double theta2 = theta * theta;
    *a = 1.0 - theta2 / 6.0;
    *b = theta / 2.0 - theta * theta2 / 24.0;
  } else {
    *a = std::sin(theta) / theta;
    *b = (1.0 - std::cos(theta)) / theta;
  }
}

// V(phi) of the SE(3) exponential, t = V * rho.
Eigen::Matrix3d Se3V(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d phi_x = Skew(phi);
  double c1;  // (1 - cos t) / t^2
  double c2;  // (t - sin t) / t^3
  if (theta < kSmallAngleRad) {
    const double theta2 = theta * theta;
    c1 = 0.5 - theta2 / 24.0;
    c2 = 1.0 / 6.0 - theta2 / 120.0;
  } else {
    const double theta2 = theta * theta;
    c1 = (1.0 - std::cos(theta)) / theta2;
    c2 = (theta - std::sin(theta)) / (theta2 * theta);
  }
  return Eigen::Matrix3d::Identity() + c1 * phi_x + c2 * phi_x * phi_x;
}

// V(phi)^-1 = I - [phi]x / 2 + c * [phi]x^2, c = (1 - t sin t / (2 (1 - cos t))) / t^2.
Eigen::Matrix3d Se3VInverse(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  const Eigen::Matrix3d phi_x = Skew(phi);
  double c;
  if (theta < kSmallAngleRad) {
    c = 1.0 / 12.0 + theta * theta / 720.0;
  } else {
    const double half = 0.5 * theta;
    // t sin t / (2 (1 - cos t)) = (t / 2) * cot(t / 2), stable up to t -> 2 pi.
    c = (1.0 - half * std::cos(half) / std::sin(half)) / (theta * theta);
  }
  return Eigen::Matrix3d::Identity() - 0.5 * phi_x + c * phi_x * phi_x;
}

// Quaternion with qw >= 0 (q and -q are the same rotation; g2o's chart uses this half).
Eigen::Quaterniond CanonicalQuaternion(const Eigen::Quaterniond& q) {
  return q.w() < 0.0 ? Eigen::Quaterniond(-q.w(), -q.x(), -q.y(), -q.z()) : q;
}

}  // namespace

double NormalizeAngle(double angle_rad) {
  // remainder() returns its argument unchanged in [-pi, pi] (quotient 0, ties to even): the test
  // only skips the call, which was 4% of iRRR's time.
  if (std::abs(angle_rad) <= M_PI) return angle_rad;
  return std::remainder(angle_rad, 2.0 * M_PI);
}

Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

Eigen::Quaterniond ExpSO3(const Eigen::Vector3d& phi) {
  const double theta = phi.norm();
  double w;
  double k;  // sin(t/2) / t
  if (theta < kSmallAngleRad) {
    const double theta2 = theta * theta;
    w = 1.0 - theta2 / 8.0;
    k = 0.5 - theta2 / 48.0;
  } else {
    w = std::cos(0.5 * theta);
    k = std::sin(0.5 * theta) / theta;
  }
  Eigen::Quaterniond q(w, k * phi.x(), k * phi.y(), k * phi.z());
  q.normalize();
  return q;
}

Eigen::Vector3d LogSO3(const Eigen::Quaterniond& q_in) {
  const Eigen::Quaterniond q = CanonicalQuaternion(q_in);
  const Eigen::Vector3d v = q.vec();
  const double n = v.norm();
  // phi = 2 atan2(|v|, w) * v / |v|; the series 2 (1 - n^2 / (3 w^2)) / w avoids 0/0.
  if (n < kSmallAngleRad) {
    return (2.0 / q.w()) * (1.0 - n * n / (3.0 * q.w() * q.w())) * v;
  }
  return (2.0 * std::atan2(n, q.w()) / n) * v;
}

// ---- SE(2) ----

Pose2::Pose2(double x_m, double y_m, double yaw_rad)
    : translation_(x_m, y_m),
      yaw_rad_(NormalizeAngle(yaw_rad)),
      cos_yaw_(std::cos(yaw_rad_)),
      sin_yaw_(std::sin(yaw_rad_)) {}

Pose2::Pose2(const Translation& translation, double yaw_rad)
    : translation_(translation),
      yaw_rad_(NormalizeAngle(yaw_rad)),
      cos_yaw_(std::cos(yaw_rad_)),
      sin_yaw_(std::sin(yaw_rad_)) {}

Pose2 Pose2::operator*(const Pose2& rhs) const {
  return Pose2(translation_ + rotation() * rhs.translation_, yaw_rad_ + rhs.yaw_rad_);
}

Pose2::Translation Pose2::operator*(const Translation& point) const {
  return translation_ + rotation() * point;
}

Pose2 Pose2::Inverse() const { return Pose2(-(rotation().transpose() * translation_), -yaw_rad_); }

Pose2 Pose2::Exp(const Tangent& xi) {
  double a;
  double b;
  Se2VCoefficients(xi(2), &a, &b);
  const Translation t(a * xi(0) - b * xi(1), b * xi(0) + a * xi(1));
  return Pose2(t, xi(2));
}

Pose2::Tangent Pose2::Log() const {
  double a;
  double b;
  Se2VCoefficients(yaw_rad_, &a, &b);
  const double inv_det = 1.0 / (a * a + b * b);
  Tangent xi;
  xi(0) = inv_det * (a * translation_.x() + b * translation_.y());
  xi(1) = inv_det * (-b * translation_.x() + a * translation_.y());
  xi(2) = yaw_rad_;
  return xi;
}

Pose2 Pose2::Retract(const Tangent& delta) const {
  return Pose2(translation_ + rotation() * delta.head<2>(), yaw_rad_ + delta(2));
}

Pose2::Tangent Pose2::ErrorVector() const {
  return Tangent(translation_.x(), translation_.y(), yaw_rad_);
}

bool Pose2::IsFinite() const { return translation_.allFinite() && std::isfinite(yaw_rad_); }

// r = [Rz' (Ri' (tj - ti) - tz); wrap(yaw_j - yaw_i - yaw_z)]. With the retraction
// t <- t + R rho, yaw <- yaw + phi:
//   dr_t/drho_i = -Rz',  dr_t/dphi_i = -Rz' S Ri' (tj - ti),  dr_yaw/dphi_i = -1,
//   dr_t/drho_j = Rz' Ri' Rj,                                 dr_yaw/dphi_j = +1.
template <>
Pose2::Tangent RelativePoseResidual<Pose2>(const Pose2& measurement,
                                           const Pose2& from,
                                           const Pose2& to,
                                           Pose2::Matrix* J_r_from,
                                           Pose2::Matrix* J_r_to) {
  const Eigen::Matrix2d from_R = from.rotation();
  const Eigen::Matrix2d measurement_Rt = measurement.rotation().transpose();
  const Eigen::Vector2d from_t_to = from_R.transpose() * (to.translation() - from.translation());
  Pose2::Tangent r;
  r.head<2>() = measurement_Rt * (from_t_to - measurement.translation());
  r(2) = NormalizeAngle(to.yaw_rad() - from.yaw_rad() - measurement.yaw_rad());
  if (J_r_from != nullptr) {
    J_r_from->setZero();
    J_r_from->topLeftCorner<2, 2>() = -measurement_Rt;
    J_r_from->topRightCorner<2, 1>() = -measurement_Rt * RotationGenerator2() * from_t_to;
    (*J_r_from)(2, 2) = -1.0;
  }
  if (J_r_to != nullptr) {
    J_r_to->setZero();
    J_r_to->topLeftCorner<2, 2>() = measurement_Rt * from_R.transpose() * to.rotation();
    (*J_r_to)(2, 2) = 1.0;
  }
  return r;
}

// ---- SE(3) ----

Pose3::Pose3(const Eigen::Quaterniond& rotation, const Translation& translation)
    : rotation_(rotation), translation_(translation) {}

Pose3 Pose3::operator*(const Pose3& rhs) const {
  Eigen::Quaterniond q = rotation_ * rhs.rotation_;
  q.normalize();  // keeps long compositions on the unit sphere
  return Pose3(q, translation_ + rotation_ * rhs.translation_);
}

Pose3::Translation Pose3::operator*(const Translation& point) const {
  return translation_ + rotation_ * point;
}

Pose3 Pose3::Inverse() const {
  const Eigen::Quaterniond q = rotation_.conjugate();
  return Pose3(q, -(q * translation_));
}

Pose3 Pose3::Exp(const Tangent& xi) {
  const Eigen::Vector3d phi = xi.tail<3>();
  return Pose3(ExpSO3(phi), Se3V(phi) * xi.head<3>());
}

Pose3::Tangent Pose3::Log() const {
  const Eigen::Vector3d phi = LogSO3(rotation_);
  Tangent xi;
  xi.head<3>() = Se3VInverse(phi) * translation_;
  xi.tail<3>() = phi;
  return xi;
}

Pose3 Pose3::Retract(const Tangent& delta) const {
  Eigen::Quaterniond q = rotation_ * ExpSO3(delta.tail<3>());
  q.normalize();
  return Pose3(q, translation_ + rotation_ * delta.head<3>());
}

Pose3::Tangent Pose3::ErrorVector() const {
  const Eigen::Quaterniond q = CanonicalQuaternion(rotation_);
  Tangent e;
  e.head<3>() = translation_;
  e.tail<3>() = q.vec();
  return e;
}

bool Pose3::IsFinite() const { return translation_.allFinite() && rotation_.coeffs().allFinite(); }

// r = [t_d; qv_d] of d = Z^-1 * Xi^-1 * Xj, with q_d = (w, v), w >= 0. Perturbing
// Xj <- Xj * P(rho, phi) gives d <- d * P, so
//   dr_t/drho_j = R_d,  dr_qv/dphi_j = (w I + [v]x) / 2.
// Perturbing Xi <- Xi * P gives d <- (Z^-1 P^-1 Z) * d; with psi = Rz' phi this is, to first order,
//   dr_t/drho_i = -Rz',  dr_t/dphi_i = [t_d]x Rz' + Rz' [tz]x,  dr_qv/dphi_i = -(w I - [v]x) Rz'
//   / 2.
template <>
Pose3::Tangent RelativePoseResidual<Pose3>(const Pose3& measurement,
                                           const Pose3& from,
                                           const Pose3& to,
                                           Pose3::Matrix* J_r_from,
                                           Pose3::Matrix* J_r_to) {
  const Pose3 delta = measurement.Inverse() * (from.Inverse() * to);
  const Eigen::Quaterniond q = CanonicalQuaternion(delta.quaternion());
  Pose3::Tangent r;
  r.head<3>() = delta.translation();
  r.tail<3>() = q.vec();
  const Eigen::Matrix3d w_identity = q.w() * Eigen::Matrix3d::Identity();
  const Eigen::Matrix3d v_x = Skew(q.vec());
  if (J_r_from != nullptr) {
    const Eigen::Matrix3d measurement_Rt = measurement.rotation().transpose();
    J_r_from->setZero();
    J_r_from->topLeftCorner<3, 3>() = -measurement_Rt;
    J_r_from->topRightCorner<3, 3>() = Skew(delta.translation()) * measurement_Rt +
                                       measurement_Rt * Skew(measurement.translation());
    J_r_from->bottomRightCorner<3, 3>() = -0.5 * (w_identity - v_x) * measurement_Rt;
  }
  if (J_r_to != nullptr) {
    J_r_to->setZero();
    J_r_to->topLeftCorner<3, 3>() = delta.rotation();
    J_r_to->bottomRightCorner<3, 3>() = 0.5 * (w_identity + v_x);
  }
  return r;
}

template <>
Pose2::Matrix Adjoint<Pose2>(const Pose2& pose) {
  Pose2::Matrix adjoint = Pose2::Matrix::Identity();
  adjoint.topLeftCorner<2, 2>() = pose.rotation();
  adjoint(0, 2) = pose.translation().y();
  adjoint(1, 2) = -pose.translation().x();
  return adjoint;
}

template <>
Pose3::Matrix Adjoint<Pose3>(const Pose3& pose) {
  Pose3::Matrix adjoint = Pose3::Matrix::Zero();
  const Eigen::Matrix3d rotation = pose.rotation();
  adjoint.topLeftCorner<3, 3>() = rotation;
  adjoint.bottomRightCorner<3, 3>() = rotation;
  adjoint.topRightCorner<3, 3>() = Skew(pose.translation()) * rotation;
  return adjoint;
}

template <>
Pose2::Matrix TangentOfErrorVector<Pose2>() {
  return Pose2::Matrix::Identity();
}

template <>
Pose3::Matrix TangentOfErrorVector<Pose3>() {
  Pose3::Matrix m = Pose3::Matrix::Identity();
  m.bottomRightCorner<3, 3>() *= 2.0;
  return m;
}

}  // namespace irrr
