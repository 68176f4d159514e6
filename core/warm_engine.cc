#include "core/warm_engine.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <map>

#include "core/warm_engine_impl.h"

namespace irrr {
namespace {

// A cluster of one link needs at least this redundancy number to be judged (Unsupported).
constexpr double kMinRedundancy = 0.1;

}  // namespace

template <class Pose>
void WarmEngine<Pose>::Impl::Step(int k, StepResult* result) {
  const int solves_before = Solves();
  const int iterations_before = Iterations();
  step_solves = solves_before;
  const bool budgeted = options->step_budget > 0;
  int conflict_before = 0;
  if (options->arbiter) {
    for (const auto& [unused, n] : ConflictLinks()) conflict_before += n;
  }
  EstimateVarianceFactor();
  std::vector<int> batch;
  if (k >= 0) batch.push_back(k);
  // With a budget, cluster k waits behind what earlier steps left unjudged (it is among them).
  if (budgeted && scale_known) batch = Unjudged();
  if (!scale_known) {
    if (k >= 0 && book->clusters[k].links.size() >= 2) Calibrate(k);
    EstimateVarianceFactor();
    if (!scale_known && released) {
      // A flush or a session's end: what waits is judged with the information as given.
      Scale as_given;
      as_given.known = true;
      as_given.estimate = variance_estimate;
      UseScale(as_given);
    }
    if (scale_known) {
      batch = Waiting();
      SortLargestFirst(&batch);
    } else {
      batch.clear();  // waits
    }
  }
  if (scale_known) {
    RejudgeRefused(result);
    Revalidate(result);
    const int good_before = GoodLinks();
    int done = 0;  // units of work: the first is done whatever the budget says
    for (int q : batch) {
      if (done > 0 && OverBudget()) break;
      Judge(q, result);
      ++done;
    }
    // Clusters that wait for support are judged again once the good set has grown.
    if ((k >= 0 || budgeted) && GoodLinks() != good_before) {
      for (int q : Waiting()) {
        if (!budgeted) {
          Judge(q, result);
        } else if (book->clusters[q].held) {
          book->clusters[q].deferred = true;
        }
      }
    }
    if (budgeted) JudgeDeferred(&done, result);
    if (!OverBudget()) ReverseOutvoted(result);
    if (options->arbiter) ArbitrateGrown(conflict_before, result);
  }
  if (budgeted) {
    result->deferred = static_cast<int>(Deferred().size());
    has_deferred = result->deferred > 0;
    result->capped = OverBudget();
  }
  std::vector<int>& changed = result->changed_loops;
  std::sort(changed.begin(), changed.end());
  changed.erase(std::unique(changed.begin(), changed.end()), changed.end());
  NoteRefusals(changed);
  std::sort(result->sessions.begin(), result->sessions.end());
  result->sessions.erase(std::unique(result->sessions.begin(), result->sessions.end()),
                         result->sessions.end());
  result->chi2 = 0.0;
  std::vector<int> components;
  for (int s : result->sessions) components.push_back(good.ComponentOf(s));
  std::sort(components.begin(), components.end());
  components.erase(std::unique(components.begin(), components.end()), components.end());
  for (int c : components) {
    if (c >= 0) result->chi2 += good.Solver(c).chi2();
  }
  result->solves += Solves() - solves_before;
  result->iterations += Iterations() - iterations_before;
  result->variance_factor = variance;
  result->variance_estimate = variance_estimate;
}

template <class Pose>
std::vector<int> WarmEngine<Pose>::Impl::Unjudged() const {
  std::vector<int> unjudged;
  for (int q : Waiting()) {
    if (!book->clusters[q].held) unjudged.push_back(q);
  }
  return unjudged;
}

template <class Pose>
std::vector<int> WarmEngine<Pose>::Impl::Deferred() const {
  std::vector<int> deferred;
  if (!CurrentScale().known) return deferred;  // what waits for a factor is not deferred
  const std::vector<int> unjudged = Unjudged();
  for (int q = 0; q < static_cast<int>(book->clusters.size()); ++q) {
    if (book->clusters[q].deferred || std::binary_search(unjudged.begin(), unjudged.end(), q)) {
      deferred.push_back(q);
    }
  }
  return deferred;
}

template <class Pose>
void WarmEngine<Pose>::Impl::JudgeDeferred(int* done, StepResult* result) {
  for (int q : Waiting()) {
    JudgedCluster& c = book->clusters[q];
    if (!c.deferred || !c.held) continue;
    if (*done > 0 && OverBudget()) return;
    c.deferred = false;
    Judge(q, result);
    ++*done;
  }
  // The challenges due, one per component, most inconsistent suspect first (as JointTestWhole
  // names them). A suspect that has left the good set meanwhile is no longer one.
  std::map<int, std::vector<std::pair<double, int>>> due;  // component -> (index, suspect)
  for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
    JudgedCluster& c = book->clusters[g];
    if (!c.deferred || c.held) continue;
    if (!c.in_good) {
      c.deferred = false;
      continue;
    }
    double chi2;
    due[good.ComponentOf(c.session_a)].push_back({ConsistencyIndex(g, &chi2), g});
  }
  for (auto& [component, ranked] : due) {
    if (*done > 0 && OverBudget()) return;
    std::sort(ranked.rbegin(), ranked.rend());
    std::vector<int> suspects;
    for (const auto& [unused, g] : ranked) {
      book->clusters[g].deferred = false;
      suspects.push_back(g);
    }
    Challenge(suspects, {component}, result, /*deferrable=*/false);
    ++*done;
  }
}

