#include "core/loop_clustering.h"

#include <catch2/catch.hpp>

namespace irrr {
namespace {

constexpr double kGap = 10.0;

TEST_CASE("Links near an open cluster's members join it (eq. 6)", "[loop_clustering]") {
  LoopClusterer clusterer(kGap);
  // (100 -> 20), then (105 -> 28): both ends within 10 of the first link.
  CHECK(clusterer.AddLink(0, 0, 100.0, 0, 20.0) == 0);
  CHECK(clusterer.AddLink(1, 0, 105.0, 0, 28.0) == 0);
  // One end too far (40 vs 20/28 is > 10): a new cluster.
  CHECK(clusterer.AddLink(2, 0, 108.0, 0, 40.0) == 1);
  // Chaining: (114 -> 36) is within 10 of (105 -> 28) but not of (100 -> 20): joins cluster 0.
  CHECK(clusterer.AddLink(3, 0, 114.0, 0, 36.0) == 0);
  REQUIRE(clusterer.num_clusters() == 2);
  CHECK(clusterer.cluster(0).links == std::vector<int>{0, 1, 3});
  CHECK(clusterer.cluster(0).newest_a == 114.0);
  CHECK(clusterer.cluster(0).newest_b == 36.0);
}

TEST_CASE("A cluster closes once it spans max_span on its later side; the next link starts anew",
          "[loop_clustering]") {
  LoopClusterer clusterer(kGap, 4 * kGap);
  // A revisit that never pauses: one link per pose, each within the gap of the one before.
  int closed_at = -1;
  for (int k = 0; k < 100; ++k) {
    const double t = 100.0 + k;
    const int cluster = clusterer.AddLink(k, 0, t, 0, t - 80.0);
    if (closed_at < 0) CHECK(cluster == 0);
    const std::vector<int> closed = clusterer.AdvanceSession(0, t + 1.0);
    if (!closed.empty() && closed_at < 0) {
      CHECK(closed == std::vector<int>{0});
      closed_at = k;
    }
  }
  // Closed when the newest pose passed the oldest member (100) by 4 gaps (40).
  CHECK(closed_at == 40);
  CHECK(clusterer.cluster(0).links.size() == 41);
  CHECK(clusterer.cluster(1).links.front() == 41);
  // Unbounded (the paper): one cluster that closes only at the end.
  LoopClusterer unbounded(kGap);
  for (int k = 0; k < 100; ++k) {
    CHECK(unbounded.AddLink(k, 0, 100.0 + k, 0, 20.0 + k) == 0);
    CHECK(unbounded.AdvanceSession(0, 101.0 + k).empty());
  }
}

TEST_CASE("Links are oriented, so either direction lands in the same cluster",
          "[loop_clustering]") {
  LoopClusterer clusterer(kGap);
  CHECK(clusterer.AddLink(0, 0, 100.0, 0, 20.0) == 0);
  CHECK(clusterer.AddLink(1, 0, 21.0, 0, 101.0) == 0);  // written earlier -> later
  CHECK(clusterer.cluster(0).stamps_a == std::vector<double>{100.0, 101.0});
  // Inter-session: side a is the higher session whichever way the link is written.
  CHECK(clusterer.AddLink(2, 1, 5.0, 0, 50.0) == 1);
  CHECK(clusterer.AddLink(3, 0, 52.0, 1, 7.0) == 1);
  CHECK(clusterer.cluster(1).session_a == 1);
  CHECK(clusterer.cluster(1).session_b == 0);
  CHECK(clusterer.cluster(1).IsInterSession());
}

TEST_CASE("Clusters of different session pairs never mix", "[loop_clustering]") {
  LoopClusterer clusterer(kGap);
  CHECK(clusterer.AddLink(0, 1, 10.0, 0, 10.0) == 0);
  CHECK(clusterer.AddLink(1, 2, 10.0, 0, 10.0) == 1);
  CHECK(clusterer.AddLink(2, 1, 10.0, 1, 0.0) == 2);
}

TEST_CASE("A link fitting two open clusters joins the oldest", "[loop_clustering]") {
  LoopClusterer clusterer(kGap);
  CHECK(clusterer.AddLink(0, 0, 100.0, 0, 20.0) == 0);
  CHECK(clusterer.AddLink(1, 0, 100.0, 0, 38.0) == 1);
  CHECK(clusterer.AddLink(2, 0, 100.0, 0, 29.0) == 0);  // within 10 of both 20 and 38
  CHECK(clusterer.cluster(1).links.size() == 1);
}

TEST_CASE("A cluster closes t_g after its newest member, at session end, or on flush",
          "[loop_clustering]") {
  LoopClusterer clusterer(kGap);
  clusterer.AddLink(0, 0, 100.0, 0, 20.0);
  CHECK(clusterer.AdvanceSession(0, 105.0).empty());
  CHECK(clusterer.AdvanceSession(0, 110.0).empty());  // exactly t_g later: still open
  CHECK(clusterer.AdvanceSession(0, 110.5) == std::vector<int>{0});
  CHECK(clusterer.cluster(0).closed);
  // A link that would have fitted the closed cluster starts a new one.
  CHECK(clusterer.AddLink(1, 0, 101.0, 0, 21.0) == 1);
  CHECK(clusterer.EndSession(0) == std::vector<int>{1});

  // Inter-session: both sides must have moved on (or ended).
  LoopClusterer two(kGap);
  two.AddLink(0, 1, 50.0, 0, 300.0);
  CHECK(two.AdvanceSession(1, 70.0).empty());  // session 0 has not moved past 300 + 10
  CHECK(two.AdvanceSession(0, 305.0).empty());
  CHECK(two.AdvanceSession(0, 311.0) == std::vector<int>{0});

  LoopClusterer flushed(kGap);
  flushed.AddLink(0, 0, 1.0, 0, 0.0);
  flushed.AddLink(1, 0, 100.0, 0, 50.0);
  CHECK(flushed.CloseAll() == std::vector<int>{0, 1});
}

TEST_CASE("An inter-session cluster with an ended side closes when the other side moves on",
          "[loop_clustering]") {
  LoopClusterer clusterer(kGap);
  clusterer.AdvanceSession(0, 500.0);
  CHECK(clusterer.EndSession(0).empty());
  clusterer.AddLink(0, 1, 20.0, 0, 300.0);
  CHECK(clusterer.AdvanceSession(1, 25.0).empty());
  CHECK(clusterer.AdvanceSession(1, 31.0) == std::vector<int>{0});
}

}  // namespace
}  // namespace irrr
