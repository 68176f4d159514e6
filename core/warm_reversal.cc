// Algorithm 2's reversal with later evidence, and the recovery after it: the part of the warm
// engine (core/warm_engine_impl.h) that takes good clusters out of the good set again.

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

#include "core/warm_engine_impl.h"

namespace irrr {
namespace {

// A good cluster accepted under a factor more than this many times today's is judged again.
constexpr double kRevalidateRatio = 2.0;
// Clusters refused while the variance factor was more than this many times smaller than today's
// are judged again (RejudgeRefused): KITTI 05's factor rises from 0.16 to 0.28 as loops are
// accepted, and two true links of one revisit refused at 0.19 (1520 -> 780, 1525 -> 780) pass
// at 0.28.
constexpr double kRefusedRatio = 1.2;
// Clusters that challenge good ones at once (Challenge), largest first.
constexpr size_t kMaxChallengers = 8;
// Good links or runs that ReverseOutvoted reverses in one step at most (each costs a rebuild of
// the good set).
constexpr int kMaxOutvotedPerStep = 8;
// A good cluster's runs are judged again (DueRuns) once the good set has this many times the links
// it had when they were last judged, or the variance factor has fallen by this ratio.
constexpr int kEvidenceGrowth = 2;
constexpr double kFactorFall = 1.5;
// Times a failed challenge names further suspects (MostStrained) and is tried again.
constexpr int kMaxWiderChallenges = 3;
// A bending run whose removal statistic stood below half its margin is judged again only once its
// strain (BendingRun) or the variance factor has changed by more than this ratio, or links have
// left the good set (RunJudgement): judging every bending run at every step took most of the
// parking garage's time (49 of 74 s).
constexpr double kStrainTolerance = 0.01;

bool Changed(double now, double then) { return std::abs(now - then) > kStrainTolerance * then; }

bool IsRefusal(LoopState state) {
  return state == LoopState::kRejectedLinkTest || state == LoopState::kRejectedClusterTest ||
         state == LoopState::kRejectedJointTest;
}

}  // namespace

template <class Pose>
void WarmEngine<Pose>::Impl::Revalidate(StepResult* result) {
  std::vector<int> suspects;
  for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
    const JudgedCluster& c = book->clusters[g];
    if (c.in_good && c.accepted_variance > kRevalidateRatio * clusters_variance) {
      suspects.push_back(g);
    }
  }
  if (suspects.empty()) return;
  for (int g : suspects) book->clusters[g].in_good = false;
  good.Rebuild(GoodLoops(), AlignmentCap());
  Rejudge(suspects, result);
  result->reversals += static_cast<int>(suspects.size());
}

