#include "daemon/inputs.h"

#include <algorithm>
#include <cmath>

#include "core/pose.h"
#include "daemon/wire.h"

namespace irrr {

const header_t& Input::header() const {
  switch (kind) {
    case Kind::kKeyframe:
      return keyframe.header;
    case Kind::kLoop:
      return loop.header;
    case Kind::kSession:
      break;
  }
  return session.header;
}

JournalRecord::Kind JournalKind(Input::Kind kind) {
  switch (kind) {
    case Input::Kind::kKeyframe:
      return JournalRecord::kKeyframe;
    case Input::Kind::kLoop:
      return JournalRecord::kLoop;
    case Input::Kind::kSession:
      break;
  }
  return JournalRecord::kSession;
}

// decode() checks the fingerprint, the lengths and the array sizes; DecodeMessage catches what it
// throws.
bool DecodeInput(JournalRecord::Kind kind, const uint8_t* data, int size, Input* input) {
  auto decode = [&](auto* message) { return DecodeMessage(data, size, message); };
  switch (kind) {
    case JournalRecord::kKeyframe:
      input->kind = Input::Kind::kKeyframe;
      return decode(&input->keyframe);
    case JournalRecord::kLoop:
      input->kind = Input::Kind::kLoop;
      return decode(&input->loop);
    case JournalRecord::kSession:
      break;
  }
  input->kind = Input::Kind::kSession;
  return decode(&input->session);
}

bool SenderAllowed(const std::vector<std::string>& allowed, const std::string& sender) {
  if (allowed.empty()) return true;
  for (const std::string& pattern : allowed) {
    if (pattern == sender) return true;
    if (!pattern.empty() && pattern.back() == '*' &&
        sender.compare(0, pattern.size() - 1, pattern, 0, pattern.size() - 1) == 0) {
      return true;
    }
  }
  return false;
}

bool RobotsAllowed(const std::vector<int>& allowed, const Input& input) {
  if (allowed.empty()) return true;
  auto ok = [&](int32_t robot) {
    return std::find(allowed.begin(), allowed.end(), robot) != allowed.end();
  };
  switch (input.kind) {
    case Input::Kind::kKeyframe:
      return ok(input.keyframe.robot_id);
    case Input::Kind::kLoop:
      return ok(input.loop.robot_from) && ok(input.loop.robot_to);
    case Input::Kind::kSession:
      break;
  }
  return input.session.event == session_event_t::FLUSH || ok(input.session.robot_id);
}

namespace {

template <class Message>
Rejection RejectionFrom(const std::string& channel, const Message& m) {
  Rejection r;
  r.channel = channel;
  r.sender = m.header.sender;
  r.seq = m.header.seq;
  return r;
}

template <class Pose>
Status CheckPoseAndInformation(const pose_t& pose,
                               const std::string& pose_field,
                               const double information[6][6],
                               const std::string& information_field) {
  Pose p;
  if (Status s = PoseFromWire(pose, pose_field, &p); !s.ok()) return s;
  typename Pose::Matrix m;
  return InformationFromWire<Pose>(information, information_field, &m);
}

Status CheckDim(int8_t dim) {
  if (dim != keyframe_t::DIM_SE2 && dim != keyframe_t::DIM_SE3) {
    return Status::Error("dim: " + std::to_string(dim) + " is neither DIM_SE2 (2) nor DIM_SE3 (3)");
  }
  return Status::Ok();
}

Status CheckFields(const keyframe_t& m) {
  if (Status s = CheckDim(m.dim); !s.ok()) return s;
  if (m.robot_id < 0) return Status::Error("robot_id: negative");
  if (m.session_id < 0) return Status::Error("session_id: negative");
  if (m.key < 0) return Status::Error("key: negative");
  if (m.has_odom_edge != 0 && m.has_odom_edge != 1)
    return Status::Error("has_odom_edge: not 0 or 1");
  const bool se2 = m.dim == keyframe_t::DIM_SE2;
  Pose2 p2;
  Pose3 p3;
  if (Status s = se2 ? PoseFromWire(m.odom_pose, "odom_pose", &p2)
                     : PoseFromWire(m.odom_pose, "odom_pose", &p3);
      !s.ok()) {
    return s;
  }
  if (!m.has_odom_edge) return Status::Ok();
  return se2 ? CheckPoseAndInformation<Pose2>(
                   m.odom_delta, "odom_delta", m.information, "information")
             : CheckPoseAndInformation<Pose3>(
                   m.odom_delta, "odom_delta", m.information, "information");
}

Status CheckFields(const loop_hypothesis_t& m) {
  if (Status s = CheckDim(m.dim); !s.ok()) return s;
  if (m.hypothesis_id < 0) return Status::Error("hypothesis_id: negative");
  if (m.robot_from < 0 || m.robot_to < 0) return Status::Error("robot_from/robot_to: negative");
  if (m.session_from < 0 || m.session_to < 0) {
    return Status::Error("session_from/session_to: negative");
  }
  if (m.key_from < 0 || m.key_to < 0) return Status::Error("key_from/key_to: negative");
  if (!std::isfinite(m.score)) return Status::Error("score: not a finite number");
  return m.dim == keyframe_t::DIM_SE2
             ? CheckPoseAndInformation<Pose2>(
                   m.measurement, "measurement", m.information, "information")
             : CheckPoseAndInformation<Pose3>(
                   m.measurement, "measurement", m.information, "information");
}

Status CheckFields(const session_event_t& m) {
  if (m.event < session_event_t::START || m.event > session_event_t::FLUSH) {
    return Status::Error("event: " + std::to_string(m.event) +
                         " is not START, PROGRESS, END or FLUSH");
  }
  if (m.event != session_event_t::FLUSH && (m.robot_id < 0 || m.session_id < 0)) {
    return Status::Error("robot_id/session_id: negative");
  }
  return Status::Ok();
}

}  // namespace

Status CheckInputFields(const Input& input) {
  switch (input.kind) {
    case Input::Kind::kKeyframe:
      return CheckFields(input.keyframe);
    case Input::Kind::kLoop:
      return CheckFields(input.loop);
    case Input::Kind::kSession:
      break;
  }
  return CheckFields(input.session);
}

Rejection RejectionOf(const std::string& channel, const keyframe_t& m) {
  Rejection r = RejectionFrom(channel, m);
  r.robot_id = m.robot_id;
  r.session_id = m.session_id;
  r.key = m.key;
  return r;
}

Rejection RejectionOf(const std::string& channel, const loop_hypothesis_t& m) {
  Rejection r = RejectionFrom(channel, m);
  r.hypothesis_id = m.hypothesis_id;
  return r;
}

Rejection RejectionOf(const std::string& channel, const session_event_t& m) {
  Rejection r = RejectionFrom(channel, m);
  r.robot_id = m.robot_id;
  r.session_id = m.session_id;
  return r;
}

Rejection RejectionOfInput(const DaemonChannels& ch, const Input& input) {
  switch (input.kind) {
    case Input::Kind::kKeyframe:
      return RejectionOf(ch.keyframe, input.keyframe);
    case Input::Kind::kLoop:
      return RejectionOf(ch.loop, input.loop);
    case Input::Kind::kSession:
      break;
  }
  return RejectionOf(ch.session, input.session);
}

std::pair<std::string, std::string> FieldAndReason(const Status& failure) {
  const std::string& m = failure.message();
  const size_t colon = m.find(": ");
  if (colon == std::string::npos) return {"", m};
  return {m.substr(0, colon), m.substr(colon + 2)};
}

}  // namespace irrr