template <class Pose>
void WarmEngine<Pose>::Impl::Judge(int k, StepResult* result) {
  std::vector<int>* changed = &result->changed_loops;
  JudgedCluster& cluster = book->clusters[k];
  const int component_a = good.ComponentOf(cluster.session_a);
  const int component_b = good.ComponentOf(cluster.session_b);
  for (int c : {component_a, component_b}) {
    for (int s : good.SessionsOf(c)) result->sessions.push_back(s);
  }
  // The screen first: each link alone against the good set (a few sparse solves), so that
  // Algorithm 1 weighs only links that are not far off.
  if (component_a == component_b) Screen(k, changed);
  // What that screen saw, so that a lone link is not screened again below with nothing changed
  // (Algorithm 1 does not touch the good set).
  const std::vector<int> screened_links =
      component_a == component_b ? book->clusters[k].links : std::vector<int>();
  const double screened_at = LinkThreshold();
  std::vector<int> splits;
  if (book->clusters[k].links.empty()) {
    book->clusters[k].in_reject = true;
    return;
  }
  // A cluster with redundancy enough of its own is judged at the larger of the global factor and
  // its own (the noise varies along a trajectory, and a place recognizer's error with it).
  if (book->clusters[k].links.size() >= 2) Calibrate(k);
  test_variance = OwnVariance(k);
  const bool survived =
      WarmIntraCluster(&problems, &pairwise, Thresholds(), k, book, changed, &splits);
  test_variance = 0.0;
  // The clusters split off are judged even when the cluster itself fell: a consistent subset
  // that passed Algorithm 1 (in R) would otherwise wait forever, never tested again (Intel in four
  // sessions + 600 wrong loops, seed 4: five true loops left pending).
  if (!survived) book->clusters[k].in_reject = true;
  std::vector<int> candidates = {k};
  candidates.insert(candidates.end(), splits.begin(), splits.end());
  // Largest first, as what waits is judged: the part Algorithm 1 leaves in the cluster can be a
  // few wrong links that split the true ones off (the ring + 1000 random-grouped, seed 9: a wrong
  // group of 3 went in first, then both true parts, 17 and 9 links, failed against it).
  SortLargestFirst(&candidates);
  for (int q : candidates) {
    JudgedCluster& c = book->clusters[q];
    if (!c.in_r || c.links.empty()) continue;
    // A lone link left of a cluster is screened as one (with the others it went by their median).
    if (c.links.size() == 1 && good.ComponentOf(c.session_a) == good.ComponentOf(c.session_b)) {
      if (q != k || c.links != screened_links || LinkThreshold() != screened_at) Screen(q, changed);
      if (c.links.empty()) {
        c.in_reject = true;
        continue;
      }
    }
    if (HoldIfUnsupported(q, changed)) continue;
    c.held = false;
    JointTest(q, result);
  }
}

