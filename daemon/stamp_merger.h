#ifndef IRRR_DAEMON_STAMP_MERGER_H_
#define IRRR_DAEMON_STAMP_MERGER_H_

// Applies several senders' inputs in the order of their stamps rather than in the order the
// network delivered them (daemon.merge; off by default). iRRR's decisions depend on the order in
// which clusters close, so two daemons that hear a fleet in different orders, or one that hears
// a robot late after a partition, could otherwise decide differently. With the merge, the order
// is a property of the data: the same inputs give the same sequence, as long as nothing arrives
// more than `window` late.
//
// Each sender's inputs come in its own order (sequencer.h) with non-decreasing stamps (a
// keyframe's stamp_utime; anything else carries its sender's latest). The merge hands over the
// input with the smallest (stamp, sender) once every other open sender has shown a larger stamp
// (or the same one, when it sorts after), or once it has waited `window`. A sender is open while it
// has sessions that have not ENDed (a robot that is done holds nobody back), or, if named in
// `expected`, from the start until it has been heard and closed. Single threaded, like the
// sequencer.

#include <chrono>
#include <cstdint>
#include <deque>
#include <limits>
#include <map>
#include <string>
#include <utility>
#include <vector>

namespace irrr {

template <class Message>
class StampMerger {
 public:
  using Clock = std::chrono::steady_clock;
  static constexpr int64_t kNoStamp = std::numeric_limits<int64_t>::min();

  StampMerger(std::chrono::milliseconds window, const std::vector<std::string>& expected)
      : window_(window) {
    for (const std::string& sender : expected) streams_[sender].open = true;
  }

  // The next input of `sender`: `stamp` its own (kNoStamp: none, it follows the sender's latest),
  // `open` whether the sender still has sessions open after it.
  void Add(
      const std::string& sender, int64_t stamp, bool open, Message message, Clock::time_point now) {
    Stream& s = streams_[sender];
    if (stamp != kNoStamp) s.latest = std::max(s.latest, stamp);
    s.open = open;
    s.waiting.push_back({std::move(message), s.latest, now});
    ++held_;
  }

  // Hands every input that may go now to `take`, in merged order. Returns how many were
  // released because they had waited `window` (their order is then arrival order).
  template <class Take>
  int Release(Clock::time_point now, Take take) {
    int late = 0;
    for (;;) {
      Stream* head = nullptr;
      const std::string* head_name = nullptr;
      for (auto& [name, s] : streams_) {
        if (s.waiting.empty()) continue;
        if (head == nullptr || s.waiting.front().stamp < head->waiting.front().stamp) {
          head = &s;
          head_name = &name;
        }
      }
      if (head == nullptr) return late;
      const Item& item = head->waiting.front();
      bool ready = true;
      for (const auto& [name, s] : streams_) {
        // A sender that may still send this stamp (inherited by its loops) and sorts first
        // is waited for too.
        if (&name != head_name && s.open && s.waiting.empty() &&
            (s.latest < item.stamp || (s.latest == item.stamp && name < *head_name))) {
          ready = false;
          break;
        }
      }
      if (!ready) {
        if (now - item.arrived < window_) return late;
        ++late;
      }
      take(std::move(head->waiting.front().message));
      head->waiting.pop_front();
      --held_;
    }
  }

  int64_t held() const { return held_; }

 private:
  struct Item {
    Message message;
    int64_t stamp;
    Clock::time_point arrived;
  };
  struct Stream {
    std::deque<Item> waiting;
    int64_t latest = kNoStamp;
    bool open = false;
  };

  std::chrono::milliseconds window_;
  std::map<std::string, Stream> streams_;  // by sender: ties of stamps go by name
  int64_t held_ = 0;
};

}  // namespace irrr

#endif  // IRRR_DAEMON_STAMP_MERGER_H_