template <class Pose>
void WarmEngine<Pose>::Impl::ReverseOutvoted(StepResult* result) {
  for (int round = 0; round < kMaxOutvotedPerStep; ++round) {
    // The candidates: groups of good links, each with its cluster, threshold and margin.
    struct Candidate {
      int cluster;
      double threshold;
      double margin;
    };
    std::vector<std::vector<int>> groups;
    std::vector<Candidate> candidates;
    for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
      const JudgedCluster& c = book->clusters[g];
      if (!c.in_good) continue;
      const double threshold = OwnLinkThreshold(g);
      for (int e : c.links) {
        if (good.EdgeChi2(e) < threshold) continue;
        groups.push_back({e});
        candidates.push_back({g, threshold, kScreenMargin});
      }
    }
    // The bending runs judged this round: groups[first_run] on, with their strains.
    const size_t first_run = groups.size();
    std::vector<double> strains;
    std::map<std::vector<int>, RunJudgement> judged;
    const long rebuilds = good.counters().rebuilds;
    for (BendingRun& run : BendingRuns()) {
      const auto last = run_judgements.find(run.links);
      if (last != run_judgements.end() && last->second.ratio < kBendingRunMargin / 2 &&
          !Changed(run.strain, last->second.strain) && !Changed(variance, last->second.variance) &&
          last->second.rebuilds == rebuilds) {
        judged.insert(*last);
        continue;
      }
      groups.push_back(std::move(run.links));
      candidates.push_back({run.cluster,
                            Threshold(d * static_cast<double>(groups.back().size())),
                            kBendingRunMargin});
      strains.push_back(run.strain);
    }
    // The runs of good clusters due to be judged again: groups[first_due] on.
    const size_t first_due = groups.size();
    std::vector<int> due_cluster;
    for (auto& [g, run] : DueRuns()) {
      groups.push_back(std::move(run));
      candidates.push_back(
          {g, Threshold(d * static_cast<double>(groups.back().size())), kBendingRunMargin});
      due_cluster.push_back(g);
    }
    // The parts of good clusters near links accepted at this step: groups[first_pinned] on.
    const size_t first_pinned = groups.size();
    for (auto& [g, part] : PinnedParts(due_cluster)) {
      groups.push_back(std::move(part));
      candidates.push_back(
          {g, Threshold(d * static_cast<double>(groups.back().size())), kScreenMargin});
    }
    const std::vector<double> removal =
        groups.empty() ? std::vector<double>() : good.LinearizeRemovals(groups);
    // A due cluster none of whose runs reaches its margin is checked until the evidence grows
    // again (a statistic that came out NaN, the matrix not positive definite, reaches nothing).
    std::map<int, bool> below;
    for (size_t k = first_due; k < first_pinned; ++k) {
      const bool passes = !(removal[k] >= candidates[k].margin * candidates[k].threshold);
      const auto [it, inserted] = below.insert({due_cluster[k - first_due], passes});
      if (!inserted) it->second = it->second && passes;
    }
    for (const auto& [g, passes] : below) {
      if (passes) MarkChecked(g);
    }
    for (size_t k = first_run; k < first_due; ++k) {
      judged[groups[k]] = {
          removal[k] / candidates[k].threshold, strains[k - first_run], variance, rebuilds};
    }
    run_judgements = std::move(judged);
    if (groups.empty()) return;
    int worst = -1;
    double worst_ratio = 0.0;
    for (size_t k = 0; k < groups.size(); ++k) {
      const double ratio = removal[k] / candidates[k].threshold;
      if (ratio >= candidates[k].margin && ratio >= worst_ratio) {
        worst_ratio = ratio;
        worst = static_cast<int>(k);
      }
    }
    if (worst < 0) return;
    const int g = candidates[worst].cluster;
    const int part =
        groups[worst].size() == book->clusters[g].links.size() ? g : SplitOff(g, groups[worst]);
    const int since = EarliestStep({part});
    book->clusters[part].in_good = false;
    good.Rebuild(GoodLoops(), AlignmentCap());
    Recover(since, {part}, ComponentsOf(part), result);
    Rejudge({part}, result);
    ++result->reversals;
  }
}

template <class Pose>
std::vector<std::pair<int, std::vector<int>>> WarmEngine<Pose>::Impl::DueRuns() {
  std::vector<std::pair<int, std::vector<int>>> due;
  const int links = GoodLinks();
  for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
    const JudgedCluster& c = book->clusters[g];
    if (!c.in_good || (links < kEvidenceGrowth * c.checked_links &&
                       kFactorFall * variance >= c.checked_variance)) {
      continue;
    }
    bool any = false;
    for (std::vector<int>& run : Runs(c.links)) {
      // Runs' last part holds the lone links.
      if (run.size() < 2 || run.size() > kMaxWeighedLinks || Lone(run.front(), run)) continue;
      due.push_back({g, std::move(run)});
      any = true;
    }
    if (!any) MarkChecked(g);
  }
  return due;
}

