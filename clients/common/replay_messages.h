#ifndef IRRR_CLIENTS_COMMON_REPLAY_MESSAGES_H_
#define IRRR_CLIENTS_COMMON_REPLAY_MESSAGES_H_

// A pose-graph file as the LCM messages a robot's front end would have sent (irrr-inject, tests):
// keyframes, loop hypotheses and session ends in the arrival order of algorithm-notes ("Files as
// input", the order RunIncrementalIrrr replays), so that the daemon sees what irrr-batch --method
// irrr sees. Identities: robot `robot_id`; session = the graph's session id (0, 1, ...); key = the
// file's vertex id; hypothesis_id = the file's edge index; stamp_utime = the vertex ordinal x 1e6
// (so a daemon cluster_gap in seconds equals irrr-batch's in poses).

#include <cstdint>
#include <string>
#include <vector>

#include "core/graph_io.h"
#include "core/pose_graph.h"
#include "daemon/common/irrr_config.h"
#include "irrr/keyframe_t.hpp"
#include "irrr/loop_hypothesis_t.hpp"
#include "irrr/session_event_t.hpp"

namespace irrr {

// One message to send, not yet stamped with its header (see MessageSequencer).
struct ReplayMessage {
  enum class Kind { kKeyframe, kLoop, kSession };
  Kind kind = Kind::kKeyframe;
  double stamp = 0.0;         // the file's vertex ordinal it arrives with (merging several files)
  int32_t sender_robot = -1;  // the robot that sends it (-1: the robot it names; see SenderFleet)
  keyframe_t keyframe{};
  loop_hypothesis_t loop{};
  session_event_t session{};
};

// The messages of one graph (built from a file by BuildPoseGraph, which gave
// `graph_edge_of_file_edge`), in arrival order, each session's END included (no FLUSH).
template <class Pose>
std::vector<ReplayMessage> ReplayMessages(const PoseGraph<Pose>& graph,
                                          const std::vector<int>& graph_edge_of_file_edge,
                                          int32_t robot_id);

// Several robots' message lists merged by stamp (ties: the earlier list first), each list's
// order kept.
std::vector<ReplayMessage> MergeByStamp(const std::vector<std::vector<ReplayMessage>>& lists);

// A fleet in one multi-session file: session s (the graph's session id) belongs to robot
// `robot_of_session[s]`, which sends its keyframes and its END; a loop hypothesis is sent by the
// robot of its later pose (the one that recognised the place), and may join two robots. Sets the
// robot ids of `messages` (from ReplayMessages) accordingly and keeps those sent by `only_robot`
// (all with -1). False if a session has no robot.
bool AssignRobots(const std::vector<int32_t>& robot_of_session,
                  int32_t only_robot,
                  std::vector<ReplayMessage>* messages);

// A FLUSH session event.
ReplayMessage FlushMessage();

// Fills headers (sender, seq from 0 over all channels, utime) and encodes, as one sender
// publishes, and keeps every message it encoded so that it can resend them (resync_request_t).
class MessageSequencer {
 public:
  using Encoded = std::pair<std::string, std::vector<uint8_t>>;  // channel, bytes

  MessageSequencer(std::string sender, DaemonChannels channels);
  // The channel and the encoded bytes of `message`, stamped with `utime`.
  Encoded Encode(ReplayMessage message, int64_t utime);
  // A PROGRESS event for (robot, session) (asks the daemon for a status).
  Encoded Progress(int32_t robot_id, int32_t session_id, int64_t utime);
  // The message encoded with header.seq `seq` (which must be <= last_seq()), unchanged.
  const Encoded& Sent(int64_t seq) const { return history_[static_cast<size_t>(seq)]; }
  // The header.seq of the last message encoded (-1: none).
  int64_t last_seq() const { return static_cast<int64_t>(history_.size()) - 1; }
  const std::string& name() const { return sender_; }

 private:
  std::string sender_;
  DaemonChannels channels_;
  std::vector<Encoded> history_;
};

// One sender per robot, as a fleet's front ends would be: with one robot the sender is `sender`
// as given, with several "<sender>/robot<R>" (hypothesis ids are unique per sender, and each
// file numbers its own from 0). FLUSH and the progress requests go out as the first robot.
class SenderFleet {
 public:
  SenderFleet(const std::string& sender,
              const DaemonChannels& channels,
              int32_t first_robot,
              int num_robots);
  // Encodes `message` as the sender of its robot (sender_robot, else the robot it names).
  MessageSequencer::Encoded Encode(const ReplayMessage& message, int64_t utime);
  MessageSequencer::Encoded Progress(int64_t utime);
  const std::vector<std::string>& names() const { return names_; }
  const MessageSequencer& sender(size_t k) const { return senders_[k]; }
  // The sender named `name` (null: not one of ours).
  const MessageSequencer* Find(const std::string& name) const;

 private:
  int32_t first_robot_;
  std::vector<MessageSequencer> senders_;
  std::vector<std::string> names_;
};

}  // namespace irrr

#endif  // IRRR_CLIENTS_COMMON_REPLAY_MESSAGES_H_
