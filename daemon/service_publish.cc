// Service, publishing: after each step a correction with its decisions and the sessions'
// map-to-odometry transforms; full corrections with every pose of the sessions re-estimated; a
// complete one on request; the map frames they are expressed in (service_state.h).

#include <algorithm>
#include <cmath>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include <fmt/core.h>
#include <spdlog/spdlog.h>

#include "daemon/service_state.h"

namespace irrr {
namespace {

bool SameDecision(const LoopDecision& a, const LoopDecision& b) {
  auto same = [](double x, double y) { return x == y || (std::isnan(x) && std::isnan(y)); };
  return a.state == b.state && a.cluster == b.cluster && a.step == b.step && same(a.chi2, b.chi2) &&
         same(a.threshold, b.threshold);
}

}  // namespace

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

template MapFrames<Pose2> FramesOf(const Engine<Pose2>& engine);
template MapFrames<Pose3> FramesOf(const Engine<Pose3>& engine);

template <class Pose>
void Service::State::Describe(Engine<Pose>& engine,
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

template <class Pose>
void Service::State::LogMembership(Engine<Pose>& engine, int s, int anchor) {
  if (anchor == engine.anchor[s]) return;
  const SessionName name = engine.sessions[s].name;
  if (anchor == engine.sessions[s].order) {
    spdlog::info(
        "session (robot {}, session {}) split off into its own frame", name.first, name.second);
  } else {
    spdlog::info("session (robot {}, session {}) joined the map of session (robot {}, session {})",
                 name.first,
                 name.second,
                 session_names[anchor].first,
                 session_names[anchor].second);
  }
  engine.anchor[s] = anchor;
}

void Service::State::PublishAll(correction_t* c,
                                std::vector<verdicts_t>* verdicts,
                                std::vector<solution_t>* chunks) {
  c->n_verdict_chunks = static_cast<int32_t>(verdicts->size());
  c->n_pose_chunks = static_cast<int32_t>(chunks->size());
  c->published_utime = NowUtime();
  Publish(daemon.channels.correction, c);
  for (verdicts_t& chunk : *verdicts) Publish(daemon.channels.verdicts, &chunk);
  for (solution_t& chunk : *chunks) Publish(daemon.channels.solution, &chunk);
}

template <class Pose>
void Service::State::PublishStep(Engine<Pose>& engine,
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
  c.deferred = step.deferred;
  c.decide_ms = static_cast<float>(decide_ms);
  c.chi2 = step.chi2;
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
      "session(s) re-estimated; decided in {:.1f} ms ({} solves{}, variance factor {:.4g}{}), "
      "published {:.1f} ms after the cluster closed",
      step.step,
      step.cluster,
      state_changes,
      counts.accepted,
      counts.rejected,
      c.n_sessions,
      decide_ms,
      step.solves,
      step.deferred > 0 ? fmt::format(", {} deferred to later steps", step.deferred)
                        : std::string(),
      step.variance_factor,
      step.VarianceEstimateDiffers()
          ? fmt::format(", the data's estimate {:.4g}", step.variance_estimate)
          : std::string(),
      latency_ms);
  std::lock_guard<std::mutex> lock(stats_mutex);
  stats.solution_id = c.solution_id;
  stats.last_step_latency_ms = static_cast<float>(latency_ms);
  stats.variance_factor = static_cast<float>(step.variance_factor);
  stats.variance_estimate = static_cast<float>(step.variance_estimate);
  ++stats.n_steps;
}

void Service::State::Refresh() {
  last_refresh = std::chrono::steady_clock::now();
  if (se2.dirty.empty() && se3.dirty.empty()) return;
  PublishWhole(Detail::kFull);
}

void Service::State::PublishComplete() { PublishWhole(Detail::kComplete); }

void Service::State::PublishWhole(Detail detail) {
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

// RunSteps (service_apply.cc) publishes each step.
template void Service::State::PublishStep(Engine<Pose2>& engine,
                                          const StepResult& step,
                                          int64_t closed_utime,
                                          double decide_ms);
template void Service::State::PublishStep(Engine<Pose3>& engine,
                                          const StepResult& step,
                                          int64_t closed_utime,
                                          double decide_ms);

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