template <class Pose>
std::vector<std::pair<int, std::vector<int>>> WarmEngine<Pose>::Impl::PinnedParts(
    const std::vector<int>& skip) const {
  std::vector<int> ends;  // of the links accepted at this step, in vertex order
  for (int e = 0; e < graph->num_edges(); ++e) {
    const LoopDecision& decision = book->decisions[e];
    if (decision.state != LoopState::kAccepted || decision.step != book->step) continue;
    ends.push_back(graph->edge(e).from);
    ends.push_back(graph->edge(e).to);
  }
  std::vector<std::pair<int, std::vector<int>>> pinned;
  if (ends.empty()) return pinned;
  std::sort(ends.begin(), ends.end());
  auto near = [&](int v) {
    const int session = graph->vertex(v).session;
    for (auto it = std::lower_bound(ends.begin(), ends.end(), v - kPinWindow);
         it != ends.end() && *it <= v + kPinWindow;
         ++it) {
      if (graph->vertex(*it).session == session) return true;
    }
    return false;
  };
  for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
    const JudgedCluster& c = book->clusters[g];
    if (!c.in_good || std::find(skip.begin(), skip.end(), g) != skip.end()) continue;
    for (std::vector<int>& part : Parts(c.links)) {
      // What was accepted at this step is left out: its runs were weighed at their trial
      // (BendingParts), and a young revisit's true lone links stand at 4 times their threshold
      // and more until the map settles around them. So is what was accepted more than
      // kPinSteps steps ago.
      int newest = -1;
      for (int e : part) newest = std::max(newest, book->decisions[e].step);
      if (part.size() > kMaxWeighedLinks || newest >= book->step ||
          newest < book->step - kPinSteps) {
        continue;
      }
      const bool pinned_now = std::any_of(part.begin(), part.end(), [&](int e) {
        return near(graph->edge(e).from) || near(graph->edge(e).to);
      });
      if (!pinned_now) continue;
      // Only a part pulled away from its claim is weighed: its links' d^2 at the estimate have
      // grown since they were accepted (the d^2 recorded then).
      double now = 0.0;
      double accepted = 0.0;
      for (int e : part) {
        now += good.EdgeChi2(e);
        accepted += book->decisions[e].chi2;
      }
      if (now > kPinGrowth * accepted) pinned.push_back({g, std::move(part)});
    }
  }
  return pinned;
}

template <class Pose>
std::vector<typename WarmEngine<Pose>::Impl::BendingRun> WarmEngine<Pose>::Impl::BendingRuns()
    const {
  struct Strained {
    int session;
    int first;  // its first vertex
    double chi2;
  };
  std::vector<Strained> strained;
  for (int e = 0; e < graph->num_edges(); ++e) {
    const Edge<Pose>& edge = graph->edge(e);
    if (edge.kind != EdgeKind::kOdometry) continue;
    const int session = graph->vertex(edge.from).session;
    if (good.ComponentOf(session) < 0) continue;
    const double chi2 = good.EdgeChi2(e);
    if (chi2 < LinkThreshold()) continue;
    strained.push_back({session, LowerEnd(edge), chi2});
  }
  std::vector<BendingRun> bending;
  if (strained.empty()) return bending;
  for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
    const JudgedCluster& c = book->clusters[g];
    if (!c.in_good || c.links.empty() || c.session_a != c.session_b ||
        book->decisions[c.links.front()].step >= book->step) {
      continue;
    }
    for (std::vector<int>& run : Runs(c.links)) {
      int lo = std::numeric_limits<int>::max();
      int hi = -1;
      for (int e : run) {
        lo = std::min(lo, LowerEnd(graph->edge(e)));
        hi = std::max(hi, UpperEnd(graph->edge(e)));
      }
      double strain = 0.0;
      for (int e : run) strain += good.EdgeChi2(e);
      bool spans = false;
      for (const Strained& s : strained) {
        if (s.session == c.session_a && lo <= s.first && s.first < hi) {
          strain += s.chi2;
          spans = true;
        }
      }
      if (spans) bending.push_back({g, std::move(run), strain});
    }
  }
  return bending;
}

