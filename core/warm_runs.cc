// A cluster's runs (the links whose ends lie near each other's: a place recognizer's matches
// along one revisit, or a group of wrong ones) and a failed cluster judged again run by run: the
// part of the warm engine (core/warm_engine_impl.h) that splits clusters by place.

#include <algorithm>
#include <cmath>
#include <functional>
#include <vector>

#include "core/warm_engine_impl.h"

namespace irrr {
namespace {

// Links of a cluster whose ends lie within this many poses of another's ends form one run (a
// place recognizer's matches along a revisit, or a group of wrong ones): a cluster that fails the
// joint test whole is judged again run by run (JudgeRuns).
constexpr int kRunGap = 5;

}  // namespace

template <class Pose>
std::vector<std::vector<int>> WarmEngine<Pose>::Impl::Runs(const std::vector<int>& links) const {
  std::vector<int> run(links.size());
  for (size_t k = 0; k < links.size(); ++k) run[k] = static_cast<int>(k);
  std::function<int(int)> root = [&](int k) { return run[k] == k ? k : run[k] = root(run[k]); };
  // Two links are Near only if their lower ends lie within kRunGap of each other: each is compared
  // with those after it in the order of lower ends, up to kRunGap further (every pair was
  // compared before: 10% of W10000's time, with clusters of thousands of links).
  auto lower = [&](int k) { return LowerEnd(graph->edge(links[k])); };
  std::vector<int> order(run);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return lower(a) < lower(b); });
  for (size_t i = 0; i < order.size(); ++i) {
    for (size_t j = i + 1; j < order.size() && lower(order[j]) - lower(order[i]) <= kRunGap; ++j) {
      if (Near(links[order[i]], links[order[j]])) run[root(order[i])] = root(order[j]);
    }
  }
  std::vector<std::vector<int>> runs;
  std::vector<int> index(links.size(), -1);
  for (size_t k = 0; k < links.size(); ++k) {
    int& r = index[root(static_cast<int>(k))];
    if (r < 0) {
      r = static_cast<int>(runs.size());
      runs.emplace_back();
    }
    runs[r].push_back(links[k]);
  }
  std::vector<std::vector<int>> parts;
  std::vector<int> lone;
  for (std::vector<int>& r : runs) {
    if (r.size() >= 2) {
      parts.push_back(std::move(r));
    } else {
      lone.push_back(r.front());
    }
  }
  if (!lone.empty()) parts.push_back(lone);
  return parts;
}

template <class Pose>
bool WarmEngine<Pose>::Impl::Near(int a, int b) const {
  const Edge<Pose>& x = graph->edge(a);
  const Edge<Pose>& y = graph->edge(b);
  return std::abs(LowerEnd(x) - LowerEnd(y)) <= kRunGap &&
         std::abs(UpperEnd(x) - UpperEnd(y)) <= kRunGap;
}

template <class Pose>
bool WarmEngine<Pose>::Impl::Lone(int e, const std::vector<int>& links) const {
  return std::none_of(links.begin(), links.end(), [&](int f) { return f != e && Near(e, f); });
}

template <class Pose>
bool WarmEngine<Pose>::Impl::AllLone(const std::vector<int>& links) const {
  return std::all_of(links.begin(), links.end(), [&](int e) { return Lone(e, links); });
}

template <class Pose>
void WarmEngine<Pose>::Impl::JudgeRuns(int q,
                                       std::vector<std::vector<int>> runs,
                                       StepResult* result) {
  std::stable_sort(
      runs.begin(), runs.end(), [](const auto& a, const auto& b) { return a.size() > b.size(); });
  // A run too short to measure its own noise is judged at its place's: the lowest own factor of
  // the cluster's runs that can (as LowestRunVariance, capped as any own factor), when that is
  // above the global one. A revisit's matches share their error, and
  // its runs' own factors measure it; a wrong run among them raises the cluster's factor by
  // disagreeing with the true ones, not the runs' (Intel + 1000 random, seed 6: the true run
  // 786-789 -> 934-936 fell at the global 0.16, chi2 increase 6.4 against 5.5).
  const double lowest = LowestVarianceOf(runs);
  const double place = std::isfinite(lowest) ? CappedOwnFactor(lowest) : variance;
  std::vector<int> clusters = {q};
  book->clusters[q].links = runs.front();
  for (size_t k = 1; k < runs.size(); ++k) {
    clusters.push_back(SplitOff(q, runs[k]));
    book->clusters[clusters.back()].in_r = true;
  }
  // Each at its own factor, not the cluster's: the cluster's own factor held the wrong runs'
  // residuals (Intel + 1000 random-grouped: at the global factor true runs whose matches share
  // their error fell, 36 true loops; at the cluster's, a wrong group of 3 passed).
  const double own = test_variance;
  for (int r : clusters) {
    test_variance = 0.0;
    if (book->clusters[r].links.size() >= 2) {
      Calibrate(r);
      test_variance = OwnVariance(r);
    }
    if (test_variance == 0.0 && place > variance) test_variance = place;
    // A lone link waits at the factor it would be judged at (not the run's before it).
    if (HoldIfUnsupported(r, &result->changed_loops)) continue;
    JointTestAtScale(r, result);
  }
  test_variance = own;
}

