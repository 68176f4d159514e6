#ifndef IRRR_DAEMON_WIRE_H_
#define IRRR_DAEMON_WIRE_H_

// The edge between LCM messages (lcmtypes/) and core types: poses, information matrices and
// verdict states in both directions, with the field checks that need no state (finite numbers,
// unit quaternions, symmetric positive-definite information). Shared by the daemon and the
// clients, so that both ends agree on one layout.

#include <cstdint>
#include <exception>
#include <string>
#include <vector>

#include "core/irrr.h"
#include "core/pose.h"
#include "core/status.h"
#include "irrr/pose_t.hpp"

namespace irrr {

// Largest deviation of a pose_t quaternion's norm from 1 that is accepted.
inline constexpr double kQuaternionNormTolerance = 1e-6;

// keyframe_t::DIM_SE2 for Pose2, DIM_SE3 for Pose3.
template <class Pose>
int8_t WireDim();

template <class Pose>
pose_t PoseToWire(const Pose& pose);

// Fails (naming `field`) on non-finite numbers, a quaternion whose norm is not 1 within
// kQuaternionNormTolerance, and for SE(2) on a pose that is not a planar rotation about z with
// t[2] = 0. The quaternion is normalized.
template <class Pose>
Status PoseFromWire(const pose_t& wire, const std::string& field, Pose* pose);

// information[6][6] row-major, SE(2) in rows and columns 0..2 (the rest 0), SE(3) all of it.
template <class Pose>
void InformationToWire(const typename Pose::Matrix& information, double out[6][6]);

// Fails (naming `field`) on non-finite entries, an asymmetric matrix (relative 1e-9), a non-zero
// entry outside the SE(2) block, or a matrix that is not positive definite.
template <class Pose>
Status InformationFromWire(const double in[6][6],
                           const std::string& field,
                           typename Pose::Matrix* information);

// verdict_t state constants.
int8_t LoopStateToWire(LoopState state);
// Fails on an unknown constant.
Status LoopStateFromWire(int8_t wire, LoopState* state);

// The bytes of an LCM message, as publish() and LogFile take them.
template <class Message>
std::vector<uint8_t> EncodeMessage(const Message& message) {
  std::vector<uint8_t> bytes(message.getEncodedSize());
  message.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  return bytes;
}

// Decodes a whole message (false: it does not decode, or bytes are left over). The C++ that
// Debian's lcm-gen 1.3.1 generates throws from std::string and std::vector on some corrupt
// lengths and counts; that is caught here, so a bad datagram is only a bad datagram.
template <class Message>
bool DecodeMessage(const void* data, int size, Message* message) {
  try {
    return message->decode(data, 0, size) == size;
  } catch (const std::exception&) {
    return false;
  }
}

// Microseconds since the Unix epoch, now.
int64_t NowUtime();

}  // namespace irrr

#endif  // IRRR_DAEMON_WIRE_H_
