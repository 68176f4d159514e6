#include "daemon/service.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <set>
#include <tuple>
#include <type_traits>
#include <utility>

#include <fmt/core.h>
#include <spdlog/spdlog.h>

#include "daemon/common/thread_pool.h"
#include "daemon/sequencer.h"
#include "daemon/snapshot.h"
#include "daemon/stamp_merger.h"
#include "daemon/wire.h"
#include "irrr/correction_t.hpp"
#include "irrr/error_t.hpp"
#include "irrr/resync_request_t.hpp"
#include "irrr/solution_request_t.hpp"
#include "irrr/solution_t.hpp"
#include "irrr/verdicts_t.hpp"

namespace irrr {
namespace {

constexpr size_t kMaxSenderBytes = 64;

// One input as received, checked field by field, waiting for the worker.
struct Input {
  enum class Kind { kKeyframe, kLoop, kSession };
  Kind kind = Kind::kKeyframe;
  keyframe_t keyframe{};
  loop_hypothesis_t loop{};
  session_event_t session{};
  int64_t received_utime = 0;
  std::vector<uint8_t> bytes;  // as received (for the journal)

  const header_t& header() const {
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
};

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

// Decodes a message of `kind` into `input` (false: it does not decode). decode() checks the
// fingerprint, the lengths and the array sizes; DecodeMessage catches what it throws.
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

// Whether `sender` is on the allow-list (empty: everyone; a trailing '*' matches any suffix).
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

// What an error_t says about the input it answers.
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

template <class Message>
Rejection RejectionFrom(const std::string& channel, const Message& m) {
  Rejection r;
  r.channel = channel;
  r.sender = m.header.sender;
  r.seq = m.header.seq;
  return r;
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

// Field checks that need no state: (field, reason) of the first failure, or an empty field.
std::pair<std::string, std::string> Failure(const Status& s) {
  const std::string& m = s.message();
  const size_t colon = m.find(": ");
  if (colon == std::string::npos) return {"", m};
  return {m.substr(0, colon), m.substr(colon + 2)};
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

// Whether every robot `input` names is on the allow-list (empty: every robot).
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

bool SameDecision(const LoopDecision& a, const LoopDecision& b) {
  auto same = [](double x, double y) { return x == y || (std::isnan(x) && std::isnan(y)); };
  return a.state == b.state && a.cluster == b.cluster && a.step == b.step && same(a.chi2, b.chi2) &&
         same(a.threshold, b.threshold);
}

using SessionName = std::pair<int32_t, int32_t>;  // (robot_id, session_id)

struct Hypothesis {
  std::string sender;
  int64_t id = -1;
  int32_t robot_from = 0;
  int32_t session_from = 0;
  int64_t key_from = 0;
  int32_t robot_to = 0;
  int32_t session_to = 0;
  int64_t key_to = 0;
};

// One Irrr (one pose type) and the wire identities of what it holds.
template <class Pose>
struct Engine {
  explicit Engine(const IrrrOptions& options) : irrr(options) {}

  struct SessionInfo {
    SessionName name;
    int order = 0;  // creation order over both engines
    int64_t first_key = 0;
  };

  Irrr<Pose> irrr;
  std::vector<SessionInfo> sessions;  // by Irrr session index
  std::vector<Pose> odom_pose;        // by Irrr vertex index
  std::vector<int> anchor;            // by Irrr session: creation order of its map's first session
  std::map<int, Hypothesis> hypothesis_of_edge;
  std::map<int, LoopDecision> published;  // last decision published, by Irrr edge
  std::set<int> dirty;                    // sessions re-estimated since the last full correction

  int64_t KeyOf(int session, int position) const { return sessions[session].first_key + position; }
};

// Where an engine's components lie: each in the frame of the first pose of its earliest session,
// the one whose first keyframe has the smallest stamp (ties: the smallest (robot_id,
// session_id)). This is a property of the data, not of arrival order, so daemons that hear the
// same inputs in other orders publish in the same frames. Core's Irrr keeps each component in the
// frame of its first-created session; poses are re-expressed when the two differ.
template <class Pose>
struct MapFrames {
  std::vector<int> component_of;  // per session: core's component index
  std::vector<int> anchor;        // per component: its earliest session
  std::vector<char> moved;        // per component: its frame differs from core's
  std::vector<Pose> map_T_core;   // per component: core's frame in the map frame

  Pose InMap(int session, const Pose& pose) const {
    const int k = component_of[session];
    return moved[k] ? map_T_core[k] * pose : pose;
  }
};

template <class Pose>
MapFrames<Pose> FramesOf(const Engine<Pose>& engine) {
  MapFrames<Pose> frames;
  const Irrr<Pose>& irrr = engine.irrr;
  frames.component_of = irrr.Components();
  const int num_components =
      frames.component_of.empty()
          ? 0
          : *std::max_element(frames.component_of.begin(), frames.component_of.end()) + 1;
  frames.anchor.assign(num_components, -1);
  std::vector<int> core_anchor(num_components, -1);
  auto first_stamp = [&](int s) {
    return irrr.graph().vertex(irrr.graph().session(s).vertices[0]).stamp;
  };
  for (int s = 0; s < static_cast<int>(frames.component_of.size()); ++s) {
    const int k = frames.component_of[s];
    if (core_anchor[k] < 0) core_anchor[k] = s;  // sessions are in creation order
    const int a = frames.anchor[k];
    if (a < 0 || std::make_pair(first_stamp(s), engine.sessions[s].name) <
                     std::make_pair(first_stamp(a), engine.sessions[a].name)) {
      frames.anchor[k] = s;
    }
  }
  frames.moved.assign(num_components, 0);
  frames.map_T_core.resize(num_components);
  for (int k = 0; k < num_components; ++k) {
    if (frames.anchor[k] == core_anchor[k]) continue;
    frames.moved[k] = 1;
    const int first = irrr.graph().session(frames.anchor[k]).vertices[0];
    frames.map_T_core[k] = irrr.estimate()[first].Inverse();
  }
  return frames;
}

}  // namespace

struct Service::State {
  State(const DaemonOptions& d, const IrrrOptions& o, MessageSink* s)
      : daemon(d),
        options(o),
        sink(s),
        sequencer(SequencerLimits{d.limits.max_held,
                                  std::chrono::milliseconds(d.resync.interval_ms),
                                  std::chrono::milliseconds(d.resync.give_up_ms)}),
        pool(d.threads > 0 ? d.threads : ThreadPool::DefaultThreads()),
        se2(o),
        se3(o),
        start_utime(NowUtime()) {
    se2.irrr.SetParallelFor(pool.AsParallelFor(), pool.size());
    se3.irrr.SetParallelFor(pool.AsParallelFor(), pool.size());
    if (d.merge.window_ms > 0) {
      merger = std::make_unique<StampMerger<Input>>(std::chrono::milliseconds(d.merge.window_ms),
                                                    d.merge.senders);
    }
  }

  const DaemonOptions daemon;
  const IrrrOptions options;
  MessageSink* const sink;
  Journal* journal = nullptr;
  // While the journal is replayed at start: nothing is published, old errors are not logged again.
  std::atomic<bool> replaying{false};
  // Off while the inputs a snapshot covers are fed again: their steps are in the snapshot.
  bool run_steps = true;
  std::string snapshot_path;   // "" = no snapshots
  int64_t snapshot_at = 0;     // journal records the last snapshot covers
  int64_t snapshot_bytes = 0;  // the last snapshot body's size

  // Receiving thread: each sender's inputs back in its order, and the senders ignored.
  mutable std::mutex sequencer_mutex;
  Sequencer<Input> sequencer;
  std::atomic<bool> solution_requested{false};
  // With daemon.merge: the senders' inputs in stamp order (stamp_merger.h), and the sessions each
  // sender has open (a sender with none holds nobody back). Under sequencer_mutex.
  std::unique_ptr<StampMerger<Input>> merger;
  std::map<std::string, std::set<std::pair<int32_t, int32_t>>> open_sessions;

  // Receiving thread -> worker.
  mutable std::mutex queue_mutex;
  std::condition_variable queue_changed;
  std::deque<Input> queue;
  bool wake = false;
  // Inputs received and not applied yet: the queue and the worker's current batch.
  std::atomic<int> unapplied{0};

  // Counters for status_t (both threads).
  mutable std::mutex stats_mutex;
  status_t stats = [] {
    status_t s{};
    s.variance_factor = 1.0f;  // before any step: the information as given
    return s;
  }();
  std::map<std::string, sender_count_t> senders;

  // Outgoing sequence number (one counter over all channels, as header_t says).
  std::mutex publish_mutex;
  int64_t next_seq = 0;

  // Worker only (the pool runs the engines' independent checks for it).
  ThreadPool pool;
  Engine<Pose2> se2;
  Engine<Pose3> se3;
  struct SessionRef {
    int8_t dim = 0;
    int index = -1;  // in its engine
  };
  std::map<SessionName, SessionRef> sessions;
  struct HypothesisRef {
    int8_t dim = 0;
    int edge = -1;
  };
  std::map<std::pair<std::string, int64_t>, HypothesisRef> hypotheses;
  std::vector<HypothesisRef> hypothesis_order;
  int num_sessions = 0;
  std::vector<SessionName> session_names;  // by creation order
  int64_t num_keyframes = 0;
  int64_t next_vertex_id = 0;
  int64_t solution_id = 0;
  const int64_t start_utime;

  template <class Message>
  void Publish(const std::string& channel, Message* message) {
    if (replaying) return;
    std::lock_guard<std::mutex> lock(publish_mutex);
    message->header.utime = NowUtime();
    message->header.seq = next_seq++;
    message->header.sender = daemon.daemon_id;
    sink->Send(channel, EncodeMessage(*message));
  }

  sender_count_t& SenderLocked(const std::string& sender) {
    auto it = senders.find(sender);
    if (it == senders.end()) {
      sender_count_t count{};
      count.sender = sender;
      count.last_seq = -1;
      it = senders.emplace(sender, count).first;
    }
    return it->second;
  }

  void Reject(const Rejection& r) {
    spdlog::log(replaying ? spdlog::level::debug : spdlog::level::warn,
                "rejected {} from \"{}\" (seq {}): {}: {}",
                r.channel,
                r.sender,
                r.seq,
                r.field.empty() ? "message" : r.field,
                r.reason);
    {
      std::lock_guard<std::mutex> lock(stats_mutex);
      ++stats.n_errors;
      stats.last_error = r.channel + ": " + (r.field.empty() ? "" : r.field + ": ") + r.reason;
      if (!r.sender.empty() && r.sender.size() <= kMaxSenderBytes) {
        ++SenderLocked(r.sender).rejected;
      }
    }
    error_t error{};
    error.daemon_id = daemon.daemon_id;
    error.channel = r.channel;
    error.sender = r.sender;
    error.seq = r.seq;
    error.robot_id = r.robot_id;
    error.session_id = r.session_id;
    error.key = r.key;
    error.hypothesis_id = r.hypothesis_id;
    error.field = r.field;
    error.reason = r.reason;
    Publish(daemon.channels.error, &error);
  }

  void Reject(Rejection r, const Status& s) {
    std::tie(r.field, r.reason) = Failure(s);
    Reject(r);
  }

  // ---- Receiving thread ----

  // A decoded input: who sent it, then its place in the sender's order (sequencer.h). Returns
  // true if it asks for an immediate status (a session PROGRESS).
  bool Admit(Input input) {
    const Rejection about = RejectionOfInput(daemon.channels, input);
    const std::string sender = input.header().sender;
    if (sender.empty() || sender.size() > kMaxSenderBytes) {
      Rejection r = about;
      r.field = "header.sender";
      r.reason = "must have 1 to " + std::to_string(kMaxSenderBytes) + " bytes";
      Reject(r);
      return false;
    }
    if (!SenderAllowed(daemon.allowed_senders, sender)) {
      Ignore(sender, "is not in daemon.allowed_senders");
      return false;
    }
    const int64_t seq = input.header().seq;
    const bool progress =
        input.kind == Input::Kind::kSession && input.session.event == session_event_t::PROGRESS;
    {
      std::lock_guard<std::mutex> lock(stats_mutex);
      ++SenderLocked(sender).received;
    }
    std::lock_guard<std::mutex> lock(sequencer_mutex);
    const auto outcome = sequencer.Offer(
        sender, seq, std::move(input), std::chrono::steady_clock::now(), [this](Input&& in) {
          return Take(std::move(in));
        });
    if (outcome == Sequencer<Input>::Outcome::kDuplicate) {
      WarnOnce("duplicate",
               sender,
               "\"" + sender + "\" sent seq " + std::to_string(seq) +
                   " again (a resend, or a producer that does not count header.seq from 0 up): "
                   "duplicates are ignored");
    }
    if (outcome == Sequencer<Input>::Outcome::kHoldFull) {
      Rejection r = about;
      r.field = "header.seq";
      r.reason = "an earlier message of this sender is missing and daemon.limits.max_held (" +
                 std::to_string(daemon.limits.max_held) +
                 ") inputs wait already: not taken, re-requested later";
      Reject(r);
    }
    return progress;
  }

  // An input in its sender's order: checked, then queued for the worker. False (the sequencer
  // waits for a resend) only when the queue is full.
  bool Take(Input&& input) {
    if (!RobotsAllowed(daemon.allowed_robots, input)) {
      Ignore(input.header().sender, "names a robot not in daemon.allowed_robots");
      return true;
    }
    if (Status s = CheckInputFields(input); !s.ok()) {
      Reject(RejectionOfInput(daemon.channels, input), s);
      return true;
    }
    // A PROGRESS changes nothing: its place in the order is all it takes (a status answers it).
    if (input.kind == Input::Kind::kSession && input.session.event == session_event_t::PROGRESS) {
      return true;
    }
    if (unapplied.load() < daemon.limits.queue_limit) {
      ++unapplied;
      if (merger == nullptr) {
        Enqueue(std::move(input));
      } else {
        Merge(std::move(input));
      }
      return true;
    }
    Rejection r = RejectionOfInput(daemon.channels, input);
    r.reason = "input queue full (daemon.limits.queue_limit " +
               std::to_string(daemon.limits.queue_limit) + "): not taken, re-requested later";
    Reject(r);
    return false;
  }

  void Enqueue(Input&& input) {
    std::lock_guard<std::mutex> lock(queue_mutex);
    queue.push_back(std::move(input));
    queue_changed.notify_one();
  }

  // daemon.merge: holds `input` until its stamp's turn (under sequencer_mutex).
  void Merge(Input&& input) {
    const std::string sender = input.header().sender;
    auto& open = open_sessions[sender];
    int64_t stamp = StampMerger<Input>::kNoStamp;
    if (input.kind == Input::Kind::kKeyframe) {
      stamp = input.keyframe.stamp_utime;
      open.insert({input.keyframe.robot_id, input.keyframe.session_id});
    } else if (input.kind == Input::Kind::kSession && input.session.event == session_event_t::END) {
      open.erase({input.session.robot_id, input.session.session_id});
    }
    const auto now = std::chrono::steady_clock::now();
    merger->Add(sender, stamp, !open.empty(), std::move(input), now);
    ReleaseMerged(now);
  }

  void ReleaseMerged(std::chrono::steady_clock::time_point now) {
    if (merger == nullptr) return;
    const int late = merger->Release(now, [this](Input&& in) { Enqueue(std::move(in)); });
    if (late > 0) {
      WarnOnce("late",
               "merge",
               std::to_string(late) + " input(s) waited daemon.merge.window_ms (" +
                   std::to_string(daemon.merge.window_ms) +
                   " ms) for a silent sender and went on in arrival order (logged once)");
    }
  }

  void Ignore(const std::string& sender, const char* why) {
    {
      std::lock_guard<std::mutex> lock(stats_mutex);
      ++stats.n_ignored;
    }
    WarnOnce("ignored", sender, "ignoring input from \"" + sender + "\": it " + why);
  }

  // Logs `text` the first time `sender` does something of `kind` (at most kMaxWarned pairs are
  // remembered, so that a flood of sender names cannot grow this without bound).
  void WarnOnce(const char* kind, const std::string& sender, const std::string& text) {
    constexpr size_t kMaxWarned = 1000;
    std::lock_guard<std::mutex> lock(warned_mutex);
    if (warned.size() < kMaxWarned && warned.emplace(kind, sender).second) spdlog::warn(text);
  }
  std::mutex warned_mutex;
  std::set<std::pair<std::string, std::string>> warned;  // (kind, sender)

  // Re-requests open gaps and gives up on old ones (the receiving thread, every few ms).
  void Tick() {
    const auto now = std::chrono::steady_clock::now();
    std::vector<Sequencer<Input>::Request> due;
    std::vector<Sequencer<Input>::Request> skipped;
    {
      std::lock_guard<std::mutex> lock(sequencer_mutex);
      due = sequencer.DueRequests(now);
      skipped = sequencer.GiveUp(now, [this](Input&& in) { return Take(std::move(in)); });
      ReleaseMerged(now);
    }
    for (const auto& request : due) {
      resync_request_t r{};
      r.daemon_id = daemon.daemon_id;
      r.sender = request.sender;
      for (const auto& [first, last] : request.ranges) {
        if (r.first_seq.size() >= static_cast<size_t>(resync_request_t::MAX_RANGES)) break;
        r.first_seq.push_back(first);
        r.last_seq.push_back(last);
      }
      r.n_ranges = static_cast<int32_t>(r.first_seq.size());
      spdlog::debug("asking \"{}\" to resend {} range(s) from seq {}",
                    r.sender,
                    r.n_ranges,
                    r.first_seq.empty() ? -1 : r.first_seq[0]);
      Publish(daemon.channels.resync, &r);
    }
    for (const auto& gap : skipped) {
      Rejection r;
      r.channel = daemon.channels.resync;
      r.sender = gap.sender;
      r.seq = gap.ranges[0].first;
      r.field = "header.seq";
      r.reason = "seq " + std::to_string(gap.ranges[0].first) + ".." +
                 std::to_string(gap.ranges[0].second) + " never arrived within " +
                 "daemon.resync.give_up_ms (" + std::to_string(daemon.resync.give_up_ms) +
                 " ms): went on without them";
      Reject(r);
    }
  }

  // ---- Worker ----

  Status AddKeyframe(const keyframe_t& m) {
    const SessionName name{m.robot_id, m.session_id};
    auto it = sessions.find(name);
    if (it == sessions.end()) {
      if (static_cast<int>(sessions.size()) >= daemon.limits.max_sessions) {
        return Status::Error("session_id: daemon.limits.max_sessions (" +
                             std::to_string(daemon.limits.max_sessions) + ") reached");
      }
      it = sessions.emplace(name, SessionRef{m.dim, -1}).first;
    } else if (it->second.dim != m.dim) {
      return Status::Error("dim: the session's keyframes are " +
                           std::string(it->second.dim == keyframe_t::DIM_SE2 ? "SE(2)" : "SE(3)"));
    }
    if (num_keyframes >= daemon.limits.max_keyframes) {
      return Status::Error("key: daemon.limits.max_keyframes (" +
                           std::to_string(daemon.limits.max_keyframes) + ") reached");
    }
    const Status s = m.dim == keyframe_t::DIM_SE2 ? AddKeyframeTo(se2, m, &it->second)
                                                  : AddKeyframeTo(se3, m, &it->second);
    if (s.ok()) {
      ++num_keyframes;
      std::lock_guard<std::mutex> lock(stats_mutex);
      stats.n_keyframes = num_keyframes;
      stats.n_sessions = num_sessions;
    }
    return s;
  }

  template <class Pose>
  Status AddKeyframeTo(Engine<Pose>& engine, const keyframe_t& m, SessionRef* ref) {
    Pose odom_pose;
    IRRR_CHECK(PoseFromWire(m.odom_pose, "odom_pose", &odom_pose).ok());
    const bool first = ref->index < 0;
    Pose delta;
    typename Pose::Matrix information;
    if (!first) {
      const auto& vertices = engine.irrr.graph().session(ref->index).vertices;
      const int64_t last_key = engine.KeyOf(ref->index, static_cast<int>(vertices.size()) - 1);
      if (m.key <= last_key) {
        return Status::Error("key: duplicate (key " + std::to_string(m.key) + " of this session " +
                             "was received already; the last is " + std::to_string(last_key) + ")");
      }
      if (m.key != last_key + 1) {
        return Status::Error("key: expected " + std::to_string(last_key + 1) + ", got " +
                             std::to_string(m.key) + " (keys of a session are consecutive)");
      }
      if (!m.has_odom_edge) {
        return Status::Error("has_odom_edge: 0, but only a session's first key has no odometry");
      }
      IRRR_CHECK(PoseFromWire(m.odom_delta, "odom_delta", &delta).ok());
      IRRR_CHECK(InformationFromWire<Pose>(m.information, "information", &information).ok());
    }
    int session = ref->index;
    if (first) {
      const int64_t id = (int64_t{m.robot_id} << 32) | static_cast<uint32_t>(m.session_id);
      IRRR_CHECK(engine.irrr.AddSession(id, &session).ok());
      ref->index = session;
      engine.anchor.push_back(num_sessions);
      session_names.push_back({m.robot_id, m.session_id});
      engine.sessions.push_back({SessionName{m.robot_id, m.session_id}, num_sessions++, m.key});
    }
    int vertex = -1;
    // Only a later pose can fail here (a stamp older than the session's last); a first pose
    // has passed every check Irrr makes.
    const Status added = engine.irrr.AddPose(session,
                                             next_vertex_id,
                                             1e-6 * static_cast<double>(m.stamp_utime),
                                             first ? nullptr : &delta,
                                             first ? nullptr : &information,
                                             &vertex);
    IRRR_CHECK(added.ok() || !first);
    if (!added.ok()) return Status::Error("stamp_utime: " + added.message());
    ++next_vertex_id;
    engine.odom_pose.resize(vertex + 1);
    engine.odom_pose[vertex] = odom_pose;
    return Status::Ok();
  }

  // The Irrr vertex of (robot, session, key) of `engine`, or an error naming `which` end.
  template <class Pose>
  Status FindVertex(const Engine<Pose>& engine,
                    int32_t robot,
                    int32_t session,
                    int64_t key,
                    const std::string& which,
                    int* vertex) const {
    const auto it = sessions.find({robot, session});
    const std::string name =
        "robot " + std::to_string(robot) + ", session " + std::to_string(session);
    if (it == sessions.end()) {
      return Status::Error("session_" + which + ": unknown session (" + name + ")");
    }
    if (it->second.dim != WireDim<Pose>()) {
      return Status::Error("dim: session (" + name + ") has the other pose type");
    }
    const auto& vertices = engine.irrr.graph().session(it->second.index).vertices;
    const int64_t first = engine.sessions[it->second.index].first_key;
    if (key < first || key >= first + static_cast<int64_t>(vertices.size())) {
      return Status::Error("key_" + which + ": unknown key " + std::to_string(key) + " (" + name +
                           " has keys " + std::to_string(first) + ".." +
                           std::to_string(first + static_cast<int64_t>(vertices.size()) - 1) + ")");
    }
    *vertex = vertices[key - first];
    return Status::Ok();
  }

  Status AddLoop(const loop_hypothesis_t& m) {
    const auto id = std::make_pair(m.header.sender, m.hypothesis_id);
    if (hypotheses.count(id) != 0) {
      return Status::Error("hypothesis_id: duplicate (" + std::to_string(m.hypothesis_id) +
                           " of this sender was received already)");
    }
    if (static_cast<int64_t>(hypotheses.size()) >= daemon.limits.max_hypotheses) {
      return Status::Error("hypothesis_id: daemon.limits.max_hypotheses (" +
                           std::to_string(daemon.limits.max_hypotheses) + ") reached");
    }
    return m.dim == keyframe_t::DIM_SE2 ? AddLoopTo(se2, m) : AddLoopTo(se3, m);
  }

  template <class Pose>
  Status AddLoopTo(Engine<Pose>& engine, const loop_hypothesis_t& m) {
    int from = -1;
    int to = -1;
    if (Status s = FindVertex(engine, m.robot_from, m.session_from, m.key_from, "from", &from);
        !s.ok()) {
      return s;
    }
    if (Status s = FindVertex(engine, m.robot_to, m.session_to, m.key_to, "to", &to); !s.ok()) {
      return s;
    }
    Pose measurement;
    typename Pose::Matrix information;
    IRRR_CHECK(PoseFromWire(m.measurement, "measurement", &measurement).ok());
    IRRR_CHECK(InformationFromWire<Pose>(m.information, "information", &information).ok());
    int edge = -1;
    if (Status s = engine.irrr.AddLoop(from, to, measurement, information, &edge); !s.ok()) {
      return Status::Error("key_to: " + s.message());
    }
    Hypothesis h;
    h.sender = m.header.sender;
    h.id = m.hypothesis_id;
    h.robot_from = m.robot_from;
    h.session_from = m.session_from;
    h.key_from = m.key_from;
    h.robot_to = m.robot_to;
    h.session_to = m.session_to;
    h.key_to = m.key_to;
    engine.hypothesis_of_edge.emplace(edge, h);
    hypotheses.emplace(std::make_pair(h.sender, h.id), HypothesisRef{WireDim<Pose>(), edge});
    hypothesis_order.push_back(HypothesisRef{WireDim<Pose>(), edge});
    std::lock_guard<std::mutex> lock(stats_mutex);
    stats.n_hypotheses = static_cast<int64_t>(hypothesis_order.size());
    return Status::Ok();
  }

  Status ApplySessionEvent(const session_event_t& m) {
    if (m.event == session_event_t::FLUSH) {
      se2.irrr.Flush();
      se3.irrr.Flush();
      return Status::Ok();
    }
    if (m.event != session_event_t::END) return Status::Ok();
    const auto it = sessions.find({m.robot_id, m.session_id});
    if (it == sessions.end()) {
      return Status::Error("session_id: END of an unknown session (robot " +
                           std::to_string(m.robot_id) + ", session " +
                           std::to_string(m.session_id) + ")");
    }
    const Status s = it->second.dim == keyframe_t::DIM_SE2 ? se2.irrr.EndSession(it->second.index)
                                                           : se3.irrr.EndSession(it->second.index);
    return s.ok() ? s : Status::Error("event: " + s.message());
  }

  // ---- Inputs that arrive before what they refer to ----

  using KeyName = std::tuple<int32_t, int32_t, int64_t>;  // (robot, session, key)
  std::map<KeyName, std::vector<Input>> parked;           // by the keyframe they wait for
  int64_t num_parked = 0;

  template <class Pose>
  static int64_t LastKeyOf(const Engine<Pose>& engine, int session) {
    const auto& vertices = engine.irrr.graph().session(session).vertices;
    return engine.KeyOf(session, static_cast<int>(vertices.size()) - 1);
  }

  // The last key of a known session (false: no keyframe of it yet).
  bool LastKey(int32_t robot, int32_t session, int64_t* last) const {
    const auto it = sessions.find({robot, session});
    if (it == sessions.end()) return false;
    *last = it->second.dim == keyframe_t::DIM_SE2 ? LastKeyOf(se2, it->second.index)
                                                  : LastKeyOf(se3, it->second.index);
    return true;
  }

  // The keyframe `input` waits for: a keyframe beyond the next key of its session waits for the
  // one before it, a loop for each of its ends.
  bool Awaited(const Input& input, KeyName* awaited) const {
    int64_t last = 0;
    if (input.kind == Input::Kind::kKeyframe) {
      const keyframe_t& m = input.keyframe;
      if (!LastKey(m.robot_id, m.session_id, &last) || m.key <= last + 1) return false;
      *awaited = {m.robot_id, m.session_id, m.key - 1};
      return true;
    }
    if (input.kind != Input::Kind::kLoop) return false;
    const loop_hypothesis_t& m = input.loop;
    for (const KeyName& end : {KeyName{m.robot_from, m.session_from, m.key_from},
                               KeyName{m.robot_to, m.session_to, m.key_to}}) {
      if (!LastKey(std::get<0>(end), std::get<1>(end), &last) || std::get<2>(end) > last) {
        *awaited = end;
        return true;
      }
    }
    return false;
  }

  void Park(const Input& input, const KeyName& awaited) {
    if (num_parked >= daemon.limits.max_parked) {
      Rejection r = input.kind == Input::Kind::kKeyframe
                        ? RejectionOf(daemon.channels.keyframe, input.keyframe)
                        : RejectionOf(daemon.channels.loop, input.loop);
      r.reason = "it refers to a keyframe not received yet, and daemon.limits.max_parked (" +
                 std::to_string(daemon.limits.max_parked) + ") inputs wait already: not applied";
      Reject(r);
      return;
    }
    spdlog::debug("parked an input until keyframe (robot {}, session {}, key {}) arrives",
                  std::get<0>(awaited),
                  std::get<1>(awaited),
                  std::get<2>(awaited));
    parked[awaited].push_back(input);
    ++num_parked;
    std::lock_guard<std::mutex> lock(stats_mutex);
    stats.n_parked = static_cast<int32_t>(num_parked);
  }

  // Applies `input`, then, in their arrival order, the parked inputs each keyframe it brings
  // releases; steps run after every input, as they would had everything arrived in order.
  void Apply(const Input& input) {
    std::deque<Input> ready{input};
    while (!ready.empty()) {
      const Input next = std::move(ready.front());
      ready.pop_front();
      KeyName awaited;
      if (Awaited(next, &awaited)) {
        Park(next, awaited);
        continue;
      }
      if (ApplyNow(next) && next.kind == Input::Kind::kKeyframe) {
        const auto it =
            parked.find({next.keyframe.robot_id, next.keyframe.session_id, next.keyframe.key});
        if (it != parked.end()) {
          num_parked -= static_cast<int64_t>(it->second.size());
          ready.insert(ready.begin(), it->second.begin(), it->second.end());
          parked.erase(it);
          std::lock_guard<std::mutex> lock(stats_mutex);
          stats.n_parked = static_cast<int32_t>(num_parked);
        }
      }
      if (!run_steps) continue;
      RunSteps(se2, next.received_utime);
      RunSteps(se3, next.received_utime);
    }
  }

  // Applies one input now; false if it was rejected.
  bool ApplyNow(const Input& input) {
    Status s = Status::Ok();
    switch (input.kind) {
      case Input::Kind::kKeyframe:
        s = AddKeyframe(input.keyframe);
        if (!s.ok()) Reject(RejectionOf(daemon.channels.keyframe, input.keyframe), s);
        break;
      case Input::Kind::kLoop:
        s = AddLoop(input.loop);
        if (!s.ok()) Reject(RejectionOf(daemon.channels.loop, input.loop), s);
        break;
      case Input::Kind::kSession:
        s = ApplySessionEvent(input.session);
        if (!s.ok()) Reject(RejectionOf(daemon.channels.session, input.session), s);
        break;
    }
    return s.ok();
  }

  template <class Pose>
  void RunSteps(Engine<Pose>& engine, int64_t closed_utime) {
    while (engine.irrr.HasPendingStep()) {
      const auto start = std::chrono::steady_clock::now();
      const StepResult step = engine.irrr.RunStep();
      const double decide_ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
              .count();
      PublishStep(engine, step, closed_utime, decide_ms);
    }
  }

  enum class Detail {
    kStep,      // transforms of the sessions touched, decisions changed
    kFull,      // + every pose of the sessions touched, every verdict whose statistic moved
    kComplete,  // + every verdict (the answer to a solution_request_t)
  };

  // Fills `c` (transforms of `touched`), `verdicts` and, unless kStep, `chunks` (every pose of
  // `touched`) for one engine. Verdicts: those whose state, cluster or step changed since last
  // published, or, when `full`, whose statistic changed too (accepted links are re-tested at
  // every step, so their chi2 moves all the time; a full correction brings them up to date).
  template <class Pose>
  void Describe(Engine<Pose>& engine,
                const std::vector<int>& touched,
                Detail detail,
                correction_t* c,
                std::vector<verdicts_t>* verdicts,
                std::vector<solution_t>* chunks,
                int* state_changes) {
    const bool full = detail != Detail::kStep;
    const Irrr<Pose>& irrr = engine.irrr;
    const std::vector<Pose>& estimate = irrr.estimate();
    const MapFrames<Pose> frames = FramesOf(engine);
    const std::vector<int>& component_of = frames.component_of;
    // A component is named by the creation order of its earliest session (MapFrames).
    auto component_name = [&](int s) {
      return engine.sessions[frames.anchor[component_of[s]]].order;
    };
    for (int s : touched) {
      const auto& vertices = irrr.graph().session(s).vertices;
      const int component = component_name(s);
      session_transform_t transform{};
      transform.robot_id = engine.sessions[s].name.first;
      transform.session_id = engine.sessions[s].name.second;
      transform.component = component;
      const int last = vertices.back();
      transform.map_T_odom =
          PoseToWire(frames.InMap(s, estimate[last]) * engine.odom_pose[last].Inverse());
      transform.latest_key = engine.KeyOf(s, static_cast<int>(vertices.size()) - 1);
      c->sessions.push_back(transform);
      LogMembership(engine, s, component);
      for (size_t begin = 0; full && begin < vertices.size(); begin += solution_t::MAX_POSES) {
        const size_t end = std::min(vertices.size(), begin + solution_t::MAX_POSES);
        solution_t chunk{};
        chunk.solution_id = c->solution_id;
        chunk.chunk_index = static_cast<int32_t>(chunks->size());
        chunk.robot_id = transform.robot_id;
        chunk.session_id = transform.session_id;
        chunk.component = component;
        chunk.first_key = engine.KeyOf(s, static_cast<int>(begin));
        for (size_t k = begin; k < end; ++k) {
          chunk.poses.push_back(PoseToWire(frames.InMap(s, estimate[vertices[k]])));
        }
        chunk.n_poses = static_cast<int32_t>(chunk.poses.size());
        chunks->push_back(std::move(chunk));
      }
    }
    c->n_sessions = static_cast<int32_t>(c->sessions.size());

    Counts counts;
    counts.components = static_cast<int>(frames.anchor.size());
    for (const auto& [edge, h] : engine.hypothesis_of_edge) {
      const LoopDecision& d = irrr.decision(edge);
      counts.accepted += d.state == LoopState::kAccepted ? 1 : 0;
      counts.rejected += d.state != LoopState::kAccepted && d.state != LoopState::kPending ? 1 : 0;
      auto it = engine.published.find(edge);
      const bool known = it != engine.published.end();
      const bool decision_changed = !known || it->second.state != d.state ||
                                    it->second.cluster != d.cluster || it->second.step != d.step;
      if (!decision_changed && !(full && !SameDecision(it->second, d)) &&
          detail != Detail::kComplete) {
        continue;
      }
      *state_changes += !known || it->second.state != d.state ? 1 : 0;
      engine.published[edge] = d;
      if (verdicts->empty() || verdicts->back().n_verdicts >= verdicts_t::MAX_VERDICTS) {
        verdicts_t chunk{};
        chunk.solution_id = c->solution_id;
        chunk.chunk_index = static_cast<int32_t>(verdicts->size());
        verdicts->push_back(std::move(chunk));
      }
      verdict_t v{};
      v.sender = h.sender;
      v.hypothesis_id = h.id;
      v.robot_from = h.robot_from;
      v.session_from = h.session_from;
      v.key_from = h.key_from;
      v.robot_to = h.robot_to;
      v.session_to = h.session_to;
      v.key_to = h.key_to;
      v.cluster = d.cluster;
      v.state = LoopStateToWire(d.state);
      v.step = d.step;
      v.chi2 = d.chi2;
      v.threshold = d.threshold;
      verdicts_t& chunk = verdicts->back();
      chunk.verdicts.push_back(std::move(v));
      chunk.n_verdicts = static_cast<int32_t>(chunk.verdicts.size());
    }
    std::lock_guard<std::mutex> lock(stats_mutex);
    EngineCounts<Pose>() = counts;
  }

  // Logs a session joining another's map, or splitting off into its own frame.
  template <class Pose>
  void LogMembership(Engine<Pose>& engine, int s, int anchor) {
    if (anchor == engine.anchor[s]) return;
    const SessionName name = engine.sessions[s].name;
    if (anchor == engine.sessions[s].order) {
      spdlog::info(
          "session (robot {}, session {}) split off into its own frame", name.first, name.second);
    } else {
      spdlog::info(
          "session (robot {}, session {}) joined the map of session (robot {}, session {})",
          name.first,
          name.second,
          session_names[anchor].first,
          session_names[anchor].second);
    }
    engine.anchor[s] = anchor;
  }

  void PublishAll(correction_t* c,
                  std::vector<verdicts_t>* verdicts,
                  std::vector<solution_t>* chunks) {
    c->n_verdict_chunks = static_cast<int32_t>(verdicts->size());
    c->n_pose_chunks = static_cast<int32_t>(chunks->size());
    c->published_utime = NowUtime();
    Publish(daemon.channels.correction, c);
    for (verdicts_t& chunk : *verdicts) Publish(daemon.channels.verdicts, &chunk);
    for (solution_t& chunk : *chunks) Publish(daemon.channels.solution, &chunk);
  }

  // After each step: its decisions (state changes) and the new transforms of the sessions it
  // touched. The poses follow in the next full correction (Refresh).
  template <class Pose>
  void PublishStep(Engine<Pose>& engine,
                   const StepResult& step,
                   int64_t closed_utime,
                   double decide_ms) {
    correction_t c{};
    c.solution_id = ++solution_id;
    c.daemon_start_utime = start_utime;
    c.step = step.step;
    c.cluster = step.cluster;
    c.closed_utime = closed_utime;
    c.solves = step.solves;
    c.decide_ms = static_cast<float>(decide_ms);
    c.chi2 = step.final_summary.final_chi2;
    std::vector<verdicts_t> verdicts;
    std::vector<solution_t> chunks;
    int state_changes = 0;
    Describe(engine, step.sessions, Detail::kStep, &c, &verdicts, &chunks, &state_changes);
    engine.dirty.insert(step.sessions.begin(), step.sessions.end());
    PublishAll(&c, &verdicts, &chunks);

    const double latency_ms = 1e-3 * static_cast<double>(c.published_utime - closed_utime);
    const Counts& counts = EngineCounts<Pose>();
    spdlog::log(
        replaying ? spdlog::level::debug : spdlog::level::info,
        "step {} (cluster {}): {} decision(s) changed, {} accepted and {} rejected or reversed in "
        "all; {} "
        "session(s) re-estimated; decided in {:.1f} ms ({} solves, variance factor {:.4g}), "
        "published {:.1f} ms after the cluster closed",
        step.step,
        step.cluster,
        state_changes,
        counts.accepted,
        counts.rejected,
        c.n_sessions,
        decide_ms,
        step.solves,
        step.variance_factor,
        latency_ms);
    std::lock_guard<std::mutex> lock(stats_mutex);
    stats.solution_id = c.solution_id;
    stats.last_step_latency_ms = static_cast<float>(latency_ms);
    stats.variance_factor = static_cast<float>(step.variance_factor);
    ++stats.n_steps;
  }

  // A full correction (step -1): every pose of the sessions re-estimated since the last one, and
  // every verdict brought up to date. Sent when the worker has caught up with its input, and at
  // least every kRefreshPeriod while it is behind, so that a map is never older than that.
  void Refresh() {
    last_refresh = std::chrono::steady_clock::now();
    if (se2.dirty.empty() && se3.dirty.empty()) return;
    PublishWhole(Detail::kFull);
  }

  // A complete correction: every session's poses and every verdict (complete = 1), for a consumer
  // that asked (solution_request_t) or after recovery from the journal.
  void PublishComplete() { PublishWhole(Detail::kComplete); }

  // kFull: the sessions re-estimated since the last full correction; kComplete: every session.
  void PublishWhole(Detail detail) {
    correction_t c{};
    c.solution_id = ++solution_id;
    c.daemon_start_utime = start_utime;
    c.step = -1;
    c.cluster = -1;
    c.closed_utime = NowUtime();
    c.complete = detail == Detail::kComplete ? 1 : 0;
    std::vector<verdicts_t> verdicts;
    std::vector<solution_t> chunks;
    int state_changes = 0;
    auto sessions_of = [detail](const auto& engine) {
      if (detail != Detail::kComplete)
        return std::vector<int>(engine.dirty.begin(), engine.dirty.end());
      std::vector<int> indices(engine.sessions.size());
      for (size_t k = 0; k < indices.size(); ++k) indices[k] = static_cast<int>(k);
      return indices;
    };
    Describe(se2, sessions_of(se2), detail, &c, &verdicts, &chunks, &state_changes);
    Describe(se3, sessions_of(se3), detail, &c, &verdicts, &chunks, &state_changes);
    se2.dirty.clear();
    se3.dirty.clear();
    PublishAll(&c, &verdicts, &chunks);
    std::lock_guard<std::mutex> lock(stats_mutex);
    stats.solution_id = c.solution_id;
  }

  // ---- Snapshots (snapshot.h) ----

  // What a snapshot holds besides the engines' step states.
  struct Snapshot {
    std::string options;      // the irrr options it was decided under (JSON)
    int64_t records = 0;      // journal records it covers
    int64_t journal_crc = 0;  // their CRC (Journal::crc)
    int64_t solution_id = 0;
    int64_t steps = 0;            // status_t.n_steps
    std::vector<int> anchor_se2;  // Engine::anchor
    std::vector<int> anchor_se3;
    IrrrStepState<Pose2> se2;
    IrrrStepState<Pose3> se3;
  };

  std::string OptionsText() const { return IrrrOptionsToJson(options).dump(); }

  // Worker: the state after the journal's `records` records, whose CRC is `crc`.
  Status WriteSnapshot(int64_t records, uint32_t crc) {
    SnapshotWriter w;
    w.String(OptionsText());
    w.I64(records);
    w.I64(crc);
    w.I64(solution_id);
    {
      std::lock_guard<std::mutex> lock(stats_mutex);
      w.I64(stats.n_steps);
    }
    w.Ints(se2.anchor);
    w.StepState(se2.irrr.StepState());
    w.Ints(se3.anchor);
    w.StepState(se3.irrr.StepState());
    if (Status s = WriteSnapshotFile(snapshot_path, w.bytes(), daemon.journal.fsync); !s.ok()) {
      return s;
    }
    snapshot_at = records;
    snapshot_bytes = static_cast<int64_t>(w.bytes().size());
    return Status::Ok();
  }

  // Reads the snapshot at `path` and checks that it fits `recovery` (the journal it was taken
  // from, at least as far as it covers) and the current options. False, with the reason in
  // `why`, when there is none or it cannot be used.
  bool LoadSnapshot(const std::string& path,
                    const JournalRecovery& recovery,
                    Snapshot* out,
                    std::string* why) const {
    std::vector<uint8_t> body;
    bool exists = false;
    if (Status s = ReadSnapshotFile(path, &body, &exists); !s.ok() || !exists) {
      *why = s.ok() ? "" : s.message();
      return false;
    }
    SnapshotReader r(body);
    Snapshot& snap = *out;
    if (!r.String(&snap.options) || !r.I64(&snap.records) || !r.I64(&snap.journal_crc) ||
        !r.I64(&snap.solution_id) || !r.I64(&snap.steps) || !r.Ints(&snap.anchor_se2) ||
        !r.StepState(&snap.se2) || !r.Ints(&snap.anchor_se3) || !r.StepState(&snap.se3) ||
        !r.at_end()) {
      *why = path + ": its body does not decode";
      return false;
    }
    if (snap.options != OptionsText()) {
      *why = path + " was taken under other irrr options: the journal is decided again under these";
      return false;
    }
    if (snap.records < 0 || static_cast<size_t>(snap.records) > recovery.records.size() ||
        JournalCrc(recovery.records, static_cast<size_t>(snap.records)) !=
            static_cast<uint32_t>(snap.journal_crc)) {
      *why = path + " covers " + std::to_string(snap.records) +
             " journal records that are not those of the journal (" +
             std::to_string(recovery.records.size()) + " records)";
      return false;
    }
    return true;
  }

  // After the inputs the snapshot covers were fed without their steps.
  Status RestoreSnapshot(Snapshot snap) {
    if (snap.anchor_se2.size() != se2.sessions.size() ||
        snap.anchor_se3.size() != se3.sessions.size()) {
      return Status::Error("its sessions are not the journal's");
    }
    if (Status s = se2.irrr.RestoreStepState(std::move(snap.se2)); !s.ok()) return s;
    if (Status s = se3.irrr.RestoreStepState(std::move(snap.se3)); !s.ok()) return s;
    se2.anchor = std::move(snap.anchor_se2);
    se3.anchor = std::move(snap.anchor_se3);
    solution_id = snap.solution_id;
    snapshot_at = snap.records;
    std::lock_guard<std::mutex> lock(stats_mutex);
    stats.n_steps = snap.steps;
    return Status::Ok();
  }

  // Feeds journal records [begin, end) through Apply (steps as `run_steps` says); counts the
  // next seq of every sender in `senders_next`. Returns the records applied.
  int64_t Replay(const JournalRecovery& recovery,
                 size_t begin,
                 size_t end,
                 const std::string& path,
                 std::map<std::string, int64_t>* senders_next) {
    int64_t applied = 0;
    for (size_t k = begin; k < end; ++k) {
      const JournalRecord& record = recovery.records[k];
      Input input;
      if (!DecodeInput(
              record.kind, record.bytes.data(), static_cast<int>(record.bytes.size()), &input)) {
        spdlog::error("journal {}: record {} does not decode (skipped)", path, k);
        continue;
      }
      input.received_utime = record.received_utime;
      int64_t& next = (*senders_next)[input.header().sender];
      next = std::max(next, input.header().seq + 1);
      Apply(input);
      ++applied;
    }
    return applied;
  }

  std::string journal_error;     // the latest journal failure (stats_mutex)
  std::set<std::string> rivals;  // other daemons heard on our correction channel (stats_mutex)

  static constexpr std::chrono::milliseconds kRefreshPeriod{250};
  std::chrono::steady_clock::time_point last_refresh = std::chrono::steady_clock::now();

  // Per engine: accepted, rejected, components (for status_t).
  struct Counts {
    int64_t accepted = 0;
    int64_t rejected = 0;
    int components = 0;
  };
  Counts counts_se2;
  Counts counts_se3;
  template <class Pose>
  Counts& EngineCounts() {
    if constexpr (std::is_same_v<Pose, Pose2>) {
      return counts_se2;
    } else {
      return counts_se3;
    }
  }
};

Service::Service(const DaemonOptions& daemon, const IrrrOptions& options, MessageSink* sink)
    : state_(std::make_unique<State>(daemon, options, sink)) {}

Service::~Service() = default;

bool Service::Receive(const std::string& channel, const uint8_t* data, int size) {
  State& st = *state_;
  const DaemonChannels& ch = st.daemon.channels;
  if (channel == ch.correction) {
    // Ours come back over multicast; another daemon's means two owners of one stream.
    correction_t correction;
    if (!DecodeMessage(data, size, &correction) ||
        correction.header.sender == st.daemon.daemon_id) {
      return false;
    }
    const std::string rival = correction.header.sender.substr(0, kMaxSenderBytes);
    st.WarnOnce("rival",
                rival,
                "daemon \"" + rival + "\" also publishes on " + ch.correction +
                    ": give each daemon its own output channels (README, \"Fleets\")");
    std::lock_guard<std::mutex> lock(st.stats_mutex);
    if (st.rivals.size() < 16) st.rivals.insert(rival);
    return false;
  }
  if (channel == ch.solution_request) {
    solution_request_t request;
    if (!DecodeMessage(data, size, &request)) return false;
    spdlog::debug("\"{}\" asks for the whole solution ({})", request.header.sender, request.reason);
    st.solution_requested = true;
    WakeWorker();
    return false;
  }
  JournalRecord::Kind kind;
  std::string type;
  if (channel == ch.keyframe) {
    kind = JournalRecord::kKeyframe, type = "keyframe_t";
  } else if (channel == ch.loop) {
    kind = JournalRecord::kLoop, type = "loop_hypothesis_t";
  } else if (channel == ch.session) {
    kind = JournalRecord::kSession, type = "session_event_t";
  } else {
    return false;
  }
  auto reject_undecodable = [&](const std::string& why) {
    {
      std::lock_guard<std::mutex> lock(st.stats_mutex);
      ++st.stats.n_undecodable;
    }
    Rejection r;
    r.channel = channel;
    r.reason = why + " (expected irrr." + type + ")";
    st.Reject(r);
    return false;
  };
  if (size > st.daemon.limits.max_message_bytes) {
    return reject_undecodable(std::to_string(size) + " bytes, more than daemon.limits." +
                              "max_message_bytes (" +
                              std::to_string(st.daemon.limits.max_message_bytes) + ")");
  }
  Input input;
  if (!DecodeInput(kind, data, size, &input)) return reject_undecodable("cannot decode");
  input.received_utime = NowUtime();
  input.bytes.assign(data, data + size);
  return st.Admit(std::move(input));
}

void Service::Tick() { state_->Tick(); }

void Service::SetJournal(Journal* journal) {
  state_->journal = journal;
  state_->snapshot_path = journal != nullptr && state_->daemon.journal.snapshot_every > 0
                              ? journal->path() + ".snapshot"
                              : "";
}

Status Service::WriteSnapshot() {
  State& st = *state_;
  if (st.journal == nullptr || st.snapshot_path.empty()) {
    return Status::Error("snapshots are off (no journal, or daemon.journal.snapshot_every 0)");
  }
  {
    std::lock_guard<std::mutex> lock(st.stats_mutex);
    if (!st.journal_error.empty()) {
      return Status::Error("the journal lacks inputs that were applied (" + st.journal_error +
                           "): no snapshot would match it");
    }
  }
  const auto start = std::chrono::steady_clock::now();
  if (Status s = st.WriteSnapshot(st.journal->records(), st.journal->crc()); !s.ok()) return s;
  spdlog::info(
      "snapshot of the first {} inputs ({:.2f} MB) written to {} in {:.1f} ms",
      st.journal->records(),
      1e-6 * static_cast<double>(st.snapshot_bytes),
      st.snapshot_path,
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count());
  return Status::Ok();
}

void Service::Recover(const JournalRecovery& recovery, const std::string& path) {
  const auto start = std::chrono::steady_clock::now();
  state_->replaying = true;
  std::map<std::string, int64_t> next_seq;
  // A snapshot spares the steps of the inputs it covers: they are fed without them, then it
  // is restored; only the inputs after it run their steps.
  size_t from = 0;
  std::string snapshot_note;
  {
    State::Snapshot snapshot;
    std::string why;
    const std::string snapshot_path = path + ".snapshot";
    if (state_->LoadSnapshot(snapshot_path, recovery, &snapshot, &why)) {
      const size_t covered = static_cast<size_t>(snapshot.records);
      state_->run_steps = false;
      state_->Replay(recovery, 0, covered, path, &next_seq);
      state_->run_steps = true;
      if (Status s = state_->RestoreSnapshot(std::move(snapshot)); s.ok()) {
        from = covered;
        snapshot_note =
            "restored the snapshot of the first " + std::to_string(covered) + " inputs, then ";
      } else {
        why = snapshot_path + ": " + s.message();
        // Start again from nothing, without it.
        const State& st = *state_;
        auto fresh = std::make_unique<State>(st.daemon, st.options, st.sink);
        fresh->journal = st.journal;
        fresh->snapshot_path = st.snapshot_path;
        state_ = std::move(fresh);
        state_->replaying = true;
        next_seq.clear();
      }
    }
    if (!why.empty()) spdlog::warn("snapshot not used: {}", why);
  }
  State& st = *state_;
  const int64_t applied = st.Replay(recovery, from, recovery.records.size(), path, &next_seq);
  st.replaying = false;
  {
    std::lock_guard<std::mutex> lock(st.sequencer_mutex);
    for (const auto& [sender, next] : next_seq) st.sequencer.Resume(sender, next);
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::string text = snapshot_note + "replayed " + std::to_string(applied) + " inputs from " +
                     path + " in " + fmt::format("{:.2f}", seconds) + " s";
  if (recovery.dropped_bytes > 0) {
    text += "; dropped " + std::to_string(recovery.dropped_bytes) + " bytes at its end (" +
            recovery.dropped_reason + ")";
    spdlog::warn("journal {}: dropped {} bytes at offset {}: {} (a write torn by a crash)",
                 path,
                 recovery.dropped_bytes,
                 recovery.valid_bytes,
                 recovery.dropped_reason);
  }
  spdlog::info("journal {}: {}; {} steps, {} hypotheses",
               path,
               text,
               st.stats.n_steps,
               st.hypothesis_order.size());
  {
    std::lock_guard<std::mutex> lock(st.stats_mutex);
    st.stats.n_recovered = static_cast<int64_t>(recovery.records.size());
    st.stats.recovery = text;
  }
  st.PublishComplete();
}

int Service::ProcessQueued(std::chrono::milliseconds wait) {
  State& st = *state_;
  std::deque<Input> batch;
  {
    std::unique_lock<std::mutex> lock(st.queue_mutex);
    st.queue_changed.wait_for(lock, wait, [&] { return !st.queue.empty() || st.wake; });
    st.wake = false;
    batch.swap(st.queue);
  }
  if (st.journal != nullptr && !batch.empty()) {
    std::vector<JournalRecord> records;
    records.reserve(batch.size());
    for (const Input& input : batch) {
      records.push_back({JournalKind(input.kind), input.received_utime, input.bytes});
    }
    if (Status s = st.journal->Append(records); !s.ok()) {
      spdlog::error("journal: {} (inputs are applied but not kept)", s.message());
      std::lock_guard<std::mutex> lock(st.stats_mutex);
      st.journal_error = s.message();
    }
  }
  for (const Input& input : batch) {
    st.Apply(input);
    --st.unapplied;
    if (st.unapplied.load() == 0 ||
        std::chrono::steady_clock::now() - st.last_refresh >= State::kRefreshPeriod) {
      st.Refresh();
    }
  }
  if (st.solution_requested.exchange(false)) st.PublishComplete();
  if (!st.snapshot_path.empty() &&
      st.journal->records() - st.snapshot_at >= st.daemon.journal.snapshot_every) {
    if (Status s = WriteSnapshot(); !s.ok()) {
      spdlog::error("snapshot: {} (a restart replays more of the journal)", s.message());
      st.snapshot_at = st.journal->records();  // tried; not again before another period
    }
  }
  return static_cast<int>(batch.size());
}

void Service::WakeWorker() {
  std::lock_guard<std::mutex> lock(state_->queue_mutex);
  state_->wake = true;
  state_->queue_changed.notify_all();
}

int Service::QueueDepth() const { return state_->unapplied.load(); }

status_t Service::CurrentStatus() const {
  const State& st = *state_;
  const int depth = QueueDepth();
  std::map<std::string, StreamCounts> streams;
  int64_t held = 0;
  {
    std::lock_guard<std::mutex> lock(st.sequencer_mutex);
    streams = st.sequencer.Counts();
    held = st.sequencer.total_held();
  }
  std::lock_guard<std::mutex> lock(st.stats_mutex);
  status_t status = st.stats;
  status.daemon_id = st.daemon.daemon_id;
  status.start_utime = st.start_utime;
  status.queue_depth = depth;
  status.queue_limit = st.daemon.limits.queue_limit;
  status.n_accepted = st.counts_se2.accepted + st.counts_se3.accepted;
  status.n_rejected = st.counts_se2.rejected + st.counts_se3.rejected;
  status.n_components = st.counts_se2.components + st.counts_se3.components;
  for (const auto& [name, count] : st.senders) {
    sender_count_t c = count;
    if (const auto it = streams.find(name); it != streams.end()) {
      const StreamCounts& s = it->second;
      c.next_seq = s.next_seq;
      c.last_seq = s.last_seq;
      c.held = static_cast<int32_t>(s.held);
      c.gaps = s.gaps;
      c.requested = s.requested;
      c.given_up = s.given_up;
      c.duplicates = s.duplicates;
    }
    status.senders.push_back(c);
  }
  status.n_senders = static_cast<int32_t>(status.senders.size());
  // DEGRADED: a limit is reached (inputs are being refused) or the journal cannot be written.
  std::vector<std::string> reasons;
  const DaemonLimits& limits = st.daemon.limits;
  if (depth >= limits.queue_limit * 9 / 10) reasons.push_back("queue at 90% of queue_limit");
  if (status.n_sessions >= limits.max_sessions) reasons.push_back("max_sessions reached");
  if (status.n_keyframes >= limits.max_keyframes) reasons.push_back("max_keyframes reached");
  if (status.n_hypotheses >= limits.max_hypotheses) reasons.push_back("max_hypotheses reached");
  if (status.n_parked >= limits.max_parked) reasons.push_back("max_parked reached");
  if (held >= limits.max_held) reasons.push_back("max_held reached");
  if (!st.journal_error.empty()) reasons.push_back("journal: " + st.journal_error);
  for (const std::string& rival : st.rivals) {
    reasons.push_back("daemon \"" + rival + "\" also publishes on " +
                      st.daemon.channels.correction);
  }
  for (const std::string& r : reasons) {
    status.degraded_reason += (status.degraded_reason.empty() ? "" : "; ") + r;
  }
  return status;
}

void Service::PublishStatus(int8_t state) {
  State& st = *state_;
  status_t status = CurrentStatus();
  status.state = state;
  if (state == status_t::RUNNING && !status.degraded_reason.empty()) {
    status.state = status_t::DEGRADED;
  }
  st.Publish(st.daemon.channels.status, &status);
}

std::vector<HypothesisDecision> Service::Decisions() const {
  const State& st = *state_;
  std::vector<HypothesisDecision> out;
  out.reserve(st.hypothesis_order.size());
  for (const State::HypothesisRef& ref : st.hypothesis_order) {
    const bool se2 = ref.dim == keyframe_t::DIM_SE2;
    const Hypothesis& h =
        se2 ? st.se2.hypothesis_of_edge.at(ref.edge) : st.se3.hypothesis_of_edge.at(ref.edge);
    out.push_back(
        {h.sender, h.id, se2 ? st.se2.irrr.decision(ref.edge) : st.se3.irrr.decision(ref.edge)});
  }
  return out;
}

namespace {

template <class Pose>
void AppendEstimates(const Engine<Pose>& engine,
                     std::vector<std::pair<int, Service::SessionEstimate>>* out) {
  const MapFrames<Pose> frames = FramesOf(engine);
  for (size_t s = 0; s < engine.sessions.size(); ++s) {
    Service::SessionEstimate e;
    e.robot_id = engine.sessions[s].name.first;
    e.session_id = engine.sessions[s].name.second;
    e.first_key = engine.sessions[s].first_key;
    e.dim = WireDim<Pose>();
    for (int v : engine.irrr.graph().session(static_cast<int>(s)).vertices) {
      e.poses.push_back(PoseToWire(frames.InMap(static_cast<int>(s), engine.irrr.estimate()[v])));
    }
    out->emplace_back(engine.sessions[s].order, std::move(e));
  }
}

}  // namespace

std::vector<Service::SessionEstimate> Service::Estimates() const {
  std::vector<std::pair<int, SessionEstimate>> ordered;
  AppendEstimates(state_->se2, &ordered);
  AppendEstimates(state_->se3, &ordered);
  std::sort(ordered.begin(), ordered.end(), [](const auto& a, const auto& b) {
    return a.first < b.first;
  });
  std::vector<SessionEstimate> out;
  for (auto& [order, e] : ordered) out.push_back(std::move(e));
  return out;
}

}  // namespace irrr
