#ifndef IRRR_DAEMON_SERVICE_STATE_H_
#define IRRR_DAEMON_SERVICE_STATE_H_

// The state behind Service (service.h), shared by the files that implement it, one concern each:
//   service_receive.cc  receiving thread: decode, check, sender order (sequencer.h), queue
//   service_apply.cc    worker: inputs applied to core's Irrr (one per pose type), steps run
//   service_publish.cc  corrections, verdicts and poses published after steps
//   service_status.cc   status_t, limits (DEGRADED), rejections answered on the error channel
//   service_recovery.cc the journal replayed and snapshots written and restored at start
// Private to the daemon: nothing outside daemon/service*.cc includes it.
//
// Threads: the receiving thread owns the sequencer and merger (under sequencer_mutex) and feeds
// the queue (queue_mutex); the worker owns the engines and everything marked "worker". Counters
// for status_t are under stats_mutex; Publish may be called from both.

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

#include "core/irrr.h"
#include "daemon/common/irrr_config.h"
#include "daemon/inputs.h"
#include "daemon/journal.h"
#include "daemon/sequencer.h"
#include "daemon/service.h"
#include "daemon/snapshot.h"
#include "daemon/stamp_merger.h"
#include "daemon/wire.h"
#include "irrr/correction_t.hpp"
#include "irrr/solution_t.hpp"
#include "irrr/status_t.hpp"
#include "irrr/verdicts_t.hpp"

namespace irrr {

using SessionName = std::pair<int32_t, int32_t>;  // (robot_id, session_id)

// A loop hypothesis as the wire names it.
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

// The map frames of `engine`'s current estimate (service_publish.cc; Pose2 and Pose3).
template <class Pose>
MapFrames<Pose> FramesOf(const Engine<Pose>& engine);

struct Service::State {
  State(const DaemonOptions& d, const IrrrOptions& o, MessageSink* s);

  const DaemonOptions daemon;
  const IrrrOptions options;
  MessageSink* const sink;
  Journal* journal = nullptr;
  // While the journal is replayed at start: nothing is published, old errors are not logged again.
  std::atomic<bool> replaying{false};
  // Off while the inputs a snapshot covers are fed again: their steps are in the snapshot.
  bool run_steps = true;
  std::string snapshot_path;     // "" = no snapshots
  int64_t snapshot_at = 0;       // journal records the last snapshot covers
  int64_t snapshot_bytes = 0;    // the last snapshot body's size
  std::string base_path;         // "" = no compaction
  int64_t compact_at_bytes = 0;  // the journal size that triggers the next compaction
  int64_t base_at = 0;           // journal records the base covers (0: none)
  // Worker: each sender's next seq after the journal's records (what a base holds, and what a
  // restart resumes the sequencer from), counted by Journaled.
  std::map<std::string, int64_t> journaled_next;
  void Journaled(const Input& input);
  // Worker: the steps' time since the last snapshot (journal.snapshot_after_s).
  double steps_s_since_snapshot = 0.0;

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
    s.variance_estimate = 1.0f;
    return s;
  }();
  std::map<std::string, sender_count_t> senders;

  // Outgoing sequence number (one counter over all channels, as header_t says).
  std::mutex publish_mutex;
  int64_t next_seq = 0;

  // Worker only.
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

  // Encodes `message` with our header (daemon_id, the next seq, now) and sends it; nothing while
  // the journal is replayed. Any thread.
  template <class Message>
  void Publish(const std::string& channel, Message* message) {
    if (replaying) return;
    std::lock_guard<std::mutex> lock(publish_mutex);
    message->header.utime = NowUtime();
    message->header.seq = next_seq++;
    message->header.sender = daemon.daemon_id;
    sink->Send(channel, EncodeMessage(*message));
  }

  // ---- Status, limits and answers (service_status.cc) ----