template <class Pose>
void WarmEngine<Pose>::Impl::RejudgeRefused(StepResult* result) {
  const int n = static_cast<int>(book->clusters.size());
  std::vector<char> risen(n, 0);
  bool any = false;
  for (int q = 0; q < n; ++q) {
    const JudgedCluster& c = book->clusters[q];
    risen[q] = !c.in_good && !c.held && c.refused_variance > 0.0 &&
               variance > kRefusedRatio * c.refused_variance;
    any = any || risen[q];
  }
  if (!any) return;
  // Only a cluster one of whose refused links would pass the test that refused it, its threshold
  // scaled by the rise, is judged again: wrong links stand tens to millions of times above theirs.
  std::vector<char> may_pass(n, 0);
  for (const LoopDecision& decision : book->decisions) {
    const int q = decision.cluster;
    if (q < 0 || !risen[q] || !IsRefusal(decision.state)) continue;
    const double rise = variance / book->clusters[q].refused_variance;
    if (decision.chi2 < decision.threshold * rise) may_pass[q] = 1;
  }
  std::vector<int> refused;
  for (int q = 0; q < n; ++q) {
    if (!may_pass[q]) continue;
    book->clusters[q].refused_variance = variance;
    refused.push_back(q);
  }
  if (!refused.empty()) Rejudge(refused, result);
}

template <class Pose>
int WarmEngine<Pose>::Impl::EarliestStep(const std::vector<int>& clusters) const {
  int earliest = book->step;
  for (int g : clusters) {
    for (int e : book->clusters[g].links) earliest = std::min(earliest, book->decisions[e].step);
  }
  return earliest;
}

template <class Pose>
void WarmEngine<Pose>::Impl::NoteRefusals(const std::vector<int>& changed) {
  for (int e : changed) {
    const LoopDecision& decision = book->decisions[e];
    if (IsRefusal(decision.state) && decision.cluster >= 0) {
      book->clusters[decision.cluster].refused_variance = variance;
    }
  }
}

template <class Pose>
void WarmEngine<Pose>::Impl::Rejudge(std::vector<int> clusters, StepResult* result) {
  std::vector<int> accepted_before;
  for (int g : clusters) {
    JudgedCluster& c = book->clusters[g];
    c.in_good = false;
    c.in_r = false;
    c.in_reject = false;
    c.links.clear();
  }
  for (int e = 0; e < graph->num_edges(); ++e) {
    const LoopDecision& decision = book->decisions[e];
    if (decision.cluster < 0 ||
        std::find(clusters.begin(), clusters.end(), decision.cluster) == clusters.end()) {
      continue;
    }
    book->clusters[decision.cluster].links.push_back(e);
    if (decision.state == LoopState::kAccepted) accepted_before.push_back(e);
  }
  SortLargestFirst(&clusters);
  ++rejudging;
  for (int g : clusters) Judge(g, result);
  --rejudging;
  for (int e : accepted_before) {
    const LoopDecision& decision = book->decisions[e];
    if (decision.state != LoopState::kAccepted) {
      book->Set(e, LoopState::kReversed, decision.chi2, decision.threshold, &result->changed_loops);
    }
  }
}

template <class Pose>
void WarmEngine<Pose>::Impl::Challenge(const std::vector<int>& suspects,
                                       const std::vector<int>& components,
                                       StepResult* result,
                                       bool deferrable) {
  if (rejudging > 0) return;  // one challenge at a time: what it re-judges does not challenge
  if (deferrable && OverBudget()) {
    for (int g : suspects) book->clusters[g].deferred = true;
    return;
  }
  std::vector<int> challengers;
  size_t challenger_links = 0;
  size_t smallest_suspect = std::numeric_limits<size_t>::max();
  for (int g : suspects) {
    smallest_suspect = std::min(smallest_suspect, book->clusters[g].links.size());
    for (int r : book->clusters[g].opponents) {
      const JudgedCluster& c = book->clusters[r];
      // A lone link cannot outvote anything: wrong ones fail against a good cluster one after
      // the other, each bending it, and none agrees with another.
      if (!c.in_reject || c.in_good || c.links.size() < 2 || !Within(components, r) ||
          std::find(challengers.begin(), challengers.end(), r) != challengers.end()) {
        continue;
      }
      challengers.push_back(r);
    }
  }
  SortLargestFirst(&challengers);
  if (challengers.size() > kMaxChallengers) challengers.resize(kMaxChallengers);
  for (int r : challengers) challenger_links += book->clusters[r].links.size();
  if (challenger_links <= smallest_suspect) return;
  if (suspects.size() >= 2 && Replace({suspects.front()}, challengers, components, result)) {
    return;
  }
  std::vector<int> strained;
  if (Replace(suspects, challengers, components, result, &strained)) return;
  // What the consistency index names may not be all that bends the map: a wrong group that
  // fits its own links by bending the odometry stays consistent, and the largest challenger
  // still fails without the suspects. Those the challenger strains join them.
  std::vector<int> wider = suspects;
  for (int round = 0; round < kMaxWiderChallenges; ++round) {
    if (strained.empty()) return;
    wider.insert(wider.end(), strained.begin(), strained.end());
    if (Replace(wider, challengers, components, result, &strained)) return;
  }
}