template <class Pose>
void WarmEngine<Pose>::Impl::Screen(int q, std::vector<int>* changed) {
  std::vector<int>& links = book->clusters[q].links;
  const std::vector<double> statistic = LinkStatistics(links);
  // Far off: kScreenMargin times the link threshold, and kClusterMargin times the cluster's
  // median statistic (links that agree with each other go on together, however far the good
  // set's estimate is from them).
  std::vector<double> sorted = statistic;
  std::sort(sorted.begin(), sorted.end());
  const double median = links.size() >= 2 ? sorted[sorted.size() / 2] : 0.0;
  const double far = std::max(kScreenMargin * LinkThreshold(), kClusterMargin * median);
  std::vector<int> kept;
  for (size_t k = 0; k < links.size(); ++k) {
    if (statistic[k] <= far) {
      kept.push_back(links[k]);
    } else {
      book->Set(links[k], LoopState::kRejectedJointTest, statistic[k], far, changed);
    }
  }
  links = kept;
}

template <class Pose>
std::vector<double> WarmEngine<Pose>::Impl::LinkStatistics(const std::vector<int>& links) {
  if (static_cast<int>(screened.size()) < graph->num_edges()) {
    LinearizedAddition none;
    none.redundancy = -1.0;
    screened.resize(graph->num_edges(), none);
  }
  const std::vector<LinearizedAddition> additions = good.LinearizeEach(links);
  std::vector<double> statistic(links.size());
  for (size_t k = 0; k < links.size(); ++k) {
    screened[links[k]] = additions[k];
    statistic[k] = additions[k].chi2_increase;
  }
  return statistic;
}

template <class Pose>
bool WarmEngine<Pose>::Impl::Unsupported(int q) const {
  const JudgedCluster& c = book->clusters[q];
  if (c.links.size() != 1) return false;
  const int e = c.links.front();
  if (e >= static_cast<int>(screened.size()) || !(screened[e].redundancy >= kMinRedundancy)) {
    return true;
  }
  // A lone link the joint optimum fits although the linearized statistic refuses it bends a loose
  // stretch of the map far from the estimate (Torus3D + 1000 random, seed 7: 4936 -> 2427, 92
  // degrees off, from a tail whose loops were still open; linearized 2.7 times its threshold,
  // under it at the joint optimum). It waits until the map around it is held.
  return screened[e].chi2_increase > LinkThreshold();
}

template <class Pose>
bool WarmEngine<Pose>::Impl::HoldIfUnsupported(int q, std::vector<int>* changed) {
  if (!Unsupported(q)) return false;
  JudgedCluster& c = book->clusters[q];
  c.in_r = false;
  c.held = true;
  book->Set(c.links.front(), LoopState::kPending, 0.0, 0.0, changed);
  return true;
}

template <class Pose>
void WarmEngine<Pose>::Impl::Accept(int q, std::vector<int>* changed) {
  JudgedCluster& c = book->clusters[q];
  for (int e : c.links) {
    book->Set(e, LoopState::kAccepted, good.EdgeChi2(e), LinkThreshold(), changed);
  }
  c.in_good = true;
  c.in_reject = false;
  c.in_r = true;
  c.accepted_variance = clusters_variance;
  MarkChecked(q);
}

template <class Pose>
void WarmEngine<Pose>::Impl::MarkChecked(int g) {
  book->clusters[g].checked_links = GoodLinks();
  book->clusters[g].checked_variance = variance;
}

template <class Pose>
void WarmEngine<Pose>::Impl::JointTest(int q, StepResult* result) {
  // A cluster with redundancy enough of its own is judged at the larger of the global factor
  // and its own (the noise varies along a trajectory; Algorithm 1's graph test has already
  // bounded its own factor by the global one's threshold). A cluster of several runs, at most at
  // the lowest of its runs' own factors.
  test_variance = OwnVariance(q);
  if (test_variance > variance) {
    test_variance = std::max(variance, std::min(test_variance, LowestRunVariance(q)));
  }
  JointTestAtScale(q, result);
  test_variance = 0.0;
}

template <class Pose>
void WarmEngine<Pose>::Impl::JointTestAtScale(int q, StepResult* result) {
  std::vector<int> parts;
  JointTestWhole(q, result, &parts);
  for (int p : parts) {
    book->clusters[p].in_r = true;
    if (HoldIfUnsupported(p, &result->changed_loops)) continue;
    JointTestAtScale(p, result);
  }
}