  // The counters of `sender`, created at first use. Requires stats_mutex.
  sender_count_t& SenderLocked(const std::string& sender);
  // Logs `r`, counts it and answers it on the error channel.
  void Reject(const Rejection& r);
  // The same with field and reason taken from `s` ("<field>: <reason>").
  void Reject(Rejection r, const Status& s);
  // Counts an input from a sender or robot outside the allow-lists; logged once per sender.
  void Ignore(const std::string& sender, const char* why);
  // Logs `text` the first time `sender` does something of `kind` (at most kMaxWarned pairs are
  // remembered, so that a flood of sender names cannot grow this without bound).
  void WarnOnce(const char* kind, const std::string& sender, const std::string& text);
  std::mutex warned_mutex;
  std::set<std::pair<std::string, std::string>> warned;  // (kind, sender)

  // ---- Receiving thread (service_receive.cc) ----

  // A decoded input: who sent it, then its place in the sender's order (sequencer.h). Returns
  // true if it asks for an immediate status (a session PROGRESS).
  bool Admit(Input input);
  // An input in its sender's order: checked, then queued for the worker. False (the sequencer
  // waits for a resend) only when the queue is full.
  bool Take(Input&& input);
  void Enqueue(Input&& input);
  // daemon.merge: holds `input` until its stamp's turn (under sequencer_mutex).
  void Merge(Input&& input);
  void ReleaseMerged(std::chrono::steady_clock::time_point now);
  // Re-requests open gaps and gives up on old ones (the receiving thread, every few ms).
  void Tick();

  // ---- Worker: inputs applied to the engines (service_apply.cc) ----

  Status AddKeyframe(const keyframe_t& m);
  template <class Pose>
  Status AddKeyframeTo(Engine<Pose>& engine, const keyframe_t& m, SessionRef* ref);
  // The Irrr vertex of (robot, session, key) of `engine`, or an error naming `which` end.
  template <class Pose>
  Status FindVertex(const Engine<Pose>& engine,
                    int32_t robot,
                    int32_t session,
                    int64_t key,
                    const std::string& which,
                    int* vertex) const;
  Status AddLoop(const loop_hypothesis_t& m);
  template <class Pose>
  Status AddLoopTo(Engine<Pose>& engine, const loop_hypothesis_t& m);
  Status ApplySessionEvent(const session_event_t& m);

  // Inputs that arrive before what they refer to wait for it.
  using KeyName = std::tuple<int32_t, int32_t, int64_t>;  // (robot, session, key)
  std::map<KeyName, std::vector<Input>> parked;           // by the keyframe they wait for
  int64_t num_parked = 0;
  // The last key of a known session (false: no keyframe of it yet).
  bool LastKey(int32_t robot, int32_t session, int64_t* last) const;
  // The keyframe `input` waits for: a keyframe beyond the next key of its session waits for the
  // one before it, a loop for each of its ends.
  bool Awaited(const Input& input, KeyName* awaited) const;
  void Park(const Input& input, const KeyName& awaited);
  // Applies `input`, then, in their arrival order, the parked inputs each keyframe it brings
  // releases; steps run after every input, as they would had everything arrived in order.
  void Apply(const Input& input);
  // Applies one input now; false if it was rejected.
  bool ApplyNow(const Input& input);
  // Runs every step that is due, publishing each (PublishStep).
  template <class Pose>
  void RunSteps(Engine<Pose>& engine, int64_t closed_utime);

