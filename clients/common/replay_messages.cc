#include "clients/common/replay_messages.h"

#include <cmath>
#include <map>
#include <utility>

#include "core/irrr.h"
#include "daemon/wire.h"

namespace irrr {

template <class Pose>
std::vector<ReplayMessage> ReplayMessages(const PoseGraph<Pose>& graph,
                                          const std::vector<int>& graph_edge_of_file_edge,
                                          int32_t robot_id) {
  std::vector<int> odometry_into(graph.num_vertices(), -1);
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kOdometry) odometry_into[graph.edge(e).to] = e;
  }
  std::vector<int> file_edge_of_graph_edge(graph.num_edges(), -1);
  for (size_t k = 0; k < graph_edge_of_file_edge.size(); ++k) {
    file_edge_of_graph_edge[graph_edge_of_file_edge[k]] = static_cast<int>(k);
  }
  std::vector<ReplayMessage> out;
  double stamp = 0.0;
  for (const ArrivalEvent& event : ArrivalOrder(graph)) {
    ReplayMessage m;
    switch (event.kind) {
      case ArrivalEvent::Kind::kPose: {
        const Vertex& v = graph.vertex(event.index);
        stamp = v.stamp;
        m.kind = ReplayMessage::Kind::kKeyframe;
        keyframe_t& k = m.keyframe;
        k.robot_id = robot_id;
        k.session_id = static_cast<int32_t>(graph.session(v.session).id);
        k.key = v.id;
        k.stamp_utime = std::llround(v.stamp * 1e6);
        k.dim = WireDim<Pose>();
        k.odom_pose = PoseToWire(graph.initial_estimate()[event.index]);
        const int odometry = odometry_into[event.index];
        k.has_odom_edge = odometry >= 0;
        if (odometry >= 0) {
          k.odom_delta = PoseToWire(graph.edge(odometry).measurement);
          InformationToWire<Pose>(graph.edge(odometry).information, k.information);
        } else {
          k.odom_delta = PoseToWire(Pose());
        }
        break;
      }
      case ArrivalEvent::Kind::kLoop: {
        const Edge<Pose>& e = graph.edge(event.index);
        const Vertex& from = graph.vertex(e.from);
        const Vertex& to = graph.vertex(e.to);
        m.kind = ReplayMessage::Kind::kLoop;
        loop_hypothesis_t& l = m.loop;
        l.hypothesis_id = file_edge_of_graph_edge[event.index];
        l.robot_from = robot_id;
        l.session_from = static_cast<int32_t>(graph.session(from.session).id);
        l.key_from = from.id;
        l.robot_to = robot_id;
        l.session_to = static_cast<int32_t>(graph.session(to.session).id);
        l.key_to = to.id;
        l.dim = WireDim<Pose>();
        l.measurement = PoseToWire(e.measurement);
        InformationToWire<Pose>(e.information, l.information);
        l.score = 1.0f;
        break;
      }
      case ArrivalEvent::Kind::kEndSession: {
        m.kind = ReplayMessage::Kind::kSession;
        session_event_t& s = m.session;
        const Session& session = graph.session(event.index);
        s.event = session_event_t::END;
        s.robot_id = robot_id;
        s.session_id = static_cast<int32_t>(session.id);
        s.last_key = graph.vertex(session.vertices.back()).id;
        s.last_hypothesis_id = -1;
        break;
      }
      case ArrivalEvent::Kind::kFlush:  // ArrivalOrder gives none
        m.kind = ReplayMessage::Kind::kSession;
        m.session.event = session_event_t::FLUSH;
        break;
    }
    m.stamp = stamp;
    out.push_back(std::move(m));
  }
  return out;
}

std::vector<ReplayMessage> MergeByStamp(const std::vector<std::vector<ReplayMessage>>& lists) {
  std::vector<ReplayMessage> out;
  std::vector<size_t> next(lists.size(), 0);
  for (;;) {
    int best = -1;
    for (size_t k = 0; k < lists.size(); ++k) {
      if (next[k] >= lists[k].size()) continue;
      if (best < 0 || lists[k][next[k]].stamp < lists[best][next[best]].stamp) {
        best = static_cast<int>(k);
      }
    }
    if (best < 0) return out;
    out.push_back(lists[best][next[best]++]);
  }
}

