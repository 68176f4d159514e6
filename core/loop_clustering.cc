#include "core/loop_clustering.h"

#include <algorithm>
#include <cmath>

namespace irrr {

LoopClusterer::LoopClusterer(double time_gap, double max_span)
    : time_gap_(time_gap), max_span_(max_span) {
  IRRR_CHECK(time_gap >= 0.0 && max_span >= 0.0);
}

int LoopClusterer::AddLink(
    int link_id, int session_1, double stamp_1, int session_2, double stamp_2) {
  IRRR_CHECK(session_1 >= 0 && session_2 >= 0);
  // Orient: side a is the higher session, or the later pose of one session.
  const bool swap = session_2 > session_1 || (session_2 == session_1 && stamp_2 > stamp_1);
  const int session_a = swap ? session_2 : session_1;
  const int session_b = swap ? session_1 : session_2;
  const double t_a = swap ? stamp_2 : stamp_1;
  const double t_b = swap ? stamp_1 : stamp_2;

  int chosen = -1;
  for (int index : open_) {  // ascending: the oldest fitting cluster wins
    const LoopCluster& c = clusters_[index];
    if (c.session_a != session_a || c.session_b != session_b) continue;
    for (size_t m = 0; m < c.links.size(); ++m) {
      if (std::abs(t_a - c.stamps_a[m]) <= time_gap_ &&
          std::abs(t_b - c.stamps_b[m]) <= time_gap_) {
        chosen = index;
        break;
      }
    }
    if (chosen >= 0) break;
  }
  if (chosen < 0) {
    chosen = num_clusters();
    LoopCluster fresh;
    fresh.session_a = session_a;
    fresh.session_b = session_b;
    fresh.newest_a = t_a;
    fresh.newest_b = t_b;
    fresh.oldest_a = t_a;
    clusters_.push_back(fresh);
    open_.push_back(chosen);
  }
  LoopCluster& c = clusters_[chosen];
  c.links.push_back(link_id);
  c.stamps_a.push_back(t_a);
  c.stamps_b.push_back(t_b);
  c.newest_a = std::max(c.newest_a, t_a);
  c.newest_b = std::max(c.newest_b, t_b);
  c.oldest_a = std::min(c.oldest_a, t_a);
  return chosen;
}

bool LoopClusterer::SidePassed(int session, double newest_member) const {
  if (session >= static_cast<int>(clocks_.size())) return false;
  const SessionClock& clock = clocks_[session];
  return clock.ended || (clock.seen && clock.newest > newest_member + time_gap_);
}

std::vector<int> LoopClusterer::CloseDue() {
  std::vector<int> closed;
  std::vector<int> still_open;
  for (int index : open_) {
    LoopCluster& c = clusters_[index];
    const bool spanned = max_span_ > 0.0 && c.session_a < static_cast<int>(clocks_.size()) &&
                         clocks_[c.session_a].seen &&
                         clocks_[c.session_a].newest > c.oldest_a + max_span_;
    if (spanned || (SidePassed(c.session_a, c.newest_a) && SidePassed(c.session_b, c.newest_b))) {
      c.closed = true;
      closed.push_back(index);
    } else {
      still_open.push_back(index);
    }
  }
  open_.swap(still_open);
  return closed;
}

std::vector<int> LoopClusterer::AdvanceSession(int session, double newest_stamp) {
  IRRR_CHECK(session >= 0);
  if (session >= static_cast<int>(clocks_.size())) clocks_.resize(session + 1);
  SessionClock& clock = clocks_[session];
  clock.newest = clock.seen ? std::max(clock.newest, newest_stamp) : newest_stamp;
  clock.seen = true;
  return CloseDue();
}

std::vector<int> LoopClusterer::EndSession(int session) {
  IRRR_CHECK(session >= 0);
  if (session >= static_cast<int>(clocks_.size())) clocks_.resize(session + 1);
  clocks_[session].ended = true;
  return CloseDue();
}

std::vector<int> LoopClusterer::CloseAll() {
  std::vector<int> closed = open_;
  for (int index : open_) clusters_[index].closed = true;
  open_.clear();
  return closed;
}

}  // namespace irrr