template <class Pose>
typename WarmEngine<Pose>::Impl::Weighed WarmEngine<Pose>::Impl::WeighedAgainst(
    int challenger, const std::vector<int>& suspects, const std::vector<int>& components) const {
  Weighed weighed;
  for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
    const JudgedCluster& c = book->clusters[g];
    if (!c.in_good || std::find(suspects.begin(), suspects.end(), g) != suspects.end()) continue;
    // A cluster as large as the challenger cannot be outvoted by it.
    if (!Within(components, g) || c.links.size() > kMaxWeighedLinks ||
        c.links.size() >= book->clusters[challenger].links.size()) {
      continue;
    }
    weighed.clusters.push_back(g);
    weighed.links.push_back(c.links);
  }
  return weighed;
}

template <class Pose>
std::vector<int> WarmEngine<Pose>::Impl::MostStrained(const Weighed& weighed) {
  std::vector<int> strained;
  for (const auto& [unused, k] : Refuted(weighed.links)) strained.push_back(weighed.clusters[k]);
  return strained;
}

template <class Pose>
void WarmEngine<Pose>::Impl::ChallengeAsWhole(const std::vector<int>& whole,
                                              const std::vector<int>& components,
                                              StepResult* result) {
  if (rejudging > 0) return;
  std::vector<int> failed;   // the runs of two links or more that failed
  std::vector<int> refused;  // their links
  for (int e : whole) {
    const int q = book->decisions[e].cluster;
    const JudgedCluster& c = book->clusters[q];
    if (!c.in_reject || c.links.size() < 2 ||
        std::find(failed.begin(), failed.end(), q) != failed.end()) {
      continue;
    }
    failed.push_back(q);
    refused.insert(refused.end(), c.links.begin(), c.links.end());
  }
  if (failed.size() < 2) return;  // one run has named its suspects already
  if (!good.Try(refused, AlignmentCap(), MaxIncrease(refused)).ok) return;
  // Every run of every good cluster, and each of their lone links on its own.
  std::vector<int> owner;
  std::vector<std::vector<int>> groups;
  for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
    const JudgedCluster& c = book->clusters[g];
    if (!c.in_good || !Within(components, g)) continue;
    for (std::vector<int>& part : Parts(c.links)) {
      owner.push_back(g);
      groups.push_back(std::move(part));
    }
  }
  const std::vector<std::pair<double, size_t>> ranked = Refuted(groups);
  good.Rollback();
  if (ranked.empty()) return;
  std::vector<std::pair<int, int>> parts;  // (part split off, the cluster it left)
  std::vector<int> suspects;               // most inconsistent first
  for (const auto& [index, k] : ranked) {
    suspects.push_back(SuspectOf({index, owner[k], groups[k]}));
    if (suspects.back() != owner[k]) parts.push_back({suspects.back(), owner[k]});
  }
  for (int g : suspects) {
    std::vector<int>& opponents = book->clusters[g].opponents;
    opponents.insert(opponents.end(), failed.begin(), failed.end());
  }
  Challenge(suspects, components, result);
  for (const auto& [part, g] : parts) {
    if (book->clusters[part].in_good && book->clusters[g].in_good) MergeBack(part, g);
  }
}

