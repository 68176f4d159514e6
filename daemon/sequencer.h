#ifndef IRRR_DAEMON_SEQUENCER_H_
#define IRRR_DAEMON_SEQUENCER_H_

// Puts each sender's messages back into the order it published them (header.seq, one counter per
// sender over all its channels), so that the daemon applies exactly the sequence the producer
// sent whatever the network lost, duplicated or reordered:
//  - the next expected seq is taken at once, with every held message that follows it;
//  - a later seq is held (at most `max_held` over all senders) and opens a gap;
//  - a seq taken already is a duplicate, ignored;
//  - an open gap is re-requested every `interval`, and given up on after `give_up` (the stream
//    then goes on from the next held message; what arrives of the gap later is a duplicate).
// A sender's first message is expected to be seq 0 (or Resume's value, after recovery). Single
// threaded: the daemon's receiving thread owns it.

#include <chrono>
#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace irrr {

struct SequencerLimits {
  int64_t max_held = 100000;
  std::chrono::milliseconds interval{200};
  std::chrono::milliseconds give_up{5000};
};

// Counters of one sender's stream (status_t's sender_count_t).
struct StreamCounts {
  int64_t next_seq = 0;    // every seq below is taken
  int64_t last_seq = -1;   // highest seen
  int64_t held = 0;        // waiting for an earlier seq
  int64_t gaps = 0;        // seqs found missing
  int64_t requested = 0;   // seqs re-requested (each request of a range counts its length)
  int64_t given_up = 0;    // seqs never received, skipped after give_up
  int64_t duplicates = 0;  // seqs taken already, ignored
};

template <class Message>
class Sequencer {
 public:
  using Clock = std::chrono::steady_clock;
  enum class Outcome {
    kTaken,      // taken, with the held messages it released
    kHeld,       // waiting for an earlier seq
    kDuplicate,  // taken already, ignored
    kHoldFull,   // would be held, but max_held messages wait already: dropped (re-requested later)
    kRefused,    // `take` refused it (the receiver is full): dropped, re-requested later
  };
  struct Request {
    std::string sender;
    std::vector<std::pair<int64_t, int64_t>> ranges;  // inclusive
  };

  explicit Sequencer(SequencerLimits limits) : limits_(limits) {}

  // Offers message `seq` of `sender`. `take(Message&&)` is called for it and then for every held
  // message that follows in order; it returns false when the receiver cannot take one now (that
  // message is dropped and the stream waits for its resend).
  template <class Take>
  Outcome Offer(
      const std::string& sender, int64_t seq, Message message, Clock::time_point now, Take take) {
    Stream& s = streams_[sender];
    s.counts.last_seq = std::max(s.counts.last_seq, seq);
    if (seq < s.counts.next_seq || s.held.count(seq) != 0) {
      ++s.counts.duplicates;
      return Outcome::kDuplicate;
    }
    if (seq > s.counts.next_seq) {
      if (total_held_ >= limits_.max_held) return Outcome::kHoldFull;
      if (s.held.empty() || seq > s.held.rbegin()->first) {
        // Newly found missing: between the highest known seq and this one.
        const int64_t known = s.held.empty() ? s.counts.next_seq - 1 : s.held.rbegin()->first;
        s.counts.gaps += seq - known - 1;
      }
      if (s.held.empty()) s.gap_since = now;
      s.held.emplace(seq, std::move(message));
      ++total_held_;
      s.counts.held = static_cast<int64_t>(s.held.size());
      return Outcome::kHeld;
    }
    if (!take(std::move(message))) return Outcome::kRefused;
    ++s.counts.next_seq;
    Release(&s, now, take);
    return Outcome::kTaken;
  }

  // Re-requests due now: per sender with an open gap, its missing ranges, at most once per
  // `interval` (the first at once).
  std::vector<Request> DueRequests(Clock::time_point now) {
    std::vector<Request> due;
    for (auto& [sender, s] : streams_) {
      if (s.held.empty() || now - s.last_request < limits_.interval) continue;
      Request r{sender, {}};
      int64_t from = s.counts.next_seq;
      for (const auto& held : s.held) {
        if (held.first > from) r.ranges.emplace_back(from, held.first - 1);
        from = held.first + 1;
      }
      for (const auto& [first, last] : r.ranges) s.counts.requested += last - first + 1;
      s.last_request = now;
      due.push_back(std::move(r));
    }
    return due;
  }

  // Gives up on gaps open longer than `give_up`: the stream goes on from its next held message
  // (handed to `take`). Returns, per sender, the ranges skipped.
  template <class Take>
  std::vector<Request> GiveUp(Clock::time_point now, Take take) {
    std::vector<Request> skipped;
    for (auto& [sender, s] : streams_) {
      if (s.held.empty() || now - s.gap_since < limits_.give_up) continue;
      const int64_t first_held = s.held.begin()->first;
      skipped.push_back({sender, {{s.counts.next_seq, first_held - 1}}});
      s.counts.given_up += first_held - s.counts.next_seq;
      s.counts.next_seq = first_held;
      Release(&s, now, take);
    }
    return skipped;
  }

  // After recovery: every seq of `sender` below `next_seq` was taken before.
  void Resume(const std::string& sender, int64_t next_seq) {
    Stream& s = streams_[sender];
    s.counts.next_seq = std::max(s.counts.next_seq, next_seq);
    s.counts.last_seq = std::max(s.counts.last_seq, next_seq - 1);
  }

  std::map<std::string, StreamCounts> Counts() const {
    std::map<std::string, StreamCounts> out;
    for (const auto& [sender, s] : streams_) out.emplace(sender, s.counts);
    return out;
  }
  int64_t total_held() const { return total_held_; }

 private:
  struct Stream {
    StreamCounts counts;
    std::map<int64_t, Message> held;
    Clock::time_point gap_since{};
    Clock::time_point last_request{};
  };

  // Hands over the held messages that now follow in order.
  template <class Take>
  void Release(Stream* s, Clock::time_point now, Take& take) {
    while (!s->held.empty() && s->held.begin()->first == s->counts.next_seq) {
      if (!take(std::move(s->held.begin()->second))) {
        // Refused: drop it; the gap it leaves is re-requested.
        s->held.erase(s->held.begin());
        --total_held_;
        break;
      }
      s->held.erase(s->held.begin());
      --total_held_;
      ++s->counts.next_seq;
    }
    if (!s->held.empty()) s->gap_since = now;
    s->counts.held = static_cast<int64_t>(s->held.size());
  }

  SequencerLimits limits_;
  std::map<std::string, Stream> streams_;
  int64_t total_held_ = 0;
};

}  // namespace irrr

#endif  // IRRR_DAEMON_SEQUENCER_H_
