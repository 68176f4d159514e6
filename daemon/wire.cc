#include "daemon/wire.h"

#include <chrono>
#include <cmath>

#include <Eigen/Cholesky>

#include "irrr/keyframe_t.hpp"
#include "irrr/verdict_t.hpp"

namespace irrr {

template <>
int8_t WireDim<Pose2>() {
  return keyframe_t::DIM_SE2;
}
template <>
int8_t WireDim<Pose3>() {
  return keyframe_t::DIM_SE3;
}

template <>
pose_t PoseToWire(const Pose2& pose) {
  pose_t wire{};
  wire.t[0] = pose.translation().x();
  wire.t[1] = pose.translation().y();
  wire.q[0] = std::cos(0.5 * pose.yaw_rad());
  wire.q[3] = std::sin(0.5 * pose.yaw_rad());
  return wire;
}

template <>
pose_t PoseToWire(const Pose3& pose) {
  pose_t wire{};
  for (int i = 0; i < 3; ++i) wire.t[i] = pose.translation()[i];
  const Eigen::Quaterniond& q = pose.quaternion();
  wire.q[0] = q.w();
  wire.q[1] = q.x();
  wire.q[2] = q.y();
  wire.q[3] = q.z();
  return wire;
}

namespace {

Status CheckPoseNumbers(const pose_t& wire, const std::string& field) {
  for (double v : wire.t) {
    if (!std::isfinite(v)) return Status::Error(field + ".t: not a finite number");
  }
  double norm_squared = 0.0;
  for (double v : wire.q) {
    if (!std::isfinite(v)) return Status::Error(field + ".q: not a finite number");
    norm_squared += v * v;
  }
  if (std::abs(std::sqrt(norm_squared) - 1.0) > kQuaternionNormTolerance) {
    return Status::Error(field + ".q: quaternion norm " + std::to_string(std::sqrt(norm_squared)) +
                         " is not 1");
  }
  return Status::Ok();
}

}  // namespace

template <>
Status PoseFromWire(const pose_t& wire, const std::string& field, Pose2* pose) {
  if (Status s = CheckPoseNumbers(wire, field); !s.ok()) return s;
  if (wire.t[2] != 0.0) return Status::Error(field + ".t: an SE(2) pose needs t[2] = 0");
  if (std::abs(wire.q[1]) > kQuaternionNormTolerance ||
      std::abs(wire.q[2]) > kQuaternionNormTolerance) {
    return Status::Error(field + ".q: an SE(2) pose rotates about z only (q[1] = q[2] = 0)");
  }
  *pose = Pose2(wire.t[0], wire.t[1], 2.0 * std::atan2(wire.q[3], wire.q[0]));
  return Status::Ok();
}

template <>
Status PoseFromWire(const pose_t& wire, const std::string& field, Pose3* pose) {
  if (Status s = CheckPoseNumbers(wire, field); !s.ok()) return s;
  Eigen::Quaterniond q(wire.q[0], wire.q[1], wire.q[2], wire.q[3]);
  q.normalize();
  *pose = Pose3(q, Eigen::Vector3d(wire.t[0], wire.t[1], wire.t[2]));
  return Status::Ok();
}

template <class Pose>
void InformationToWire(const typename Pose::Matrix& information, double out[6][6]) {
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) {
      out[r][c] = r < Pose::kDim && c < Pose::kDim ? information(r, c) : 0.0;
    }
  }
}

template <class Pose>
Status InformationFromWire(const double in[6][6],
                           const std::string& field,
                           typename Pose::Matrix* information) {
  typename Pose::Matrix m;
  for (int r = 0; r < 6; ++r) {
    for (int c = 0; c < 6; ++c) {
      const double v = in[r][c];
      if (!std::isfinite(v)) {
        return Status::Error(field + "[" + std::to_string(r) + "][" + std::to_string(c) +
                             "]: not a finite number");
      }
      if (r < Pose::kDim && c < Pose::kDim) {
        m(r, c) = v;
      } else if (v != 0.0) {
        return Status::Error(field + "[" + std::to_string(r) + "][" + std::to_string(c) +
                             "]: must be 0 outside the " + Pose::kName + " block");
      }
    }
  }
  const double scale = m.cwiseAbs().maxCoeff();
  if ((m - m.transpose()).cwiseAbs().maxCoeff() > 1e-9 * scale) {
    return Status::Error(field + ": not symmetric");
  }
  Eigen::LLT<typename Pose::Matrix> llt(m);
  if (scale <= 0.0 || llt.info() != Eigen::Success) {
    return Status::Error(field + ": not positive definite");
  }
  *information = m;
  return Status::Ok();
}

int8_t LoopStateToWire(LoopState state) {
  switch (state) {
    case LoopState::kPending:
      return verdict_t::PENDING;
    case LoopState::kAccepted:
      return verdict_t::ACCEPTED;
    case LoopState::kRejectedLinkTest:
      return verdict_t::REJECTED_LINK_TEST;
    case LoopState::kRejectedClusterTest:
      return verdict_t::REJECTED_CLUSTER_TEST;
    case LoopState::kRejectedJointTest:
      return verdict_t::REJECTED_JOINT_TEST;
    case LoopState::kReversed:
      return verdict_t::REVERSED;
  }
  return verdict_t::PENDING;
}

Status LoopStateFromWire(int8_t wire, LoopState* state) {
  for (LoopState s : {LoopState::kPending,
                      LoopState::kAccepted,
                      LoopState::kRejectedLinkTest,
                      LoopState::kRejectedClusterTest,
                      LoopState::kRejectedJointTest,
                      LoopState::kReversed}) {
    if (LoopStateToWire(s) == wire) {
      *state = s;
      return Status::Ok();
    }
  }
  return Status::Error("state: unknown verdict constant " + std::to_string(wire));
}

int64_t NowUtime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

template void InformationToWire<Pose2>(const Pose2::Matrix&, double[6][6]);
template void InformationToWire<Pose3>(const Pose3::Matrix&, double[6][6]);
template Status InformationFromWire<Pose2>(const double[6][6], const std::string&, Pose2::Matrix*);
template Status InformationFromWire<Pose3>(const double[6][6], const std::string&, Pose3::Matrix*);

}  // namespace irrr