template <class Pose>
bool WarmEngine<Pose>::Impl::Replace(const std::vector<int>& suspects,
                                     const std::vector<int>& challengers,
                                     const std::vector<int>& components,
                                     StepResult* result,
                                     std::vector<int>* strained) {
  size_t good_links = 0;        // of the good set now, in the components involved
  size_t base_links = 0;        // of the good set being built, there
  std::vector<int> base_loops;  // the good set without the suspects
  for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
    const JudgedCluster& c = book->clusters[g];
    if (!c.in_good) continue;
    const size_t links = Within(components, g) ? c.links.size() : 0;
    good_links += links;
    if (std::find(suspects.begin(), suspects.end(), g) != suspects.end()) continue;
    base_links += links;
    base_loops.insert(base_loops.end(), c.links.begin(), c.links.end());
  }
  good.RebuildKeeping(base_loops, AlignmentCap());
  std::vector<int> taken;
  // What the first challenger strains, at its trial (open if `ok`).
  auto weigh = [&](int q, bool ok) {
    if (strained == nullptr || q != challengers.front()) return;
    *strained = ok ? MostStrained(WeighedAgainst(q, suspects, components)) : std::vector<int>();
  };
  auto take_if_passes = [&](int q) {
    const std::vector<int>& links = book->clusters[q].links;
    const typename GoodSet<Pose>::Trial trial = good.Try(links, AlignmentCap(), MaxIncrease(links));
    weigh(q, trial.ok);
    if (!trial.ok) return;
    if (!IncreasePasses(trial) || !Consistent(q)) {
      good.Rollback();
      return;
    }
    good.Commit();
    taken.push_back(q);
    base_links += book->clusters[q].links.size();
  };
  for (int r : challengers) {
    if (MayPass(r)) {
      take_if_passes(r);
    } else if (strained != nullptr && r == challengers.front()) {
      // It cannot pass, but what it strains is asked for: its trial, rolled back.
      const std::vector<int>& links = book->clusters[r].links;
      const bool ok = good.Try(links, AlignmentCap(), MaxIncrease(links)).ok;
      weigh(r, ok);
      if (ok) good.Rollback();
    }
  }
  // Without a challenger taken, the suspects taken back cannot make the good set larger. They are
  // tried back most strained first by the good set so built (the order given breaks ties): one
  // that a challenger taken conflicts with fails first, and the attempt ends as soon as it cannot
  // make the good set larger.
  if (!taken.empty()) {
    std::vector<std::pair<double, int>> by_strain;  // (-strain, suspect)
    for (int g : suspects) by_strain.push_back({-Strain(g), g});
    std::stable_sort(by_strain.begin(), by_strain.end(), [](const auto& a, const auto& b) {
      return a.first < b.first;
    });
    size_t untried = 0;  // links of the suspects not tried back yet
    for (int g : suspects) untried += book->clusters[g].links.size();
    for (const auto& [unused, g] : by_strain) {
      // Once even all the suspects left cannot make the good set larger, it stays as it was.
      if (base_links + untried <= good_links) break;
      untried -= book->clusters[g].links.size();
      take_if_passes(g);
    }
  }
  if (base_links <= good_links) {
    good.Restore();  // the good set stays as it was
    return false;
  }
  good.Release();
  for (int q : taken) {
    if (!book->clusters[q].in_good) Accept(q, &result->changed_loops);
  }
  std::vector<int> reversed;
  for (int g : suspects) {
    if (std::find(taken.begin(), taken.end(), g) == taken.end()) reversed.push_back(g);
  }
  const int since = EarliestStep(reversed);  // the earliest acceptance of a reversed cluster's link
  for (int g : reversed) book->clusters[g].in_good = false;
  Recover(since, reversed, components, result);
  Rejudge(reversed, result);
  ++result->reversals;
  return true;
}

template <class Pose>
bool WarmEngine<Pose>::Impl::MayPass(int q) {
  const JudgedCluster& c = book->clusters[q];
  if (good.ComponentOf(c.session_a) != good.ComponentOf(c.session_b)) return true;
  const std::vector<double> statistic = LinkStatistics(c.links);
  const double worst = *std::max_element(statistic.begin(), statistic.end());
  return worst <= kClusterMargin * Threshold(static_cast<double>(d * c.links.size()));
}

