#ifndef IRRR_DAEMON_SERVICE_H_
#define IRRR_DAEMON_SERVICE_H_

// The iRRR service: what irrrd does, without the process around it (LCM sockets, signals,
// threads). Raw messages come in through Receive (the receiving thread: decode, check the fields,
// queue; never waits for optimization), each sender's in the order of its header.seq
// (sequencer.h: lost ones re-requested, duplicates ignored); ProcessQueued (the worker thread)
// applies them in arrival order to core's Irrr, one per pose type, runs the steps whose clusters
// closed, and publishes a correction after each step. Everything it publishes goes to a MessageSink
// (LCM in the daemon, a list in tests).
//
// Identity on the wire: a session is (robot_id, session_id), a pose (robot_id, session_id, key),
// a hypothesis (sender, hypothesis_id). A session's pose type is that of its first keyframe.
// An input the service does not take is answered on the error channel (error_t), logged and
// counted; nothing else is affected.

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "core/irrr.h"
#include "daemon/common/irrr_config.h"
#include "daemon/journal.h"
#include "irrr/keyframe_t.hpp"
#include "irrr/loop_hypothesis_t.hpp"
#include "irrr/session_event_t.hpp"
#include "irrr/status_t.hpp"

namespace irrr {

// Where the service's messages go. Send may be called from both threads at once.
class MessageSink {
 public:
  virtual ~MessageSink() = default;
  virtual void Send(const std::string& channel, const std::vector<uint8_t>& bytes) = 0;
};

// The decision about one hypothesis as the service reports it (tests, the final summary).
struct HypothesisDecision {
  std::string sender;
  int64_t hypothesis_id = -1;
  LoopDecision decision;
};

class Service {
 public:
  // `daemon` and `options` must be valid (ParseDaemonConfig); `sink` outlives the service.
  Service(const DaemonOptions& daemon, const IrrrOptions& options, MessageSink* sink);
  ~Service();
  Service(const Service&) = delete;
  Service& operator=(const Service&) = delete;

  // Receiving thread. Decodes one message of an input channel, checks its fields and queues it
  // (or answers an error). Returns true if the message asks for an immediate status (a session
  // PROGRESS). A correction_t on its own correction channel from another daemon_id means two
  // daemons share one output stream: logged once, and the status says DEGRADED with its name.
  bool Receive(const std::string& channel, const uint8_t* data, int size);

  // Receiving thread, every few milliseconds: re-requests what senders' sequence numbers show
  // missing (resync_request_t, every resync.interval_ms) and gives up on gaps older than
  // resync.give_up_ms.
  void Tick();

  // Before the threads start: appends every input to `journal` (not owned; null: none) before
  // applying it, and replays what a journal held (Journal::Open) to rebuild the state it had,
  // publishing nothing but one complete correction at the end; status_t.recovery says so.
  // With daemon.journal.snapshot_every > 0 the worker also writes a snapshot of the state
  // (snapshot.h) to "<journal>.snapshot" every that many inputs; Recover uses it when it matches
  // the journal and the options, and otherwise replays everything (and says why). With
  // daemon.journal.compact_mb > 0 the worker compacts the journal once it grows past that: the
  // whole state to "<journal>.base", the journal started again after it. Recover starts from the
  // base when there is one; it fails only when the journal was compacted and its base cannot be
  // used (the inputs before the journal are gone).
  void SetJournal(Journal* journal);
  Status Recover(const JournalRecovery& recovery, const std::string& path);
  // Worker thread (or after it stopped): writes a snapshot now (irrrd does at a clean stop).
  Status WriteSnapshot();

  // Worker thread. Waits up to `wait` for input, then applies everything queued, in arrival
  // order, running and publishing every step that becomes due. Returns the inputs applied.
  int ProcessQueued(std::chrono::milliseconds wait);
  // Makes a waiting ProcessQueued return at once.
  void WakeWorker();

  // Publishes a status_t with the given state (status_t::RUNNING, ...). Any thread.
  void PublishStatus(int8_t state);
  status_t CurrentStatus() const;
  int QueueDepth() const;

  // Worker thread (or after it stopped): every hypothesis received, in arrival order, with its
  // decision, and the estimate of every pose, by (robot, session) then key.
  std::vector<HypothesisDecision> Decisions() const;
  struct SessionEstimate {
    int32_t robot_id = 0;
    int32_t session_id = 0;
    int64_t first_key = 0;
    int8_t dim = 0;
    std::vector<pose_t> poses;  // key first_key + i, in its component's frame
  };
  std::vector<SessionEstimate> Estimates() const;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

}  // namespace irrr

#endif  // IRRR_DAEMON_SERVICE_H_
