// Service, the receiving thread: a message decoded and checked, put in its sender's order
// (sequencer.h) and, with daemon.merge, in stamp order (stamp_merger.h), then queued for the
// worker; lost inputs re-requested (service_state.h).

#include <chrono>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include <spdlog/spdlog.h>

#include "daemon/service_state.h"
#include "irrr/correction_t.hpp"
#include "irrr/resync_request_t.hpp"
#include "irrr/solution_request_t.hpp"

namespace irrr {

bool Service::State::Admit(Input input) {
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

bool Service::State::Take(Input&& input) {
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

void Service::State::Enqueue(Input&& input) {
  std::lock_guard<std::mutex> lock(queue_mutex);
  queue.push_back(std::move(input));
  queue_changed.notify_one();
}

void Service::State::Merge(Input&& input) {
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

void Service::State::ReleaseMerged(std::chrono::steady_clock::time_point now) {
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

void Service::State::Tick() {
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
                    ": give each daemon its own output channels (docs/fleets.md)");
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

}  // namespace irrr