template <class Pose>
void WarmEngine<Pose>::Impl::JointTestWhole(int q, StepResult* result, std::vector<int>* parts) {
  std::vector<int>* changed = &result->changed_loops;
  while (true) {
    std::vector<int>& links = book->clusters[q].links;
    const std::vector<int> components = ComponentsOf(q);
    const typename GoodSet<Pose>::Trial trial = good.Try(links, AlignmentCap(), MaxIncrease(links));
    if (!trial.ok) {
      for (int e : links) {
        book->Set(e,
                  LoopState::kRejectedJointTest,
                  std::numeric_limits<double>::quiet_NaN(),
                  std::numeric_limits<double>::quiet_NaN(),
                  changed);
      }
      book->clusters[q].in_reject = true;
      return;
    }
    double cluster_chi2;
    const double index = ConsistencyIndex(q, &cluster_chi2);
    if (IncreasePasses(trial) && index < 1.0) {
      // Links failing on their own leave; the rest is judged again without them.
      std::vector<int> kept;
      std::vector<std::pair<int, double>> failing;
      for (int e : links) {
        const double chi2 = good.EdgeChi2(e);
        if (chi2 < LinkThreshold()) {
          kept.push_back(e);
        } else {
          failing.push_back({e, chi2});
        }
      }
      if (failing.empty()) {
        const std::vector<std::vector<int>> bending = BendingParts(links);
        if (bending.empty()) {
          good.Commit();
          Accept(q, changed);
          return;
        }
        good.Rollback();
        for (const std::vector<int>& part : bending) parts->push_back(SplitOff(q, part));
        continue;
      }
      good.Rollback();
      for (const auto& [e, chi2] : failing) {
        book->Set(e, LoopState::kRejectedLinkTest, chi2, LinkThreshold(), changed);
      }
      links = kept;
      if (kept.empty()) break;
      continue;
    }
    // Inconsistent as a whole. A cluster of several runs (Runs: a few wrong links among
    // a place's true ones form runs of their own) is judged again as its runs, each a cluster
    // of its own, so that a wrong run does not take the true ones down with it; the runs that
    // fail then challenge together what bent them (ChallengeAsWhole).
    const std::vector<std::vector<int>> runs = Runs(links);
    if (runs.size() >= 2) {
      good.Rollback();
      const std::vector<int> whole = links;  // JudgeRuns splits the cluster
      JudgeRuns(q, runs, result);
      ChallengeAsWhole(whole, components, result);
      return;
    }
    // Lone links judged together (no two near each other) that fail as a whole: those that would
    // fail on their own too (linearized statistic alone against the good set at least the link
    // threshold at the global factor: unrelated links share no error, and wrong ones among them
    // raise the group's own factor) leave, and the rest is judged again. When all leave, they
    // still name suspects below: true lone links that all fail may have been bent by a wrong
    // link accepted before (Manhattan + 300 local, seed 1: 1584 -> 1575).
    bool refused_alone = false;  // every link failed on its own too, and keeps that statistic
    if (links.size() >= 2 && AllLone(links)) {
      good.Rollback();
      const std::vector<double> statistic = LinkStatistics(links);
      const double alone = ThresholdsAt(variance).Of(d);
      std::vector<int> kept;
      for (size_t k = 0; k < links.size(); ++k) {
        if (statistic[k] < alone) {
          kept.push_back(links[k]);
        } else {
          book->Set(links[k], LoopState::kRejectedJointTest, statistic[k], alone, changed);
        }
      }
      if (!kept.empty() && kept.size() < links.size()) {
        links = kept;
        continue;
      }
      refused_alone = kept.empty();
      // None leaves, or all do: the same trial again (deterministic), for the suspects below.
      const bool reopened = good.Try(links, AlignmentCap(), MaxIncrease(links)).ok;
      IRRR_CHECK(reopened);
    }
    // With the good clusters that are inconsistent too, if any.
    std::vector<std::pair<double, int>> ranked;  // (consistency index, good cluster)
    for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
      if (!book->clusters[g].in_good || !Within(components, g)) continue;
      double chi2;
      const double g_index = ConsistencyIndex(g, &chi2);
      if (g_index >= 1.0) ranked.push_back({g_index, g});
    }
    if (ranked.empty()) {
      // A lone link of a larger cluster leaves it, so that it can be challenged alone.
      for (const Bending& b : BendingClusters(q, components)) {
        ranked.push_back({b.index, SuspectOf(b)});
      }
    }
    std::sort(ranked.rbegin(), ranked.rend());
    std::vector<int> suspects;  // most inconsistent first
    for (const auto& [unused, g] : ranked) suspects.push_back(g);
    good.Rollback();
    const double threshold = trial.dof > 0.0 ? Threshold(trial.dof) : 0.0;
    // Not `links`: the lone links split off above added clusters, and the book's clusters moved.
    // Links refused alone keep their own statistics, which RejudgeRefused reads when the factor
    // rises (the group's increase is not any one link's).
    if (!refused_alone) {
      for (int e : book->clusters[q].links) {
        book->Set(e, LoopState::kRejectedJointTest, trial.increase, threshold, changed);
      }
    }
    book->clusters[q].in_reject = true;
    for (int g : suspects) book->clusters[g].opponents.push_back(q);
    if (!suspects.empty()) Challenge(suspects, components, result);
    return;
  }
  book->clusters[q].in_reject = true;
}

