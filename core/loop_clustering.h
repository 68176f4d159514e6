#ifndef IRRR_CORE_LOOP_CLUSTERING_H_
#define IRRR_CORE_LOOP_CLUSTERING_H_

// Clustering of loop hypotheses (paper III.A.1, eq. 6; algorithm-notes "Clustering").
//
// Each link joins two poses (session, stamp). A link is oriented so that its side "a" is in the
// session of higher index (or, within one session, is the later pose) and side "b" the other.
// Clusters only group links of the same ordered session pair (a, b). A new link joins an open
// cluster R_k when some member (p, q) has
//   |t_a - t_p| <= t_g  and  |t_b - t_q| <= t_g                              (eq. 6)
// and starts a new cluster otherwise; when it fits several open clusters it joins the oldest
// (clusters are never merged). A cluster closes when, on each of its two sides, the session has
// ended or its newest pose is more than t_g past the cluster's newest member on that side; or on
// an explicit flush. Beyond the paper, a bound on a cluster's span: it also closes once its "a"
// session's newest pose is more than `max_span` past its oldest member on that side, so that a
// place revisited without pause (or hypotheses that keep chaining in) is judged in pieces, each
// at most max_span + t_g after its first link, instead of once at the end. Closed clusters never
// grow.

#include <vector>

#include "core/status.h"

namespace irrr {

struct LoopCluster {
  int session_a = -1;  // session of the "a" side (higher session index, or the same session)
  int session_b = -1;
  std::vector<int> links;        // the caller's link ids, in arrival order
  std::vector<double> stamps_a;  // per link, stamp of its "a" pose
  std::vector<double> stamps_b;
  double newest_a = 0.0;  // largest member stamp on each side
  double newest_b = 0.0;
  double oldest_a = 0.0;  // smallest member stamp on side a
  bool closed = false;

  bool IsInterSession() const { return session_a != session_b; }
};

class LoopClusterer {
 public:
  // `time_gap` is t_g, in the units of the stamps (seconds, or poses for files); must be >= 0.
  // `max_span` > 0 bounds a cluster's span (see above; 0: unbounded, the paper's rule).
  explicit LoopClusterer(double time_gap, double max_span = 0.0);

  // Adds link `link_id` between (session_1, stamp_1) and (session_2, stamp_2); returns the index of
  // the cluster it joined or started.
  int AddLink(int link_id, int session_1, double stamp_1, int session_2, double stamp_2);

  // The newest pose of `session` now has stamp `newest_stamp`. Returns the indices of the clusters
  // this closed, ascending.
  std::vector<int> AdvanceSession(int session, double newest_stamp);
  // `session` will receive no more poses. Returns the clusters this closed, ascending.
  std::vector<int> EndSession(int session);
  // Closes every open cluster. Returns them, ascending.
  std::vector<int> CloseAll();

  int num_clusters() const { return static_cast<int>(clusters_.size()); }
  const LoopCluster& cluster(int index) const { return clusters_[index]; }
  double time_gap() const { return time_gap_; }

 private:
  struct SessionClock {
    double newest = 0.0;
    bool seen = false;
    bool ended = false;
  };

  bool SidePassed(int session, double newest_member) const;
  std::vector<int> CloseDue();

  double time_gap_;
  double max_span_;
  std::vector<LoopCluster> clusters_;
  std::vector<int> open_;  // indices of open clusters, ascending
  std::vector<SessionClock> clocks_;
};

}  // namespace irrr

#endif  // IRRR_CORE_LOOP_CLUSTERING_H_