  // ---- Publishing (service_publish.cc) ----

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
                int* state_changes);
  // Logs a session joining another's map, or splitting off into its own frame.
  template <class Pose>
  void LogMembership(Engine<Pose>& engine, int s, int anchor);
  void PublishAll(correction_t* c,
                  std::vector<verdicts_t>* verdicts,
                  std::vector<solution_t>* chunks);
  // After each step: its decisions (state changes) and the new transforms of the sessions it
  // touched. The poses follow in the next full correction (Refresh).
  template <class Pose>
  void PublishStep(Engine<Pose>& engine,
                   const StepResult& step,
                   int64_t closed_utime,
                   double decide_ms);
  // A full correction (step -1): every pose of the sessions re-estimated since the last one, and
  // every verdict brought up to date. Sent when the worker has caught up with its input, and at
  // least every kRefreshPeriod while it is behind, so that a map is never older than that.
  void Refresh();
  // A complete correction: every session's poses and every verdict (complete = 1), for a consumer
  // that asked (solution_request_t) or after recovery from the journal.
  void PublishComplete();
  // kFull: the sessions re-estimated since the last full correction; kComplete: every session.
  void PublishWhole(Detail detail);
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

  // ---- Journal and snapshots (service_recovery.cc; snapshot.h) ----

  // What a snapshot holds besides the engines' step states (and a base's step part).
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
  std::string OptionsText() const;
  // What a snapshot and a base begin with: the options, the journal records they cover and
  // their CRC, the solution id and the steps run.
  void WriteHeader(int64_t records, uint32_t crc, SnapshotWriter* w) const;
  static bool ReadHeader(SnapshotReader* r, Snapshot* snap);
  // Worker: the state after the journal's `records` records, whose CRC is `crc`.
  Status WriteSnapshot(int64_t records, uint32_t crc);
  // The same after checking that snapshots are on and the journal holds every input applied;
  // logs what it wrote.
  Status SnapshotAt(int64_t records, uint32_t crc);
  // Worker, after each input applied: a snapshot when journal.snapshot_every inputs or
  // journal.snapshot_after_s seconds of steps have passed since the last one. `records` and
  // `crc` name the journal's prefix applied so far.
  void SnapshotIfDue(int64_t records, uint32_t crc);
  // Reads the snapshot at `path` and checks that it fits `recovery` (the journal it was taken
  // from, at least as far as it covers) and the current options. False, with the reason in
  // `why`, when there is none or it cannot be used.
  bool LoadSnapshot(const std::string& path,
                    const JournalRecovery& recovery,
                    Snapshot* out,
                    std::string* why) const;
  // After the inputs the snapshot covers were fed without their steps.
  Status RestoreSnapshot(Snapshot snap);
  // Feeds journal records [begin, end) (indices into recovery.records) through Apply (steps as
  // `run_steps` says), counting each sender's next seq in journaled_next. Returns the records
  // applied.
  int64_t Replay(const JournalRecovery& recovery,
                 size_t begin,
                 size_t end,
                 const std::string& path);

  // ---- The base and compaction (service_recovery.cc) ----

  // Worker, after a batch is applied: when the journal has grown past journal.compact_mb, the
  // whole state goes to the base and the journal starts again after it (Journal::Compact).
  void CompactIfDue();
  // With journal.keep_compacted, the name the journal's records are kept under when it is
  // compacted now ("<journal>.<first>-<end>"); otherwise "".
  std::string ArchiveName() const;
  // The whole state after the journal's `records` records, whose CRC is `crc`: the service's
  // tables, each engine's inputs (SnapshotWriter::Inputs) and step state.
  Status WriteBase(int64_t records, uint32_t crc);
  template <class Pose>
  void WriteEngine(const Engine<Pose>& engine, SnapshotWriter* w) const;
  // Into this State, fresh: the base at `path`, if it fits `recovery` (its records end at or
  // after the base's, and their CRC up to it is the base's). The tables and the engines' inputs
  // are restored; the step part goes to `steps`, for RestoreSnapshot unless a later snapshot
  // replaces it. A base taken under other irrr options has its inputs decided again, every step
  // run (`*decided_again`; its step part is then of no use). False, with the reason in `why` (""
  // when there is no base).
  bool LoadBase(const std::string& path,
                const JournalRecovery& recovery,
                Snapshot* steps,
                bool* decided_again,
                std::string* why);
  template <class Pose>
  bool ReadEngine(SnapshotReader* r,
                  Engine<Pose>* engine,
                  IrrrStepState<Pose>* steps,
                  bool decide_again);

  std::string journal_error;     // the latest journal failure (stats_mutex)
  std::set<std::string> rivals;  // other daemons heard on our correction channel (stats_mutex)
};

}  // namespace irrr

#endif  // IRRR_DAEMON_SERVICE_STATE_H_
