// Service, the worker: each input applied to core's Irrr of its pose type (keyframes, loops,
// session events), inputs that refer to a keyframe not received yet parked until it arrives, and
// the steps that become due run and published (service_state.h).

#include <algorithm>
#include <chrono>
#include <deque>
#include <iterator>
#include <mutex>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <spdlog/spdlog.h>

#include "daemon/service_state.h"

namespace irrr {
namespace {

template <class Pose>
int64_t LastKeyOf(const Engine<Pose>& engine, int session) {
  const auto& vertices = engine.irrr.graph().session(session).vertices;
  return engine.KeyOf(session, static_cast<int>(vertices.size()) - 1);
}

}  // namespace

Status Service::State::AddKeyframe(const keyframe_t& m) {
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
Status Service::State::AddKeyframeTo(Engine<Pose>& engine, const keyframe_t& m, SessionRef* ref) {
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

template <class Pose>
Status Service::State::FindVertex(const Engine<Pose>& engine,
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

Status Service::State::AddLoop(const loop_hypothesis_t& m) {
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
Status Service::State::AddLoopTo(Engine<Pose>& engine, const loop_hypothesis_t& m) {
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

Status Service::State::ApplySessionEvent(const session_event_t& m) {
  if (m.event == session_event_t::FLUSH) {
    se2.irrr.Flush();
    se3.irrr.Flush();
    return Status::Ok();
  }
  if (m.event != session_event_t::END) return Status::Ok();
  const auto it = sessions.find({m.robot_id, m.session_id});
  if (it == sessions.end()) {
    return Status::Error("session_id: END of an unknown session (robot " +
                         std::to_string(m.robot_id) + ", session " + std::to_string(m.session_id) +
                         ")");
  }
  const Status s = it->second.dim == keyframe_t::DIM_SE2 ? se2.irrr.EndSession(it->second.index)
                                                         : se3.irrr.EndSession(it->second.index);
  return s.ok() ? s : Status::Error("event: " + s.message());
}

bool Service::State::LastKey(int32_t robot, int32_t session, int64_t* last) const {
  const auto it = sessions.find({robot, session});
  if (it == sessions.end()) return false;
  *last = it->second.dim == keyframe_t::DIM_SE2 ? LastKeyOf(se2, it->second.index)
                                                : LastKeyOf(se3, it->second.index);
  return true;
}

bool Service::State::Awaited(const Input& input, KeyName* awaited) const {
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

void Service::State::Park(const Input& input, const KeyName& awaited) {
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

void Service::State::Apply(const Input& input) {
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

bool Service::State::ApplyNow(const Input& input) {
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
void Service::State::RunSteps(Engine<Pose>& engine, int64_t closed_utime) {
  while (engine.irrr.HasPendingStep()) {
    const auto start = std::chrono::steady_clock::now();
    const StepResult step = engine.irrr.RunStep();
    const double decide_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
    steps_s_since_snapshot += 1e-3 * decide_ms;
    PublishStep(engine, step, closed_utime, decide_ms);
  }
}

// Also run when a base's inputs are decided again (service_recovery.cc).
template void Service::State::RunSteps(Engine<Pose2>& engine, int64_t closed_utime);
template void Service::State::RunSteps(Engine<Pose3>& engine, int64_t closed_utime);

int Service::ProcessQueued(std::chrono::milliseconds wait) {
  State& st = *state_;
  // The most inputs taken (and journaled) at once: a crash leaves at most these journaled but not
  // applied, and a restart decides them before it listens again.
  constexpr size_t kMaxBatch = 256;
  std::deque<Input> batch;
  {
    std::unique_lock<std::mutex> lock(st.queue_mutex);
    st.queue_changed.wait_for(lock, wait, [&] { return !st.queue.empty() || st.wake; });
    st.wake = false;
    const auto end = st.queue.begin() + std::min(st.queue.size(), kMaxBatch);
    batch.assign(std::make_move_iterator(st.queue.begin()), std::make_move_iterator(end));
    st.queue.erase(st.queue.begin(), end);
  }
  // The journal's records and CRC after each input of the batch (snapshots within it).
  int64_t records_before = 0;
  std::vector<uint32_t> crc_after;
  if (st.journal != nullptr && !batch.empty()) {
    std::vector<JournalRecord> records;
    records.reserve(batch.size());
    for (const Input& input : batch) {
      records.push_back({JournalKind(input.kind), input.received_utime, input.bytes});
    }
    records_before = st.journal->records();
    if (Status s = st.journal->Append(records, &crc_after); !s.ok()) {
      spdlog::error("journal: {} (inputs are applied but not kept)", s.message());
      std::lock_guard<std::mutex> lock(st.stats_mutex);
      st.journal_error = s.message();
    } else {
      for (const Input& input : batch) st.Journaled(input);
    }
  }
  for (size_t k = 0; k < batch.size(); ++k) {
    st.Apply(batch[k]);
    --st.unapplied;
    if (st.unapplied.load() == 0 ||
        std::chrono::steady_clock::now() - st.last_refresh >= State::kRefreshPeriod) {
      st.Refresh();
    }
    if (k < crc_after.size()) {
      st.SnapshotIfDue(records_before + static_cast<int64_t>(k) + 1, crc_after[k]);
    }
  }
  // Every record journaled is applied now: where the journal may start again.
  if (!batch.empty()) st.CompactIfDue();
  if (st.solution_requested.exchange(false)) st.PublishComplete();
  return static_cast<int>(batch.size());
}

void Service::State::SnapshotIfDue(int64_t records, uint32_t crc) {
  const DaemonJournal& every = daemon.journal;
  const bool due = records - snapshot_at >= every.snapshot_every ||
                   (every.snapshot_after_s > 0 && steps_s_since_snapshot >= every.snapshot_after_s);
  if (snapshot_path.empty() || records <= snapshot_at || !due) return;
  if (Status s = SnapshotAt(records, crc); !s.ok()) {
    spdlog::error("snapshot: {} (a restart replays more of the journal)", s.message());
    snapshot_at = records;  // tried; not again before another period
    steps_s_since_snapshot = 0.0;
  }
}

void Service::WakeWorker() {
  std::lock_guard<std::mutex> lock(state_->queue_mutex);
  state_->wake = true;
  state_->queue_changed.notify_all();
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

}  // namespace irrr