template <class Pose>
std::vector<typename WarmEngine<Pose>::Impl::Bending> WarmEngine<Pose>::Impl::BendingClusters(
    int q, const std::vector<int>& components) const {
  std::vector<Bending> ranked;
  const size_t size = book->clusters[q].links.size();
  if (size < 2) return ranked;
  std::vector<int> owner;  // the good cluster each group is of
  std::vector<std::vector<int>> groups;
  for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
    const JudgedCluster& c = book->clusters[g];
    if (!c.in_good || !Within(components, g)) continue;
    if (c.links.size() < size) {
      owner.push_back(g);
      groups.push_back(c.links);
      continue;
    }
    // A larger cluster: its lone links, near no other of its links (a wrong link accepted with a
    // true revisit is one). Not its runs of two or more: a true run near a bend stands out too,
    // and challenged alone early on it can fall (Manhattan + 1000 local-grouped, seed 11).
    for (int e : c.links) {
      if (!Lone(e, c.links)) continue;
      owner.push_back(g);
      groups.push_back({e});
    }
  }
  if (groups.empty()) return ranked;
  const std::vector<double> removal = good.LinearizeRemovals(groups);
  for (size_t k = 0; k < groups.size(); ++k) {
    const double index = removal[k] / Threshold(d * static_cast<double>(groups[k].size()));
    if (index < 1.0) continue;
    ranked.push_back({index, owner[k], groups[k]});
  }
  return ranked;
}

template <class Pose>
int WarmEngine<Pose>::Impl::SuspectOf(const Bending& b) {
  const bool part = b.links.size() < book->clusters[b.cluster].links.size();
  return part ? SplitOffGood(b.cluster, b.links) : b.cluster;
}

template <class Pose>
void WarmEngine<Pose>::Impl::MergeBack(int part, int g) {
  JudgedCluster& p = book->clusters[part];
  for (int e : p.links) book->decisions[e].cluster = g;
  std::vector<int>& links = book->clusters[g].links;
  links.insert(links.end(), p.links.begin(), p.links.end());
  p.links.clear();
  p.in_good = false;
}

template <class Pose>
int WarmEngine<Pose>::Impl::SplitOffGood(int g, const std::vector<int>& links) {
  const double accepted_variance = book->clusters[g].accepted_variance;
  const int part = SplitOff(g, links);
  book->clusters[part].in_good = true;
  book->clusters[part].in_r = true;
  book->clusters[part].accepted_variance = accepted_variance;
  book->clusters[part].checked_links = book->clusters[g].checked_links;
  book->clusters[part].checked_variance = book->clusters[g].checked_variance;
  return part;
}

template <class Pose>
int WarmEngine<Pose>::Impl::SplitOff(int q, const std::vector<int>& links) {
  const int part = book->AddCluster(book->clusters[q].session_a, book->clusters[q].session_b);
  book->clusters[part].closed = true;
  book->clusters[part].links = links;
  std::vector<int>& kept = book->clusters[q].links;
  for (int e : links) {
    kept.erase(std::remove(kept.begin(), kept.end(), e), kept.end());
    book->decisions[e].cluster = part;
  }
  return part;
}

template <class Pose>
WarmEngine<Pose>::WarmEngine(PoseGraph<Pose>* graph,
                             const IrrrOptions* options,
                             DecisionBook* book,
                             std::vector<Pose>* estimate,
                             const std::vector<Pose>* dead_reckoning)
    : impl_(std::make_unique<Impl>(graph, options, book, estimate, dead_reckoning)) {}

template <class Pose>
WarmEngine<Pose>::~WarmEngine() = default;

