#ifndef IRRR_CORE_DECISIONS_H_
#define IRRR_CORE_DECISIONS_H_

// What iRRR has decided: each loop hypothesis's state with the statistic that decided it
// (algorithm-notes, "Decisions users can read"), and the judged clusters with the sets of the
// paper's Algorithms 1-3 they are in. Shared by both engines; it is also what a snapshot of an
// Irrr holds (IrrrStepState).

#include <limits>
#include <vector>

namespace irrr {

enum class LoopState {
  kPending,              // not judged yet, or judged consistent on its own but not (yet) accepted
  kAccepted,             // in the good set
  kRejectedLinkTest,     // Algorithm 1: its own d_l^2 failed the per-link test
  kRejectedClusterTest,  // Algorithm 1: its cluster failed the graph test
  kRejectedJointTest,    // Algorithm 2: its cluster was inconsistent with the others
  kReversed,             // was accepted; later evidence rejected its cluster (Algorithm 2)
};

const char* LoopStateName(LoopState state);

// Why a loop hypothesis is where it is.
struct LoopDecision {
  int cluster = -1;
  LoopState state = LoopState::kPending;
  int step = -1;  // step at which the state last changed (-1: never)
  // The statistic and threshold that decided: d_l^2 vs chi2(alpha, dim) for link tests and
  // accepted links, D_G^2 vs chi2(alpha, d_G) for the cluster test, the cluster's D_C^2 vs
  // chi2(alpha, d_C) (or the chi2 increase of the joint test) for the joint test; each threshold
  // scaled by the variance factor in use.
  double chi2 = std::numeric_limits<double>::quiet_NaN();
  double threshold = std::numeric_limits<double>::quiet_NaN();
};

// A judged cluster: the unit the tests accept or reject. Algorithm 1 may split a cluster; the
// links that leave then form a cluster of their own.
struct JudgedCluster {
  std::vector<int> links;  // graph edge indices still in the cluster
  int session_a = -1;
  int session_b = -1;
  bool in_r = false;       // passed Algorithm 1 (the paper's set R)
  bool in_good = false;    // in the good set
  bool in_reject = false;  // in the reject set
  bool closed = false;     // its clusterer cluster has closed (it is judged, or waits)
  bool held = false;       // warm engine: waits until the good set can check it
  // Warm engine, work a step budget left for later steps: a held cluster is due to be judged
  // again (the good set has grown), or a good cluster is due to be challenged by the refused
  // clusters among its opponents.
  bool deferred = false;
  // Warm engine: the good clusters it fell against while they were inconsistent too (Algorithm
  // 2's reversal), its Algorithm 1 redundancy (chi2 and degrees of freedom at its local optimum,
  // for the variance factor), the clusters' variance factor when it was accepted, and the factor
  // its links were last refused at (0: none refused).
  std::vector<int> opponents;
  double redundancy_chi2 = 0.0;
  double redundancy_dof = 0.0;
  double accepted_variance = 0.0;
  double refused_variance = 0.0;
  // Warm engine, good clusters: the good set's links and the variance factor when its runs were
  // last judged (at its acceptance, then by ReverseOutvoted once the evidence has grown).
  int checked_links = 0;
  double checked_variance = 0.0;
};

// The decisions and clusters of one graph, with the step that changes them.
struct DecisionBook {
  std::vector<LoopDecision> decisions;  // per graph edge
  std::vector<JudgedCluster> clusters;
  int step = 0;

  int AddCluster(int session_a, int session_b) {
    clusters.emplace_back();
    clusters.back().session_a = session_a;
    clusters.back().session_b = session_b;
    return static_cast<int>(clusters.size()) - 1;
  }

  // Sets a loop's state (recording the step and, if it changed, the loop in `changed`) and the
  // statistic that decided it.
  void Set(int edge, LoopState state, double chi2, double threshold, std::vector<int>* changed) {
    LoopDecision& d = decisions[edge];
    if (d.state != state) {
      d.state = state;
      d.step = step;
      if (changed != nullptr) changed->push_back(edge);
    }
    d.chi2 = chi2;
    d.threshold = threshold;
  }

  int Links(int cluster) const { return static_cast<int>(clusters[cluster].links.size()); }
};

}  // namespace irrr

#endif  // IRRR_CORE_DECISIONS_H_
