#ifndef IRRR_CORE_PAPER_ENGINE_H_
#define IRRR_CORE_PAPER_ENGINE_H_

// The paper's Algorithms 2 and 3 as written (Latif, Cadena, Neira 2012; the reference code's
// choices where the paper leaves them open, algorithm-notes "Tests"), every optimization from
// dead reckoning: incremental iRRR (III.B; members of the good set may be eliminated too, the
// reject set is never cleared) and batch RRR (the reject set cleared whenever the good set
// grows). Kept for comparison with the warm engine (IrrrOptions::PaperFaithful()).
//
// Algorithm 2 (inter-cluster consistency): good and candidate clusters are optimized together;
// if the joint tests
//   D_C^2 = sum of the tested clusters' link d^2  <  chi2(alpha, dim x links)
//   D_G^2                                          <  chi2(alpha, d_G)
// pass, all are accepted; otherwise the cluster with the largest consistency index
// CI = D_C^2(cluster) / chi2(alpha, dim x its links) is eliminated and the rest tested again.
// Algorithm 3 runs Algorithm 2 on the clusters of R that its line-8 optimization (the current
// set alone) leaves consistent.

#include <vector>

#include "core/decisions.h"
#include "core/irrr_options.h"
#include "core/local_problem.h"
#include "core/pose_graph.h"
#include "core/test_statistics.h"

namespace irrr {

template <class Pose>
class PaperEngine {
 public:
  // Everything given must outlive the engine; `estimate` receives the optimum of the good set of
  // the sessions each step touches (one pose per vertex).
  PaperEngine(const PoseGraph<Pose>* graph,
              const IrrrOptions* options,
              DecisionBook* book,
              std::vector<Pose>* estimate,
              const std::vector<Pose>* dead_reckoning);

  // Incremental iRRR (III.B): Algorithm 1 on closed cluster `cluster`; if it survives, Algorithm
  // 3 over the components it touches; then the optimum of their good set is the new estimate.
  void Step(int cluster, StepResult* result);

  // Batch RRR (Algorithm 3 with the reject set cleared whenever the good set grows) over every
  // cluster of the book, which Algorithm 1 has not judged yet; the estimate receives the optimum
  // of the good set of every session.
  void RunBatch();

  // Every session's component under the good set, numbered by earliest session.
  std::vector<int> Components() const;

 private:
  std::vector<int> LoopsOf(const std::vector<int>& clusters) const;
  std::vector<int> GoodWithin(const std::vector<char>& sessions) const;
  bool Within(const std::vector<char>& sessions, int cluster) const;
  double GraphThreshold(const OptimizerSummary& summary) const;
  LocalSolution Solve(const std::vector<char>& sessions, const std::vector<int>& clusters);
  void InterCluster(const std::vector<char>& sessions,
                    std::vector<int> candidates,
                    bool incremental,
                    std::vector<int>* rejected,
                    std::vector<int>* changed);
  void Algorithm3(const std::vector<char>& sessions, bool incremental, std::vector<int>* changed);

  const PoseGraph<Pose>* graph_;
  const IrrrOptions* options_;
  DecisionBook* book_;
  std::vector<Pose>* estimate_;
  LocalProblems<Pose> problems_;
  TestThresholds thresholds_;
};

extern template class PaperEngine<Pose2>;
extern template class PaperEngine<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_PAPER_ENGINE_H_