template <class Pose>
void WarmEngine<Pose>::AddPose(int vertex) {
  impl_->good.AddPose(vertex);
  impl_->pairwise.Update();
}

template <class Pose>
void WarmEngine<Pose>::Release() {
  impl_->released = true;
}

template <class Pose>
bool WarmEngine<Pose>::HasReleased() const {
  const Impl& m = *impl_;
  if (!m.released || m.CurrentScale().known) return false;
  for (int q : m.Waiting()) {
    if (!m.book->clusters[q].held) return true;
  }
  return false;
}

template <class Pose>
bool WarmEngine<Pose>::HasDeferred() const {
  return impl_->has_deferred;
}

template <class Pose>
void WarmEngine<Pose>::Step(int cluster, StepResult* result) {
  impl_->Step(cluster, result);
}

template <class Pose>
std::vector<int> WarmEngine<Pose>::Impl::RefutedOdometry() const {
  std::vector<int> odometry;
  for (int e = 0; e < graph->num_edges(); ++e) {
    if (graph->edge(e).kind == EdgeKind::kOdometry && weakened.count(e) == 0) odometry.push_back(e);
  }
  if (odometry.empty()) return {};
  // The odometry's own variance factor: the median removal statistic per degree of freedom over
  // a sample spread along the trajectory (edges no loop spans have none and are left out).
  std::vector<std::vector<int>> sample;
  const size_t stride = std::max<size_t>(1, odometry.size() / kOdometrySample);
  for (size_t k = 0; k < odometry.size(); k += stride) sample.push_back({odometry[k]});
  std::vector<double> per_dof;
  for (double removal : good.LinearizeRemovals(sample)) {
    if (removal > 0.0 && std::isfinite(removal)) per_dof.push_back(removal / d);
  }
  if (per_dof.size() < kOdometrySample / 4) return {};
  std::nth_element(per_dof.begin(), per_dof.begin() + per_dof.size() / 2, per_dof.end());
  // The median of chi2(d)/d is about 1 - 2/(9d) (Wilson-Hilferty).
  const double odometry_factor = per_dof[per_dof.size() / 2] / (1.0 - 2.0 / (9.0 * d));
  const double threshold = kScreenMargin * ThresholdsAt(std::max(variance, odometry_factor)).Of(d);
  std::vector<std::vector<int>> candidates;
  for (int e : odometry) {
    if (good.EdgeChi2(e) >= threshold / kScreenMargin) candidates.push_back({e});
  }
  std::vector<int> refuted;
  if (candidates.empty()) return refuted;
  const std::vector<double> removal = good.LinearizeRemovals(candidates);
  for (size_t k = 0; k < candidates.size(); ++k) {
    if (removal[k] >= threshold) refuted.push_back(candidates[k].front());
  }
  return refuted;
}

template <class Pose>
std::vector<int> WarmEngine<Pose>::OdometryFaults() const {
  std::vector<int> faults = impl_->RefutedOdometry();
  for (const auto& [e, unused] : impl_->weakened) faults.push_back(e);
  std::sort(faults.begin(), faults.end());
  return faults;
}

template <class Pose>
std::vector<int> WarmEngine<Pose>::WeakenedOdometry() const {
  std::vector<int> edges;
  for (const auto& [e, unused] : impl_->weakened) edges.push_back(e);
  return edges;
}

template <class Pose>
const typename Pose::Matrix& WarmEngine<Pose>::GivenInformation(int edge) const {
  const auto it = impl_->weakened.find(edge);
  return it != impl_->weakened.end() ? it->second : impl_->graph->edge(edge).information;
}

template <class Pose>
void WarmEngine<Pose>::RestoreWeakened(const std::vector<int>& edges) {
  impl_->Weaken(edges);
}

template <class Pose>
std::vector<int> WarmEngine<Pose>::Components() const {
  return impl_->good.Components();
}

template <class Pose>
void WarmEngine<Pose>::Restore() {
  Impl& m = *impl_;
  m.screened.clear();
  m.good.Rebuild(m.GoodLoops(), m.AlignmentCap());
  m.has_deferred = m.options->step_budget > 0 && !m.Deferred().empty();
}

// With the engine, its Impl's members defined above (those of core/warm_reversal.cc and
// core/warm_scale.cc are instantiated there).
template class WarmEngine<Pose2>;
template class WarmEngine<Pose3>;

}  // namespace irrr