template <class Pose>
std::vector<std::vector<int>> WarmEngine<Pose>::Impl::Parts(const std::vector<int>& links) const {
  std::vector<std::vector<int>> parts;
  for (std::vector<int>& run : Runs(links)) {
    if (run.size() >= 2 && !Lone(run.front(), run)) {
      parts.push_back(std::move(run));
    } else {
      for (int e : run) parts.push_back({e});
    }
  }
  return parts;
}

template <class Pose>
std::vector<std::pair<double, size_t>> WarmEngine<Pose>::Impl::Refuted(
    const std::vector<std::vector<int>>& groups) const {
  std::vector<std::pair<double, size_t>> ranked;
  if (groups.empty()) return ranked;
  const std::vector<double> removal = good.LinearizeRemovals(groups);
  for (size_t k = 0; k < groups.size(); ++k) {
    const double ratio = removal[k] / Threshold(d * static_cast<double>(groups[k].size()));
    if (ratio >= kBendingRunMargin) ranked.push_back({ratio, k});
  }
  std::sort(ranked.rbegin(), ranked.rend());
  return ranked;
}

template <class Pose>
std::vector<std::vector<int>> WarmEngine<Pose>::Impl::BendingParts(
    const std::vector<int>& links) const {
  std::vector<std::vector<int>> parts = Parts(links);
  if (parts.size() < 2) return {};
  parts.erase(std::remove_if(parts.begin(),
                             parts.end(),
                             [](const std::vector<int>& p) { return p.size() > kMaxWeighedLinks; }),
              parts.end());
  std::vector<std::pair<double, size_t>> ranked = Refuted(parts);
  size_t links_bending = 0;
  for (const auto& [unused, k] : ranked) links_bending += parts[k].size();
  // The least refuted stays when all would leave (parts that refute each other).
  if (!ranked.empty() && links_bending == links.size()) ranked.pop_back();
  std::vector<std::vector<int>> bending;
  for (const auto& [unused, k] : ranked) bending.push_back(std::move(parts[k]));
  return bending;
}

// Calibrate, JointTestAtScale and the rest are instantiated with the engine
// (core/warm_engine.cc).
#define IRRR_INSTANTIATE_RUNS(Pose)                                                             \
  template std::vector<std::vector<int>> WarmEngine<Pose>::Impl::Runs(const std::vector<int>&)  \
      const;                                                                                    \
  template bool WarmEngine<Pose>::Impl::Near(int, int) const;                                   \
  template bool WarmEngine<Pose>::Impl::Lone(int, const std::vector<int>&) const;               \
  template bool WarmEngine<Pose>::Impl::AllLone(const std::vector<int>&) const;                 \
  template void WarmEngine<Pose>::Impl::JudgeRuns(                                              \
      int, std::vector<std::vector<int>>, StepResult*);                                         \
  template std::vector<std::vector<int>> WarmEngine<Pose>::Impl::BendingParts(                  \
      const std::vector<int>&) const;                                                           \
  template std::vector<std::vector<int>> WarmEngine<Pose>::Impl::Parts(const std::vector<int>&) \
      const;                                                                                    \
  template std::vector<std::pair<double, size_t>> WarmEngine<Pose>::Impl::Refuted(              \
      const std::vector<std::vector<int>>&) const;
IRRR_INSTANTIATE_RUNS(Pose2)
IRRR_INSTANTIATE_RUNS(Pose3)
#undef IRRR_INSTANTIATE_RUNS

}  // namespace irrr
