#include "core/intra_cluster.h"

#include <algorithm>

namespace irrr {
namespace {

double GraphThreshold(const TestThresholds& thresholds,
                      const OptimizerSummary& summary,
                      bool exact_dof) {
  const int rows = summary.residual_dimension;
  const int dof = exact_dof ? rows - summary.free_parameters : rows;
  return thresholds.Of(std::max(dof, 1));
}

template <class Pose>
LocalSolution SolveCluster(LocalProblems<Pose>* problems,
                           const TestThresholds& thresholds,
                           const std::vector<int>& links) {
  return problems->Solve(
      problems->SessionsOf(links), links, kAlignmentCap * thresholds.Of(Pose::kDim));
}

template <class Pose>
bool WarmIntraClusterImpl(LocalProblems<Pose>* problems,
                          const PairwiseConsistency<Pose>* pairwise,
                          const PairwiseConsistency<Pose>* pairwise_for_noise,
                          const TestThresholds& thresholds,
                          int cluster,
                          DecisionBook* book,
                          std::vector<int>* changed,
                          std::vector<int>* splits) {
  const double link_threshold = thresholds.Of(Pose::kDim);
  if (pairwise != nullptr && book->clusters[cluster].links.size() >= 2) {
    // Links that do not agree with the largest consistent set leave it as clusters of their own,
    // each judged below (after the cluster they left).
    const std::vector<std::vector<int>> subsets = pairwise->ConsistentSubsets(
        book->clusters[cluster].links, PairwiseThreshold<Pose>(thresholds));
    book->clusters[cluster].links = subsets.front();
    std::vector<int> parts;
    for (size_t k = 1; k < subsets.size(); ++k) {
      const int part =
          book->AddCluster(book->clusters[cluster].session_a, book->clusters[cluster].session_b);
      book->clusters[part].links = subsets[k];
      book->clusters[part].closed = true;
      for (int e : subsets[k]) book->decisions[e].cluster = part;
      parts.push_back(part);
    }
    const bool survived = WarmIntraClusterImpl<Pose>(
        problems, nullptr, pairwise_for_noise, thresholds, cluster, book, changed, splits);
    for (int part : parts) {
      splits->push_back(part);
      WarmIntraClusterImpl<Pose>(
          problems, nullptr, pairwise_for_noise, thresholds, part, book, changed, splits);
    }
    return survived;
  }
  std::vector<int> links = book->clusters[cluster].links;
  std::vector<std::pair<double, int>> set_aside;  // (d^2 when set aside, link)
  LocalSolution solution;
  while (!links.empty()) {
    solution = SolveCluster(problems, thresholds, links);
    const OptimizerSummary& summary = solution.summary;
    const double graph_threshold = GraphThreshold(thresholds, summary, true);
    const bool graph_passes = solution.ok() && summary.final_chi2 < graph_threshold;
    if (graph_passes) {
      std::vector<int> kept;
      for (int e : links) {
        const double chi2 = summary.edge_chi2[e];
        if (chi2 < link_threshold) {
          kept.push_back(e);
        } else {
          book->Set(e, LoopState::kRejectedLinkTest, chi2, link_threshold, changed);
          set_aside.push_back({chi2, e});
        }
      }
      if (kept.size() == links.size()) {
        for (int e : links) {
          book->Set(e, LoopState::kPending, summary.edge_chi2[e], link_threshold, changed);
        }
        break;
      }
      links = kept;
      continue;
    }
    if (links.size() == 1 || !solution.ok()) {
      for (int e : links) {
        book->Set(e, LoopState::kRejectedClusterTest, summary.final_chi2, graph_threshold, changed);
        set_aside.push_back({summary.edge_chi2[e], e});
      }
      links.clear();
      break;
    }
    // Inconsistent together: the link that strays most at the cluster's optimum leaves.
    const int worst = *std::max_element(links.begin(), links.end(), [&summary](int a, int b) {
      return summary.edge_chi2[a] < summary.edge_chi2[b];
    });
    book->Set(
        worst, LoopState::kRejectedLinkTest, summary.edge_chi2[worst], link_threshold, changed);
    set_aside.push_back({summary.edge_chi2[worst], worst});
    links.erase(std::find(links.begin(), links.end(), worst));
  }
  // Readmission: each link set aside, most plausible first, comes back if the cluster still
  // passes with it.
  if (!links.empty() && !set_aside.empty()) {
    std::sort(set_aside.begin(), set_aside.end());
    for (const auto& [unused, e] : set_aside) {
      links.push_back(e);
      const LocalSolution trial = SolveCluster(problems, thresholds, links);
      bool fits =
          trial.ok() && trial.summary.final_chi2 < GraphThreshold(thresholds, trial.summary, true);
      for (int member : links) fits = fits && trial.summary.edge_chi2[member] < link_threshold;
      if (!fits) {
        links.pop_back();
        continue;
      }
      solution = trial;
      for (int member : links) {
        book->Set(
            member, LoopState::kPending, trial.summary.edge_chi2[member], link_threshold, changed);
      }
    }
  }
  JudgedCluster& c = book->clusters[cluster];
  c.links = links;
  c.in_r = !links.empty();
  if (!c.in_r) return false;
  const RedundancySample sample = ClusterRedundancy(*pairwise_for_noise, links, solution);
  c.redundancy_chi2 = sample.chi2;
  c.redundancy_dof = sample.dof;
  // The links that stayed out: a cluster of their own.
  std::vector<int> left;
  for (const auto& [unused, e] : set_aside) {
    if (std::find(links.begin(), links.end(), e) == links.end()) left.push_back(e);
  }
  if (!left.empty()) {
    std::sort(left.begin(), left.end());
    const int split = book->AddCluster(c.session_a, c.session_b);
    book->clusters[split].links = left;
    book->clusters[split].closed = true;
    for (int e : left) book->decisions[e].cluster = split;
    splits->push_back(split);
    WarmIntraClusterImpl<Pose>(
        problems, nullptr, pairwise_for_noise, thresholds, split, book, changed, splits);
  }
  return true;
}

}  // namespace

template <class Pose>
bool PaperIntraCluster(LocalProblems<Pose>* problems,
                       const TestThresholds& thresholds,
                       bool exact_dof,
                       int cluster,
                       DecisionBook* book,
                       std::vector<int>* changed) {
  JudgedCluster& c = book->clusters[cluster];
  const LocalSolution solution = SolveCluster(problems, thresholds, c.links);
  const OptimizerSummary& summary = solution.summary;
  const double graph_threshold = GraphThreshold(thresholds, summary, exact_dof);
  const double link_threshold = thresholds.Of(Pose::kDim);
  if (!solution.ok() || !(summary.final_chi2 < graph_threshold)) {
    for (int e : c.links) {
      book->Set(e, LoopState::kRejectedClusterTest, summary.final_chi2, graph_threshold, changed);
    }
    c.links.clear();
  } else {
    std::vector<int> kept;
    for (int e : c.links) {
      const double chi2 = summary.edge_chi2[e];
      const bool pass = chi2 < link_threshold;
      if (pass) kept.push_back(e);
      book->Set(e,
                pass ? LoopState::kPending : LoopState::kRejectedLinkTest,
                chi2,
                link_threshold,
                changed);
    }
    c.links = kept;
  }
  c.in_r = !c.links.empty();
  return c.in_r;
}

template <class Pose>
bool WarmIntraCluster(LocalProblems<Pose>* problems,
                      const PairwiseConsistency<Pose>* pairwise,
                      const TestThresholds& thresholds,
                      int cluster,
                      DecisionBook* book,
                      std::vector<int>* changed,
                      std::vector<int>* splits) {
  IRRR_CHECK(pairwise != nullptr);
  return WarmIntraClusterImpl(
      problems, pairwise, pairwise, thresholds, cluster, book, changed, splits);
}

template <class Pose>
RedundancySample ClusterRedundancy(const PairwiseConsistency<Pose>& pairwise,
                                   const std::vector<int>& links,
                                   const LocalSolution& solution) {
  if (links.size() < 2 || !solution.ok()) return {};
  if (pairwise.Noiseless(links, kNoiseless * Pose::kDim)) return {};
  return {solution.chi2, solution.dof};
}

template bool PaperIntraCluster<Pose2>(
    LocalProblems<Pose2>*, const TestThresholds&, bool, int, DecisionBook*, std::vector<int>*);
template bool PaperIntraCluster<Pose3>(
    LocalProblems<Pose3>*, const TestThresholds&, bool, int, DecisionBook*, std::vector<int>*);
template bool WarmIntraCluster<Pose2>(LocalProblems<Pose2>*,
                                      const PairwiseConsistency<Pose2>*,
                                      const TestThresholds&,
                                      int,
                                      DecisionBook*,
                                      std::vector<int>*,
                                      std::vector<int>*);
template bool WarmIntraCluster<Pose3>(LocalProblems<Pose3>*,
                                      const PairwiseConsistency<Pose3>*,
                                      const TestThresholds&,
                                      int,
                                      DecisionBook*,
                                      std::vector<int>*,
                                      std::vector<int>*);
template RedundancySample ClusterRedundancy<Pose2>(const PairwiseConsistency<Pose2>&,
                                                   const std::vector<int>&,
                                                   const LocalSolution&);
template RedundancySample ClusterRedundancy<Pose3>(const PairwiseConsistency<Pose3>&,
                                                   const std::vector<int>&,
                                                   const LocalSolution&);

}  // namespace irrr