template <class Pose>
double WarmEngine<Pose>::Impl::Strain(int q) const {
  const JudgedCluster& c = book->clusters[q];
  if (good.ComponentOf(c.session_a) != good.ComponentOf(c.session_b)) return 0.0;
  double worst = 0.0;
  for (const LinearizedAddition& addition : good.LinearizeEach(c.links)) {
    worst = std::max(worst, addition.chi2_increase);
  }
  return worst / Threshold(static_cast<double>(d * c.links.size()));
}

template <class Pose>
void WarmEngine<Pose>::Impl::Recover(int since,
                                     const std::vector<int>& reversed,
                                     const std::vector<int>& components,
                                     StepResult* result) {
  std::vector<std::pair<int, int>> refused;  // (cluster, link)
  for (int e = 0; e < graph->num_edges(); ++e) {
    const LoopDecision& decision = book->decisions[e];
    if (decision.cluster < 0 || decision.step < since ||
        (decision.state != LoopState::kRejectedJointTest &&
         decision.state != LoopState::kRejectedLinkTest &&
         decision.state != LoopState::kReversed) ||
        std::find(reversed.begin(), reversed.end(), decision.cluster) != reversed.end() ||
        !Within(components, decision.cluster)) {
      continue;
    }
    refused.push_back({decision.cluster, e});
  }
  std::sort(refused.begin(), refused.end());
  std::vector<int> parts;
  for (size_t k = 0; k < refused.size();) {
    const int g = refused[k].first;
    std::vector<int> links;
    for (; k < refused.size() && refused[k].first == g; ++k) links.push_back(refused[k].second);
    parts.push_back(SplitOff(g, links));
  }
  SortLargestFirst(&parts);
  ++rejudging;
  for (int q : parts) Judge(q, result);
  --rejudging;
}

// Judge, JointTest and the rest are instantiated with the engine (core/warm_engine.cc).
#define IRRR_INSTANTIATE_REVERSAL(Pose)                                                          \
  template void WarmEngine<Pose>::Impl::Revalidate(StepResult*);                                 \
  template void WarmEngine<Pose>::Impl::RejudgeRefused(StepResult*);                             \
  template void WarmEngine<Pose>::Impl::ReverseOutvoted(StepResult*);                            \
  template std::vector<WarmEngine<Pose>::Impl::BendingRun> WarmEngine<Pose>::Impl::BendingRuns() \
      const;                                                                                     \
  template std::vector<std::pair<int, std::vector<int>>> WarmEngine<Pose>::Impl::PinnedParts(    \
      const std::vector<int>&) const;                                                            \
  template void WarmEngine<Pose>::Impl::NoteRefusals(const std::vector<int>&);                   \
  template int WarmEngine<Pose>::Impl::EarliestStep(const std::vector<int>&) const;              \
  template void WarmEngine<Pose>::Impl::Rejudge(std::vector<int>, StepResult*);                  \
  template void WarmEngine<Pose>::Impl::ChallengeAsWhole(                                        \
      const std::vector<int>&, const std::vector<int>&, StepResult*);                            \
  template void WarmEngine<Pose>::Impl::Challenge(                                               \
      const std::vector<int>&, const std::vector<int>&, StepResult*, bool);                      \
  template bool WarmEngine<Pose>::Impl::Replace(const std::vector<int>&,                         \
                                                const std::vector<int>&,                         \
                                                const std::vector<int>&,                         \
                                                StepResult*,                                     \
                                                std::vector<int>*);                              \
  template bool WarmEngine<Pose>::Impl::MayPass(int);                                            \
  template double WarmEngine<Pose>::Impl::Strain(int) const;                                     \
  template void WarmEngine<Pose>::Impl::Recover(                                                 \
      int, const std::vector<int>&, const std::vector<int>&, StepResult*);
IRRR_INSTANTIATE_REVERSAL(Pose2)
IRRR_INSTANTIATE_REVERSAL(Pose3)
#undef IRRR_INSTANTIATE_REVERSAL

}  // namespace irrr
