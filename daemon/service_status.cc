// Service: status_t, the limits that make it DEGRADED, and rejections answered on the error
// channel (service_state.h).

#include <map>
#include <mutex>
#include <string>
#include <tuple>
#include <vector>

#include <spdlog/spdlog.h>

#include "daemon/service_state.h"
#include "irrr/error_t.hpp"

namespace irrr {

sender_count_t& Service::State::SenderLocked(const std::string& sender) {
  auto it = senders.find(sender);
  if (it == senders.end()) {
    sender_count_t count{};
    count.sender = sender;
    count.last_seq = -1;
    it = senders.emplace(sender, count).first;
  }
  return it->second;
}

void Service::State::Reject(const Rejection& r) {
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

void Service::State::Reject(Rejection r, const Status& s) {
  std::tie(r.field, r.reason) = FieldAndReason(s);
  Reject(r);
}

void Service::State::Ignore(const std::string& sender, const char* why) {
  {
    std::lock_guard<std::mutex> lock(stats_mutex);
    ++stats.n_ignored;
  }
  WarnOnce("ignored", sender, "ignoring input from \"" + sender + "\": it " + why);
}

void Service::State::WarnOnce(const char* kind,
                              const std::string& sender,
                              const std::string& text) {
  constexpr size_t kMaxWarned = 1000;
  std::lock_guard<std::mutex> lock(warned_mutex);
  if (warned.size() < kMaxWarned && warned.emplace(kind, sender).second) spdlog::warn(text);
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

}  // namespace irrr