bool AssignRobots(const std::vector<int32_t>& robot_of_session,
                  int32_t only_robot,
                  std::vector<ReplayMessage>* messages) {
  auto robot_of = [&](int32_t session, int32_t* robot) {
    if (session < 0 || static_cast<size_t>(session) >= robot_of_session.size()) return false;
    *robot = robot_of_session[static_cast<size_t>(session)];
    return true;
  };
  std::map<std::pair<int32_t, int64_t>, double> stamp_of;  // (session, key) -> arrival ordinal
  std::vector<ReplayMessage> kept;
  for (ReplayMessage m : *messages) {
    switch (m.kind) {
      case ReplayMessage::Kind::kKeyframe:
        if (!robot_of(m.keyframe.session_id, &m.keyframe.robot_id)) return false;
        stamp_of[{m.keyframe.session_id, m.keyframe.key}] = m.stamp;
        m.sender_robot = m.keyframe.robot_id;
        break;
      case ReplayMessage::Kind::kLoop: {
        loop_hypothesis_t& l = m.loop;
        if (!robot_of(l.session_from, &l.robot_from) || !robot_of(l.session_to, &l.robot_to)) {
          return false;
        }
        const bool from_later =
            stamp_of[{l.session_from, l.key_from}] > stamp_of[{l.session_to, l.key_to}];
        m.sender_robot = from_later ? l.robot_from : l.robot_to;
        break;
      }
      case ReplayMessage::Kind::kSession:
        if (m.session.event != session_event_t::FLUSH &&
            !robot_of(m.session.session_id, &m.session.robot_id)) {
          return false;
        }
        m.sender_robot = m.session.robot_id;
        break;
    }
    if (only_robot < 0 || m.sender_robot == only_robot) kept.push_back(m);
  }
  *messages = std::move(kept);
  return true;
}

ReplayMessage FlushMessage() {
  ReplayMessage m;
  m.kind = ReplayMessage::Kind::kSession;
  m.session.event = session_event_t::FLUSH;
  m.session.last_key = -1;
  m.session.last_hypothesis_id = -1;
  return m;
}

MessageSequencer::MessageSequencer(std::string sender, DaemonChannels channels)
    : sender_(std::move(sender)), channels_(std::move(channels)) {}

MessageSequencer::Encoded MessageSequencer::Encode(ReplayMessage message, int64_t utime) {
  const int64_t seq = static_cast<int64_t>(history_.size());
  switch (message.kind) {
    case ReplayMessage::Kind::kKeyframe:
      message.keyframe.header = {utime, seq, sender_};
      history_.emplace_back(channels_.keyframe, EncodeMessage(message.keyframe));
      break;
    case ReplayMessage::Kind::kLoop:
      message.loop.header = {utime, seq, sender_};
      history_.emplace_back(channels_.loop, EncodeMessage(message.loop));
      break;
    case ReplayMessage::Kind::kSession:
      message.session.header = {utime, seq, sender_};
      history_.emplace_back(channels_.session, EncodeMessage(message.session));
      break;
  }
  return history_.back();
}

MessageSequencer::Encoded MessageSequencer::Progress(int32_t robot_id,
                                                     int32_t session_id,
                                                     int64_t utime) {
  ReplayMessage m;
  m.kind = ReplayMessage::Kind::kSession;
  m.session.event = session_event_t::PROGRESS;
  m.session.robot_id = robot_id;
  m.session.session_id = session_id;
  m.session.last_key = -1;
  m.session.last_hypothesis_id = -1;
  return Encode(m, utime);
}

SenderFleet::SenderFleet(const std::string& sender,
                         const DaemonChannels& channels,
                         int32_t first_robot,
                         int num_robots)
    : first_robot_(first_robot) {
  for (int r = 0; r < num_robots; ++r) {
    const std::string name =
        num_robots == 1 ? sender : sender + "/robot" + std::to_string(first_robot + r);
    senders_.emplace_back(name, channels);
    names_.push_back(name);
  }
}

MessageSequencer::Encoded SenderFleet::Encode(const ReplayMessage& message, int64_t utime) {
  int32_t robot = message.session.robot_id;
  if (message.kind == ReplayMessage::Kind::kKeyframe) robot = message.keyframe.robot_id;
  if (message.kind == ReplayMessage::Kind::kLoop) robot = message.loop.robot_from;
  if (message.sender_robot >= 0) robot = message.sender_robot;
  const bool flush = message.kind == ReplayMessage::Kind::kSession &&
                     message.session.event == session_event_t::FLUSH;
  return senders_[flush ? 0 : robot - first_robot_].Encode(message, utime);
}

MessageSequencer::Encoded SenderFleet::Progress(int64_t utime) {
  return senders_[0].Progress(first_robot_, 0, utime);
}

const MessageSequencer* SenderFleet::Find(const std::string& name) const {
  for (const MessageSequencer& s : senders_) {
    if (s.name() == name) return &s;
  }
  return nullptr;
}

template std::vector<ReplayMessage> ReplayMessages<Pose2>(const PoseGraph<Pose2>&,
                                                          const std::vector<int>&,
                                                          int32_t);
template std::vector<ReplayMessage> ReplayMessages<Pose3>(const PoseGraph<Pose3>&,
                                                          const std::vector<int>&,
                                                          int32_t);

}  // namespace irrr
