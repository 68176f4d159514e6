// The service's inputs (daemon/inputs.h): decoding, the field checks that need no state, the
// allow-lists and what an error_t says, each on its own, without a service.

#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include <catch2/catch.hpp>

#include "daemon/inputs.h"
#include "daemon/wire.h"
#include "tests/service_helpers.h"

namespace irrr {
namespace {

Input KeyframeInput(const keyframe_t& k) {
  Input input;
  input.kind = Input::Kind::kKeyframe;
  input.keyframe = k;
  return input;
}

Input LoopInput(const loop_hypothesis_t& l) {
  Input input;
  input.kind = Input::Kind::kLoop;
  input.loop = l;
  return input;
}

Input SessionInput(const session_event_t& e) {
  Input input;
  input.kind = Input::Kind::kSession;
  input.session = e;
  return input;
}

std::string Failure(const Input& input) {
  const Status s = CheckInputFields(input);
  return s.ok() ? "ok" : s.message();
}

int Size(const std::vector<uint8_t>& bytes) { return static_cast<int>(bytes.size()); }

TEST_CASE("Inputs decode by their channel's type, and other bytes do not", "[inputs]") {
  const std::vector<uint8_t> keyframe = EncodeMessage(Keyframe(0, 3));
  Input input;
  REQUIRE(DecodeInput(JournalRecord::kKeyframe, keyframe.data(), Size(keyframe), &input));
  CHECK(input.kind == Input::Kind::kKeyframe);
  CHECK(input.keyframe.key == 3);
  CHECK(&input.header() == &input.keyframe.header);
  CHECK(JournalKind(input.kind) == JournalRecord::kKeyframe);

  // A keyframe's bytes on the loop channel: another fingerprint.
  CHECK_FALSE(DecodeInput(JournalRecord::kLoop, keyframe.data(), Size(keyframe), &input));
  // Cut short, or with a byte left over.
  CHECK_FALSE(DecodeInput(JournalRecord::kKeyframe, keyframe.data(), Size(keyframe) - 1, &input));
  std::vector<uint8_t> longer = keyframe;
  longer.push_back(0);
  CHECK_FALSE(DecodeInput(JournalRecord::kKeyframe, longer.data(), Size(longer), &input));

  const std::vector<uint8_t> event = EncodeMessage(SessionEvent(session_event_t::END, 2));
  REQUIRE(DecodeInput(JournalRecord::kSession, event.data(), Size(event), &input));
  CHECK(input.kind == Input::Kind::kSession);
  CHECK(input.session.session_id == 2);
  CHECK(JournalKind(input.kind) == JournalRecord::kSession);
}

TEST_CASE("Field checks name the first field that fails, and pass valid inputs", "[inputs]") {
  CHECK(Failure(KeyframeInput(Keyframe(0, 0))) == "ok");
  CHECK(Failure(KeyframeInput(Keyframe(0, 5))) == "ok");
  CHECK(Failure(LoopInput(Loop(7, 0, 5))) == "ok");
  CHECK(Failure(SessionInput(SessionEvent(session_event_t::FLUSH))) == "ok");

  keyframe_t k = Keyframe(0, 1);
  k.dim = 4;
  CHECK(Failure(KeyframeInput(k)) == "dim: 4 is neither DIM_SE2 (2) nor DIM_SE3 (3)");
  k = Keyframe(0, 1);
  k.key = -1;
  CHECK(Failure(KeyframeInput(k)) == "key: negative");
  k = Keyframe(0, 1);
  k.has_odom_edge = 2;
  CHECK(Failure(KeyframeInput(k)) == "has_odom_edge: not 0 or 1");
  k = Keyframe(0, 1);
  k.odom_delta.t[0] = std::numeric_limits<double>::quiet_NaN();
  CHECK_THAT(Failure(KeyframeInput(k)), Catch::Matchers::StartsWith("odom_delta.t"));
  k = Keyframe(0, 1);
  k.information[1][1] = -1.0;
  CHECK_THAT(Failure(KeyframeInput(k)), Catch::Matchers::StartsWith("information"));
  // A first keyframe carries no odometry: its delta is not looked at.
  k = Keyframe(0, 0);
  k.odom_delta.t[0] = std::numeric_limits<double>::quiet_NaN();
  CHECK(Failure(KeyframeInput(k)) == "ok");

  loop_hypothesis_t l = Loop(7, 0, 5);
  l.score = std::numeric_limits<float>::infinity();
  CHECK(Failure(LoopInput(l)) == "score: not a finite number");
  l = Loop(7, 0, 5);
  l.session_to = -2;
  CHECK(Failure(LoopInput(l)) == "session_from/session_to: negative");
  l = Loop(7, 0, 5);
  l.measurement.q[0] = 0.5;  // norm 0.5
  CHECK_THAT(Failure(LoopInput(l)), Catch::Matchers::StartsWith("measurement.q"));

  session_event_t e = SessionEvent(session_event_t::END);
  e.event = 9;
  CHECK(Failure(SessionInput(e)) == "event: 9 is not START, PROGRESS, END or FLUSH");
  e = SessionEvent(session_event_t::END);
  e.robot_id = -1;
  CHECK(Failure(SessionInput(e)) == "robot_id/session_id: negative");
  e.event = session_event_t::FLUSH;  // names no session
  CHECK(Failure(SessionInput(e)) == "ok");
}

TEST_CASE("Allow-lists: exact names, prefixes ending in *, robots at both ends of a loop",
          "[inputs]") {
  CHECK(SenderAllowed({}, "anyone"));
  CHECK(SenderAllowed({"robot-1"}, "robot-1"));
  CHECK_FALSE(SenderAllowed({"robot-1"}, "robot-10"));
  CHECK(SenderAllowed({"fleet/*"}, "fleet/robot2"));
  CHECK(SenderAllowed({"fleet/*"}, "fleet/"));
  CHECK_FALSE(SenderAllowed({"fleet/*"}, "fleet"));
  CHECK(SenderAllowed({"*"}, "x"));

  loop_hypothesis_t l = Loop(1, 0, 5);
  l.robot_from = 1;
  l.robot_to = 2;
  CHECK(RobotsAllowed({}, LoopInput(l)));
  CHECK(RobotsAllowed({1, 2}, LoopInput(l)));
  CHECK_FALSE(RobotsAllowed({1}, LoopInput(l)));
  keyframe_t k = Keyframe(0, 0);
  k.robot_id = 3;
  CHECK_FALSE(RobotsAllowed({1, 2}, KeyframeInput(k)));
  session_event_t e = SessionEvent(session_event_t::FLUSH);
  e.robot_id = 9;
  CHECK(RobotsAllowed({1}, SessionInput(e)));  // a FLUSH names no robot
  e.event = session_event_t::END;
  CHECK_FALSE(RobotsAllowed({1}, SessionInput(e)));
}

TEST_CASE("A rejection names the input's channel, sender, seq and ids", "[inputs]") {
  DaemonChannels channels;
  keyframe_t k = Keyframe(4, 7);
  k.robot_id = 2;
  k.header.sender = "robot-2";
  const Rejection r = RejectionOfInput(channels, KeyframeInput(k));
  CHECK(r.channel == channels.keyframe);
  CHECK(r.sender == "robot-2");
  CHECK(r.seq == k.header.seq);
  CHECK(r.robot_id == 2);
  CHECK(r.session_id == 4);
  CHECK(r.key == 7);
  CHECK(r.hypothesis_id == -1);
  CHECK(r.field.empty());

  const Rejection loop = RejectionOfInput(channels, LoopInput(Loop(11, 0, 5)));
  CHECK(loop.channel == channels.loop);
  CHECK(loop.hypothesis_id == 11);
  CHECK(loop.key == -1);

  CHECK(FieldAndReason(Status::Error("key_to: self-loop")) ==
        std::make_pair(std::string("key_to"), std::string("self-loop")));
  CHECK(FieldAndReason(Status::Error("no field here")) ==
        std::make_pair(std::string(), std::string("no field here")));
}

}  // namespace
}  // namespace irrr
