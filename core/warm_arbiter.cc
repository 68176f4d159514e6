// The arbiter: when clusters that are consistent on their own keep failing against the good set,
// a robust global solve of their component says which side the map supports, whichever side
// arrived first, and Replace confirms that side with the joint tests (the part of the warm engine,
// core/warm_engine_impl.h, that settles conflicts on all their evidence).

#include <algorithm>
#include <utility>

#include "core/robust_solve.h"
#include "core/warm_engine_impl.h"

namespace irrr {

template <class Pose>
bool WarmEngine<Pose>::Impl::InConflict(int q, int component) const {
  const JudgedCluster& c = book->clusters[q];
  if (!c.in_reject || c.in_good || c.links.size() < 2 ||
      good.ComponentOf(c.session_a) != component || good.ComponentOf(c.session_b) != component) {
    return false;
  }
  for (int e : c.links) {
    if (book->decisions[e].state != LoopState::kRejectedJointTest) return false;
  }
  return true;
}

template <class Pose>
std::map<int, int> WarmEngine<Pose>::Impl::ConflictLinks() const {
  std::map<int, int> links;
  for (int q = 0; q < static_cast<int>(book->clusters.size()); ++q) {
    const JudgedCluster& c = book->clusters[q];
    const int component = good.ComponentOf(c.session_a);
    if (InConflict(q, component)) links[component] += static_cast<int>(c.links.size());
  }
  return links;
}

template <class Pose>
void WarmEngine<Pose>::Impl::ArbitrateGrown(int before, StepResult* result) {
  auto bits = [](int n) {
    int b = 0;
    for (; n > 0; n >>= 1) ++b;
    return b;
  };
  const std::map<int, int> now = ConflictLinks();
  int total = 0;
  for (const auto& [unused, n] : now) total += n;
  // Only when the evidence against the good set has doubled since it was last this large: a run
  // of n links is arbitrated O(log n) times.
  if (total < kMinConflictLinks || bits(total) <= bits(before)) return;
  for (const auto& [component, n] : now) Arbitrate(component, result);
}

template <class Pose>
void WarmEngine<Pose>::Impl::Arbitrate(int component, StepResult* result) {
  // The component's graph: its sessions' odometry, the good loops and the clusters in conflict,
  // each session chained along its odometry from where the good set puts its first pose (the
  // dead reckoning within a session: no choice the good set made bends it).
  PoseGraph<Pose> sub;
  std::vector<int> sub_of(graph->num_vertices(), -1);
  for (int s : good.SessionsOf(component)) {
    int session = -1;
    IRRR_CHECK(sub.AddSession(graph->session(s).id, &session).ok());
    Pose pose;
    for (int v : graph->session(s).vertices) {
      const int odometry = graph->OdometryInto(v);
      const Edge<Pose>* edge = odometry >= 0 ? &graph->edge(odometry) : nullptr;
      pose = edge != nullptr ? pose * edge->measurement : good.Estimate(v);
      IRRR_CHECK(sub.AddPose(session,
                             graph->vertex(v).id,
                             graph->vertex(v).stamp,
                             pose,
                             edge != nullptr ? &edge->measurement : nullptr,
                             edge != nullptr ? &edge->information : nullptr,
                             &sub_of[v])
                     .ok());
    }
  }
  std::vector<int> clusters;  // good or in conflict, in the component
  std::vector<std::vector<int>> sub_links;
  for (int q = 0; q < static_cast<int>(book->clusters.size()); ++q) {
    const JudgedCluster& c = book->clusters[q];
    const bool good_here = c.in_good && !c.links.empty() && Within({component}, q);
    if (!good_here && !InConflict(q, component)) continue;
    clusters.push_back(q);
    sub_links.emplace_back();
    for (int e : c.links) {
      const Edge<Pose>& edge = graph->edge(e);
      int index = -1;
      IRRR_CHECK(
          sub.AddLoop(
                 sub_of[edge.from], sub_of[edge.to], edge.measurement, edge.information, &index)
              .ok());
      sub_links.back().push_back(index);
    }
  }
  RobustOptions robust;
  robust.kernel = RobustKernel::kDcs;
  // Odometry is weighed too: its scale falls below 0.5 at d^2 = 3 Phi, kScreenMargin times the
  // link threshold (where the screen refuses a loop).
  robust.dcs_odometry_phi = kScreenMargin * LinkThreshold() / 3.0;
  RobustResult<Pose> solved;
  if (!RobustSolve(sub, robust, sub.initial_estimate(), &solved).ok()) return;
  // Each cluster's support: the mean of its links' scales.
  std::vector<std::pair<double, int>> suspects;  // (support, good cluster)
  std::vector<int> challengers;
  for (size_t k = 0; k < clusters.size(); ++k) {
    double support = 0.0;
    for (int index : sub_links[k]) support += solved.weight[index];
    support /= static_cast<double>(sub_links[k].size());
    const bool in_good = book->clusters[clusters[k]].in_good;
    if (in_good && support < kArbiterSupport) suspects.push_back({support, clusters[k]});
    if (!in_good && support >= kArbiterSupport) challengers.push_back(clusters[k]);
  }
  ++result->arbitrations;
  if (challengers.empty()) return;
  std::sort(suspects.begin(), suspects.end());
  std::vector<int> suspect_clusters;
  for (const auto& [unused, g] : suspects) suspect_clusters.push_back(g);
  SortLargestFirst(&challengers);
  // The odometry the solve found faulty is weakened for the replacement, and stays so only if
  // the good set it builds is larger.
  const std::vector<int> faulty = FaultyOdometry(sub, sub_of, solved, component);
  Weaken(faulty);
  if (!Replace(suspect_clusters, challengers, {component}, result)) Unweaken(faulty);
}

template <class Pose>
std::vector<int> WarmEngine<Pose>::Impl::FaultyOdometry(const PoseGraph<Pose>& sub,
                                                        const std::vector<int>& sub_of,
                                                        const RobustResult<Pose>& solved,
                                                        int component) const {
  std::vector<int> faulty;
  int odometry = 0;
  for (int s : good.SessionsOf(component)) {
    for (int v : graph->session(s).vertices) {
      const int e = graph->OdometryInto(v);
      if (e < 0) continue;
      ++odometry;
      if (weakened.count(e) == 0 && solved.weight[sub.OdometryInto(sub_of[v])] < kArbiterSupport) {
        faulty.push_back(e);
      }
    }
  }
  if (static_cast<double>(faulty.size()) > kMaxFaultShare * odometry) faulty.clear();
  return faulty;
}

template <class Pose>
void WarmEngine<Pose>::Impl::Weaken(const std::vector<int>& edges) {
  if (edges.empty()) return;
  for (int e : edges) {
    if (weakened.count(e) != 0) continue;
    const typename Pose::Matrix information = graph->edge(e).information;
    weakened.emplace(e, information);
    IRRR_CHECK(graph->SetInformation(e, kFaultWeight * information).ok());
  }
  pairwise.Recompute();
}

template <class Pose>
void WarmEngine<Pose>::Impl::Unweaken(const std::vector<int>& edges) {
  if (edges.empty()) return;
  for (int e : edges) {
    IRRR_CHECK(graph->SetInformation(e, weakened.at(e)).ok());
    weakened.erase(e);
  }
  pairwise.Recompute();
}

#define IRRR_INSTANTIATE_ARBITER(Pose)                                                        \
  template bool WarmEngine<Pose>::Impl::InConflict(int, int) const;                           \
  template std::map<int, int> WarmEngine<Pose>::Impl::ConflictLinks() const;                  \
  template void WarmEngine<Pose>::Impl::ArbitrateGrown(int, StepResult*);                     \
  template void WarmEngine<Pose>::Impl::Arbitrate(int, StepResult*);                          \
  template std::vector<int> WarmEngine<Pose>::Impl::FaultyOdometry(                           \
      const PoseGraph<Pose>&, const std::vector<int>&, const RobustResult<Pose>&, int) const; \
  template void WarmEngine<Pose>::Impl::Weaken(const std::vector<int>&);                      \
  template void WarmEngine<Pose>::Impl::Unweaken(const std::vector<int>&);
IRRR_INSTANTIATE_ARBITER(Pose2)
IRRR_INSTANTIATE_ARBITER(Pose3)
#undef IRRR_INSTANTIATE_ARBITER

}  // namespace irrr
