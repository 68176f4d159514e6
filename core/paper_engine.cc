#include "core/paper_engine.h"

#include <algorithm>

#include "core/intra_cluster.h"

namespace irrr {

template <class Pose>
PaperEngine<Pose>::PaperEngine(const PoseGraph<Pose>* graph,
                               const IrrrOptions* options,
                               DecisionBook* book,
                               std::vector<Pose>* estimate,
                               const std::vector<Pose>* dead_reckoning)
    : graph_(graph),
      options_(options),
      book_(book),
      estimate_(estimate),
      problems_(graph, dead_reckoning, options->optimizer),
      thresholds_{options->alpha, 1.0, std::numeric_limits<double>::infinity()} {}

template <class Pose>
std::vector<int> PaperEngine<Pose>::LoopsOf(const std::vector<int>& clusters) const {
  std::vector<int> loops;
  for (int c : clusters) {
    const std::vector<int>& links = book_->clusters[c].links;
    loops.insert(loops.end(), links.begin(), links.end());
  }
  std::sort(loops.begin(), loops.end());
  return loops;
}

template <class Pose>
bool PaperEngine<Pose>::Within(const std::vector<char>& sessions, int cluster) const {
  const JudgedCluster& c = book_->clusters[cluster];
  return sessions[c.session_a] && sessions[c.session_b];
}

template <class Pose>
std::vector<int> PaperEngine<Pose>::GoodWithin(const std::vector<char>& sessions) const {
  std::vector<int> good;
  for (int c = 0; c < static_cast<int>(book_->clusters.size()); ++c) {
    if (book_->clusters[c].in_good && Within(sessions, c)) good.push_back(c);
  }
  return good;
}

template <class Pose>
double PaperEngine<Pose>::GraphThreshold(const OptimizerSummary& summary) const {
  const int rows = summary.residual_dimension;
  const int dof =
      options_->graph_dof == GraphDegreesOfFreedom::kExact ? rows - summary.free_parameters : rows;
  return thresholds_.Of(std::max(dof, 1));
}

template <class Pose>
LocalSolution PaperEngine<Pose>::Solve(const std::vector<char>& sessions,
                                       const std::vector<int>& clusters) {
  return problems_.Solve(sessions, LoopsOf(clusters), kAlignmentCap * thresholds_.Of(Pose::kDim));
}

template <class Pose>
void PaperEngine<Pose>::InterCluster(const std::vector<char>& sessions,
                                     std::vector<int> candidates,
                                     bool incremental,
                                     std::vector<int>* rejected,
                                     std::vector<int>* changed) {
  const double link_threshold = thresholds_.Of(Pose::kDim);
  while (!candidates.empty()) {
    std::vector<int> tested = GoodWithin(sessions);
    tested.insert(tested.end(), candidates.begin(), candidates.end());
    const LocalSolution solution = Solve(sessions, tested);
    const OptimizerSummary& summary = solution.summary;
    double cluster_chi2 = 0.0;
    double num_links = 0.0;
    int worst = -1;
    double worst_index = -1.0;
    double worst_chi2 = 0.0;
    double worst_threshold = 0.0;
    for (int c : tested) {
      double chi2 = 0.0;
      for (int e : book_->clusters[c].links) chi2 += summary.edge_chi2[e];
      const double threshold = thresholds_.Of(Pose::kDim * book_->clusters[c].links.size());
      cluster_chi2 += chi2;
      num_links += static_cast<double>(book_->clusters[c].links.size());
      // Incremental: members of the good set may be eliminated too (III.B).
      if ((incremental || !book_->clusters[c].in_good) && chi2 / threshold > worst_index) {
        worst_index = chi2 / threshold;
        worst = c;
        worst_chi2 = chi2;
        worst_threshold = threshold;
      }
    }
    const bool pass = solution.ok() && cluster_chi2 < thresholds_.Of(Pose::kDim * num_links) &&
                      summary.final_chi2 < GraphThreshold(summary);
    if (pass) {
      for (int c : tested) {
        book_->clusters[c].in_good = true;
        for (int e : book_->clusters[c].links) {
          book_->Set(e, LoopState::kAccepted, summary.edge_chi2[e], link_threshold, changed);
        }
      }
      return;
    }
    IRRR_CHECK(worst >= 0);
    JudgedCluster& c = book_->clusters[worst];
    const LoopState state = c.in_good ? LoopState::kReversed : LoopState::kRejectedJointTest;
    for (int e : c.links) book_->Set(e, state, worst_chi2, worst_threshold, changed);
    c.in_good = false;
    candidates.erase(std::remove(candidates.begin(), candidates.end(), worst), candidates.end());
    rejected->push_back(worst);
  }
}

template <class Pose>
void PaperEngine<Pose>::Algorithm3(const std::vector<char>& sessions,
                                   bool incremental,
                                   std::vector<int>* changed) {
  const double link_threshold = thresholds_.Of(Pose::kDim);
  auto count_good = [this]() {
    int n = 0;
    for (const JudgedCluster& c : book_->clusters) n += c.in_good ? 1 : 0;
    return n;
  };
  while (true) {
    std::vector<int> current;
    for (int c = 0; c < static_cast<int>(book_->clusters.size()); ++c) {
      const JudgedCluster& cluster = book_->clusters[c];
      if (cluster.in_r && !cluster.in_good && !cluster.in_reject && Within(sessions, c)) {
        current.push_back(c);
      }
    }
    if (current.empty()) return;
    // Line 8: the current set alone (algorithm-notes: not the good set).
    const LocalSolution solution = Solve(sessions, current);
    std::vector<int> candidates;
    for (int c : current) {
      bool any = false;
      for (int e : book_->clusters[c].links) {
        any = any || solution.summary.edge_chi2[e] < link_threshold;
      }
      if (any && solution.ok()) candidates.push_back(c);
    }
    if (candidates.empty()) return;
    const int good_before = count_good();
    std::vector<int> rejected;
    InterCluster(sessions, candidates, incremental, &rejected, changed);
    const int good_after = count_good();
    if (!incremental && good_after > good_before) {
      for (JudgedCluster& c : book_->clusters) c.in_reject = false;
    } else {
      for (int c : rejected) book_->clusters[c].in_reject = true;
    }
    // Batch RRR ends when a round neither grows the good set nor rejects anything new; the
    // incremental version always removes the candidates from the current set.
    if (!incremental && good_after <= good_before && rejected.empty()) return;
  }
}

template <class Pose>
std::vector<int> PaperEngine<Pose>::Components() const {
  std::vector<char> active(graph_->num_edges(), 0);
  for (const JudgedCluster& c : book_->clusters) {
    if (!c.in_good) continue;
    for (int e : c.links) active[e] = 1;
  }
  return SessionComponents(*graph_, active);
}

template <class Pose>
void PaperEngine<Pose>::Step(int cluster, StepResult* result) {
  const int solves_before = problems_.solves();
  const int iterations_before = problems_.iterations();
  const std::vector<int> component = Components();
  const JudgedCluster& c = book_->clusters[cluster];
  std::vector<char> sessions(graph_->num_sessions(), 0);
  for (int s = 0; s < graph_->num_sessions(); ++s) {
    sessions[s] = component[s] == component[c.session_a] || component[s] == component[c.session_b];
  }
  if (PaperIntraCluster(&problems_,
                        thresholds_,
                        options_->graph_dof == GraphDegreesOfFreedom::kExact,
                        cluster,
                        book_,
                        &result->changed_loops)) {
    Algorithm3(sessions, /*incremental=*/true, &result->changed_loops);
    const LocalSolution solution = problems_.Solve(sessions,
                                                   LoopsOf(GoodWithin(sessions)),
                                                   kAlignmentCap * thresholds_.Of(Pose::kDim),
                                                   estimate_);
    result->chi2 = solution.chi2;
    for (int s = 0; s < graph_->num_sessions(); ++s) {
      if (sessions[s]) result->sessions.push_back(s);
    }
  }
  result->solves = problems_.solves() - solves_before;
  result->iterations = problems_.iterations() - iterations_before;
}

template <class Pose>
void PaperEngine<Pose>::RunBatch() {
  const bool exact = options_->graph_dof == GraphDegreesOfFreedom::kExact;
  for (int c = 0; c < static_cast<int>(book_->clusters.size()); ++c) {
    PaperIntraCluster(&problems_, thresholds_, exact, c, book_, nullptr);
  }
  const std::vector<char> all(graph_->num_sessions(), 1);
  Algorithm3(all, /*incremental=*/false, nullptr);
  problems_.Solve(
      all, LoopsOf(GoodWithin(all)), kAlignmentCap * thresholds_.Of(Pose::kDim), estimate_);
}

template class PaperEngine<Pose2>;
template class PaperEngine<Pose3>;

}  // namespace irrr
