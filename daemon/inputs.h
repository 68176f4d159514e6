#ifndef IRRR_DAEMON_INPUTS_H_
#define IRRR_DAEMON_INPUTS_H_

// The service's inputs as received (service.h): a keyframe_t, loop_hypothesis_t or
// session_event_t decoded from the bytes of its channel, the field checks that need no state
// (dimension, signs, finite numbers, unit quaternions, positive-definite information), the
// allow-lists, and what an error_t says about an input it answers. Nothing here keeps state or
// logs: the service decides what to do with a failure.

#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "core/status.h"
#include "daemon/common/irrr_config.h"
#include "daemon/journal.h"
#include "irrr/keyframe_t.hpp"
#include "irrr/loop_hypothesis_t.hpp"
#include "irrr/session_event_t.hpp"

namespace irrr {

// header.sender must have 1 to this many bytes.
inline constexpr size_t kMaxSenderBytes = 64;

// One input as received, waiting for the worker. Only the message of `kind` is meaningful.
struct Input {
  enum class Kind { kKeyframe, kLoop, kSession };
  Kind kind = Kind::kKeyframe;
  keyframe_t keyframe{};
  loop_hypothesis_t loop{};
  session_event_t session{};
  int64_t received_utime = 0;
  std::vector<uint8_t> bytes;  // as received (for the journal)

  const header_t& header() const;
};

// The journal record kind of an input kind.
JournalRecord::Kind JournalKind(Input::Kind kind);

// Decodes `size` bytes as a message of `kind` into `input` (its kind and message). False when they
// do not decode (fingerprint, lengths, array sizes, bytes left over; nothing thrown); `input` may
// be partly written then.
bool DecodeInput(JournalRecord::Kind kind, const uint8_t* data, int size, Input* input);

// The checks of an input's fields that need no state. Fails with "<field>: <reason>", e.g.
// "odom_delta.q: quaternion norm 1.1 is not 1" or "dim: 4 is neither DIM_SE2 (2) nor DIM_SE3 (3)";
// the first failing field is named.
Status CheckInputFields(const Input& input);

// Whether `sender` is on the allow-list `allowed` (empty: everyone; an entry ending in '*'
// matches any sender that starts with what precedes it).
bool SenderAllowed(const std::vector<std::string>& allowed, const std::string& sender);

// Whether every robot `input` names is in `allowed` (empty: every robot): a keyframe's robot, both
// ends of a loop, a session event's robot (a FLUSH names none and is always allowed).
bool RobotsAllowed(const std::vector<int>& allowed, const Input& input);

// What an error_t says about the input it answers: the ids of the input, and the field and reason.
struct Rejection {
  std::string channel;
  std::string sender;
  int64_t seq = -1;
  int32_t robot_id = -1;
  int32_t session_id = -1;
  int64_t key = -1;
  int64_t hypothesis_id = -1;
  std::string field;
  std::string reason;
};

// A rejection naming the message's channel, sender, seq and ids (field and reason empty).
Rejection RejectionOf(const std::string& channel, const keyframe_t& message);
Rejection RejectionOf(const std::string& channel, const loop_hypothesis_t& message);
Rejection RejectionOf(const std::string& channel, const session_event_t& message);
// The same for an input, on its channel of `channels`.
Rejection RejectionOfInput(const DaemonChannels& channels, const Input& input);

// Splits a failure "<field>: <reason>" into field and reason (no ": ": an empty field).
std::pair<std::string, std::string> FieldAndReason(const Status& failure);

}  // namespace irrr

#endif  // IRRR_DAEMON_INPUTS_H_
