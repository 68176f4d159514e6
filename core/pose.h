#ifndef IRRR_CORE_POSE_H_
#define IRRR_CORE_POSE_H_

// Rigid-body poses in SE(2) and SE(3) with one shared interface, so that the pose graph, the
// optimizer and iRRR are written once as templates over the pose type.
//
// A pose `a_T_b` maps points from frame b to frame a: p_a = a_T_b * p_b. Composition
// `a_T_c = a_T_b * b_T_c`.
//
// Three maps between a pose and its tangent vector (dimension kDim) are used:
//  - Exp / Log: the Lie group exponential and logarithm, xi = [rho; phi] (translation part first).
//  - Retract: the optimizer's update, x (+) [rho; phi] = x * Pose(Exp_SO(phi), rho), i.e. the
//    translation moves by R * rho and the rotation by Exp_SO(phi), both in the body frame.
//  - ErrorVector: g2o's error chart, used for residuals so that chi2 values and information
//    matrices mean the same as in g2o files: [x, y, yaw] in SE(2), [x, y, z, qx, qy, qz] (unit
//    quaternion with qw >= 0) in SE(3).

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace irrr {

// SE(2): translation in metres, yaw in radians kept in [-pi, pi].
class Pose2 {
 public:
  static constexpr int kDim = 3;             // tangent, residual and information dimension
  static constexpr int kTranslationDim = 2;  // dimension of the translation
  static constexpr const char* kName = "SE(2)";
  using Tangent = Eigen::Matrix<double, kDim, 1>;
  using Matrix = Eigen::Matrix<double, kDim, kDim>;
  using Translation = Eigen::Vector2d;
  using Rotation = Eigen::Matrix2d;

  Pose2() = default;
  Pose2(double x_m, double y_m, double yaw_rad);
  Pose2(const Translation& translation, double yaw_rad);

  const Translation& translation() const { return translation_; }
  double yaw_rad() const { return yaw_rad_; }
  Rotation rotation() const {
    Rotation r;
    r << cos_yaw_, -sin_yaw_, sin_yaw_, cos_yaw_;
    return r;
  }

  Pose2 operator*(const Pose2& rhs) const;
  Translation operator*(const Translation& point) const;
  Pose2 Inverse() const;

  static Pose2 Exp(const Tangent& xi);
  Tangent Log() const;
  Pose2 Retract(const Tangent& delta) const;
  Tangent ErrorVector() const;

  bool IsFinite() const;

 private:
  Translation translation_ = Translation::Zero();
  double yaw_rad_ = 0.0;
  // cos and sin of the yaw, computed once: residuals and Jacobians read them for every edge at
  // every iteration (recomputing them there was 10% of iRRR's time).
  double cos_yaw_ = 1.0;
  double sin_yaw_ = 0.0;
};

// SE(3): translation in metres, rotation as a unit quaternion.
class Pose3 {
 public:
  static constexpr int kDim = 6;
  static constexpr int kTranslationDim = 3;
  static constexpr const char* kName = "SE(3)";
  using Tangent = Eigen::Matrix<double, kDim, 1>;
  using Matrix = Eigen::Matrix<double, kDim, kDim>;
  using Translation = Eigen::Vector3d;
  using Rotation = Eigen::Matrix3d;

  Pose3() = default;
  // `rotation` must be a unit quaternion (callers validate external input first).
  Pose3(const Eigen::Quaterniond& rotation, const Translation& translation);

  const Translation& translation() const { return translation_; }
  const Eigen::Quaterniond& quaternion() const { return rotation_; }
  Rotation rotation() const { return rotation_.toRotationMatrix(); }

  Pose3 operator*(const Pose3& rhs) const;
  Translation operator*(const Translation& point) const;
  Pose3 Inverse() const;

  static Pose3 Exp(const Tangent& xi);
  Tangent Log() const;
  Pose3 Retract(const Tangent& delta) const;
  Tangent ErrorVector() const;

  bool IsFinite() const;

 private:
  Eigen::Quaterniond rotation_ = Eigen::Quaterniond::Identity();
  Translation translation_ = Translation::Zero();
};

// Wraps an angle to [-pi, pi].
double NormalizeAngle(double angle_rad);

// SO(3) exponential and logarithm (rotation vector <-> unit quaternion), exact near 0 and pi.
Eigen::Quaterniond ExpSO3(const Eigen::Vector3d& phi);
Eigen::Vector3d LogSO3(const Eigen::Quaterniond& q);

// Skew-symmetric matrix [v]x with [v]x * w = v x w.
Eigen::Matrix3d Skew(const Eigen::Vector3d& v);

// The adjoint of a pose: T * Exp(xi) * T^-1 = Exp(Adjoint(T) * xi), so that a perturbation in
// the frame of T's "to" side is moved to its "from" side (first order, tangent as Exp's).
template <class Pose>
typename Pose::Matrix Adjoint(const Pose& pose);

// d(tangent)/d(ErrorVector) at the identity: how a small error in g2o's chart (the residual, whose
// covariance is the inverse information) reads as a perturbation x * Exp(xi). The identity in
// SE(2); in SE(3) the quaternion's vector part is half the rotation vector, so diag(1, 1, 1, 2,
// 2, 2).
template <class Pose>
typename Pose::Matrix TangentOfErrorVector();

// Residual of a relative-pose constraint (paper eq. 1, in g2o's error chart):
//   r = ErrorVector(measurement^-1 * (from^-1 * to)),
// so that d^2 = r' * information * r (eq. 2). When non-null, J_r_from and J_r_to receive the
// Jacobians of r with respect to Retract perturbations of `from` and `to`.
template <class Pose>
typename Pose::Tangent RelativePoseResidual(const Pose& measurement,
                                            const Pose& from,
                                            const Pose& to,
                                            typename Pose::Matrix* J_r_from,
                                            typename Pose::Matrix* J_r_to);

}  // namespace irrr

#endif  // IRRR_CORE_POSE_H_
