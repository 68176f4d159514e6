#ifndef IRRR_CORE_IRRR_H_
#define IRRR_CORE_IRRR_H_

// iRRR: which loop hypotheses to trust (Latif, Cadena, Neira 2012, section III; open points as in
// algorithm-notes.md).
//
// An Irrr object is fed sessions, poses with their odometry and loop hypotheses in arrival order.
// Loop hypotheses are grouped into clusters (loop_clustering.h); every cluster that closes
// triggers a step:
//   1. Algorithm 1 (intra-cluster consistency) on the new cluster alone;
//   2. if it survives, the incremental Algorithm 3 over the component(s) the cluster touches,
//      where Algorithm 2 may also eliminate members of the good set (a reversal) and the reject
//      set is never cleared (III.B);
//   3. an optimization with the good set of those components, whose result is the new estimate.
// Sessions are independent until an accepted inter-session cluster joins them (III.C); a step
// only touches the components its cluster involves, and each component keeps its own frame (that
// of its earliest session's first pose).
//
// RunBatchRrr is the paper's batch Algorithm 3 (with its reject-set clearing) on a whole graph.

#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "core/loop_clustering.h"
#include "core/optimizer.h"
#include "core/pose_graph.h"
#include "core/status.h"
#include "core/test_statistics.h"

namespace irrr {

// Degrees of freedom of the graph test D_G^2 < chi2(alpha, d_G).
enum class GraphDegreesOfFreedom {
  kResidualRows,  // reference code: Pose::kDim x active edges
  kExact,         // residual rows minus free state dimensions
};

// Which decision engine judges the clusters.
enum class IrrrEngine {
  // The default: every check on the component's good-set optimum, kept up to date warm, with a
  // linearized screen before any nonlinear solve and every threshold scaled by the estimated
  // variance factor (core/warm_engine.h).
  kWarm,
  // Every check from dead reckoning, as the reference code (the paper-faithful preset, and the
  // strengthened cold tests of the "beyond the paper" options below).
  kCold,
};

struct IrrrOptions {
  IrrrEngine engine = IrrrEngine::kWarm;
  // Confidence of every chi-square test, in (0, 1). 0.999 by default: with the variance factor
  // estimated, a true cluster fails a test at 0.95 one time in twenty (a recall of about 0.7 on
  // Manhattan), while wrong ones stand far above either threshold. The paper-faithful preset: 0.95.
  double alpha = 0.999;
  // Warm engine: the variance factor of the information matrices (the residuals' real covariance
  // over the one the information claims). 0: estimated from the data's redundancy; a positive
  // value fixes it (1: trust the information as given).
  double variance_factor = 0.0;
  double cluster_gap = 50.0;  // t_g of eq. (6), in stamp units (poses for files, seconds live)
  GraphDegreesOfFreedom graph_dof = GraphDegreesOfFreedom::kResidualRows;
  // Beyond the paper (algorithm-notes): the joint test of Algorithm 2 also requires every tested
  // cluster's consistency index to be below 1, so that one wrong cluster cannot hide in the sum.
  bool require_each_cluster_consistent = true;
  // Beyond the paper: Algorithm 1 removes failing links one at a time and judges the rest again,
  // so that one wrong link clustered with true ones does not take them down with it. When the
  // graph test fails, every link is first tested alone with odometry, then the link without which
  // the others fit best is dropped until the rest pass. Off: the paper's Algorithm 1 (a failed
  // graph test rejects the whole cluster; failing links leave it in one go).
  bool prune_failing_clusters = true;
  // Beyond the paper: when Algorithm 2's joint test fails, the clusters with the largest
  // consistency indices (up to this many) are each left out in turn; if leaving out some of them
  // makes the rest pass, the smallest of those goes, else the paper's choice (largest index).
  // 1: the paper's rule.
  int elimination_lookahead = 3;
  // Beyond the paper: the links that leave a cluster in Algorithm 1 form a new cluster, judged
  // like any other (a consistent wrong group clustered in time with true loops, or the reverse).
  bool split_failing_links = true;
  // Beyond the paper: clusters of R that are not candidates when Algorithm 3 stops are each
  // tested alone against the good set (Algorithm 2), so that none stays undecided.
  bool settle_undecided = true;
  // Beyond the paper (incremental only): when a candidate falls in Algorithm 2 against good
  // clusters that are themselves inconsistent, earlier candidates that fell against the same good
  // clusters are tested again with it, so that later evidence can reverse an early wrong
  // acceptance instead of being rejected one cluster at a time.
  bool revive_opponents = true;
  // Beyond the paper (incremental only): when Algorithm 2 eliminates several clusters in one
  // call, they are tested once more against the resulting good set.
  bool retry_within_step = true;
  // Each check optimizes only the stretch of each session between its first and last loop
  // endpoint: the rest of an odometry chain has zero residual at the optimum, so the chi2 values
  // and decisions are those of the whole problem (off: every pose of the sessions involved).
  bool local_problems = true;
  // The joint tests of the incremental algorithm start from the previous step's estimate instead
  // of dead reckoning (off: dead reckoning, as the reference code).
  bool warm_start = false;
  // Speed (none changes a decision; irrr-bench-speed measures what each buys). An optimization
  // asked for again with the same loops, spans and start (the line-8 optimization after
  // Algorithm 1, the final one after a passing joint test, prefetched ones) is not run again.
  bool reuse_solves = true;
  // When Algorithm 2's joint test fails, the lookahead's leave-one-outs are solved in the order of
  // what is known of their rank before solving (links, good member) and stop once a passing one
  // cannot be outranked by those left (off: every one is solved).
  bool lazy_lookahead = true;
  // One optimizer is kept across solves, so that its symbolic analysis (ordering, elimination
  // tree, supernodes) serves every next solve of the same sparsity pattern (off: a fresh one each).
  bool reuse_analysis = true;
  // A bound on a cluster's links (the cost of Algorithm 1 on it grows with them): a full cluster
  // takes no more, and the next link starts a new cluster. 0: unbounded (the paper).
  int max_cluster_size = 0;
  OptimizerOptions optimizer;

  // The paper's tests as written: every "beyond the paper" rule above switched off.
  static IrrrOptions PaperFaithful();

  Status Validate() const;
};

// Runs body(0), ..., body(n - 1), possibly concurrently, and returns when all have returned. Core
// runs no threads itself: a caller that has a thread pool passes one (SetParallelFor), and iRRR
// then runs independent optimizations on it. Decisions do not depend on it: every result is
// committed in the serial order.
using ParallelFor = std::function<void(int n, const std::function<void(int)>& body)>;

enum class LoopState {
  kPending,              // not judged yet, or judged consistent on its own but not (yet) accepted
  kAccepted,             // in the good set
  kRejectedLinkTest,     // Algorithm 1: its own d_l^2 failed the per-link test
  kRejectedClusterTest,  // Algorithm 1: its cluster failed the graph test
  kRejectedJointTest,    // Algorithm 2: its cluster was inconsistent with the others
  kReversed,             // was accepted; later evidence rejected its cluster (Algorithm 2)
};

const char* LoopStateName(LoopState state);

// Why a loop hypothesis is where it is (algorithm-notes, "Decisions users can read").
struct LoopDecision {
  int cluster = -1;
  LoopState state = LoopState::kPending;
  int step = -1;  // step at which the state last changed (-1: never)
  // The statistic and threshold that decided: d_l^2 vs chi2(alpha, dim) for link tests and
  // accepted links, D_G^2 vs chi2(alpha, d_G) for the cluster test, the cluster's D_C^2 vs
  // chi2(alpha, d_C) for the joint test.
  double chi2 = std::numeric_limits<double>::quiet_NaN();
  double threshold = std::numeric_limits<double>::quiet_NaN();
};

// What an Irrr's steps have computed. Everything else an Irrr holds (graph, clusters, dead
// reckoning) follows from its inputs alone, so an Irrr fed the same inputs without running their
// steps and then given this state is the Irrr that ran them, bit for bit (the daemon's snapshots).
template <class Pose>
struct IrrrStepState {
  struct Cluster {
    std::vector<int> links;  // graph edge indices still in the cluster
    int session_a = -1;
    int session_b = -1;
    bool in_r = false;  // passed Algorithm 1
    bool in_good = false;
    bool in_reject = false;
    std::vector<int> opponents;  // clusters eliminated while this good one was inconsistent too
    // Warm engine: Algorithm 1's redundancy (for the variance factor), the variance factor the
    // cluster was accepted at (for Reversing), and whether it has closed (for waiting ones).
    double redundancy_chi2 = 0.0;
    double redundancy_dof = 0.0;
    double accepted_variance = 0.0;
    bool closed = false;
  };
  std::vector<LoopDecision> decisions;  // per graph edge
  std::vector<Pose> estimate;           // per vertex
  std::vector<Cluster> clusters;        // the judged clusters (splits included)
  std::vector<int> cluster_of;          // per clusterer cluster: its index in `clusters`
  int steps = 0;                        // steps run
  int judged = 0;                       // closed clusters judged so far, in closing order
};

struct StepResult {
  int step = -1;
  int cluster = -1;                // the cluster that triggered it
  std::vector<int> changed_loops;  // graph edge indices whose decision changed
  std::vector<int> sessions;       // sessions whose estimate was recomputed
  int solves = 0;                  // optimizations run
  int iterations = 0;              // their iterations (each one linearization and factorization)
  OptimizerSummary final_summary;  // of the optimization with the good set
  double variance_factor = 1.0;    // the variance factor the step's tests used
  double variance_estimate = 1.0;  // the one the data gave (warm engine; tests use at most 1)
  int reversals = 0;               // challenges that reversed good clusters (warm engine)
};

template <class Pose>
class Irrr {
 public:
  using Matrix = typename Pose::Matrix;

  // Options must be valid (checked, aborts otherwise).
  explicit Irrr(const IrrrOptions& options);

  // Input, in arrival order. Each validates like PoseGraph (graph untouched on error). A pose
  // gets its initial estimate by dead reckoning in its session's frame.
  Status AddSession(int64_t session_id, int* session_index);
  Status AddPose(int session,
                 int64_t vertex_id,
                 double stamp,
                 const Pose* odometry,
                 const Matrix* odometry_information,
                 int* vertex_index);
  // A loop hypothesis between two existing poses; returns its graph edge index.
  Status AddLoop(int from_vertex,
                 int to_vertex,
                 const Pose& measurement,
                 const Matrix& information,
                 int* edge_index);
  Status EndSession(int session);
  // Closes every open cluster (they are judged by the next steps).
  void Flush();

  // Independent optimizations (the checks a step is about to run) go to `parallel_for`, which
  // runs on `workers` threads (< 2, or an empty function: everything serial, the default).
  void SetParallelFor(ParallelFor parallel_for, int workers);

  bool HasPendingStep() const;
  // Judges the oldest closed cluster not judged yet. Requires HasPendingStep().
  StepResult RunStep();

  const PoseGraph<Pose>& graph() const;
  // Current estimate: each component in the frame of its earliest session's first pose.
  const std::vector<Pose>& estimate() const;
  // Decision of graph edge `edge` (odometry edges are never judged: kPending, cluster -1).
  const LoopDecision& decision(int edge) const;
  const LoopClusterer& clusters() const;
  // Component of every session under the current good set (numbered by earliest session).
  std::vector<int> Components() const;
  int num_steps() const;

  // What the steps have computed, and its restoration into an Irrr that was fed the same inputs
  // without running their steps. RestoreStepState fails, changing nothing, on a state that does
  // not fit this Irrr's graph and clusters.
  IrrrStepState<Pose> StepState() const;
  Status RestoreStepState(IrrrStepState<Pose> state);

  ~Irrr();
  Irrr(const Irrr&) = delete;
  Irrr& operator=(const Irrr&) = delete;

 private:
  struct State;
  std::unique_ptr<State> state_;
};

// The paper's batch RRR (Algorithm 3, reject set cleared whenever the good set grows) on every
// loop edge of `graph`, clustered in edge order with the given gap. Decisions come back per graph
// edge (odometry edges kPending), and `estimate` (if not null) receives the optimum with the good
// set. Options must be valid.
template <class Pose>
std::vector<LoopDecision> RunBatchRrr(const PoseGraph<Pose>& graph,
                                      const IrrrOptions& options,
                                      std::vector<Pose>* estimate,
                                      const ParallelFor& parallel_for = {},
                                      int workers = 1);

// One input event of a graph replayed in arrival order (algorithm-notes, "Files as input").
struct ArrivalEvent {
  enum class Kind {
    kPose,        // vertex `index` arrives with its odometry edge (none for a session's first)
    kLoop,        // loop edge `index` arrives (right after the later of its two poses)
    kEndSession,  // session `index` ends (right after its last pose and that pose's loops)
  };
  Kind kind = Kind::kPose;
  int index = -1;
};

// The arrival order of a whole graph: vertices in index order; each vertex's loops (edges whose
// later endpoint it is, in edge order) right after it; a session's end right after its last
// vertex and that vertex's loops.
template <class Pose>
std::vector<ArrivalEvent> ArrivalOrder(const PoseGraph<Pose>& graph);

// Replays a whole graph into an Irrr, one arrival event at a time, and maps the Irrr's vertex and
// edge indices back to the graph's. The graph must be valid (it was built through PoseGraph), so
// a rejected input is a broken invariant (aborts).
template <class Pose>
class GraphReplay {
 public:
  GraphReplay(const PoseGraph<Pose>& graph, Irrr<Pose>* irrr);

  // Feeds one event of ArrivalOrder(graph) (in that order).
  void Apply(const ArrivalEvent& event);
  // Decisions indexed like the graph's edges, estimate like its vertices (after the replay).
  std::vector<LoopDecision> Decisions() const;
  std::vector<Pose> Estimate() const;

 private:
  const PoseGraph<Pose>& graph_;
  Irrr<Pose>* irrr_;
  std::vector<int> odometry_into_;  // per graph vertex: its odometry edge, or -1
  std::vector<int> session_of_;     // graph session -> irrr session
  std::vector<int> vertex_of_;      // graph vertex -> irrr vertex
  std::vector<int> edge_of_;        // graph edge -> irrr edge
};

// Feeds a whole graph to an Irrr in arrival order (algorithm-notes, "Files as input"): vertices in
// index order, each with its odometry; a loop right after the later of its two poses (edge order
// among loops of one pose); a session ends with its last pose; every open cluster is flushed at the
// end; the steps run as clusters close. Decisions come back indexed like `graph`'s edges, and
// `estimate` (if not null) indexed like its vertices. `steps` (if not null) receives every step.
template <class Pose>
std::vector<LoopDecision> RunIncrementalIrrr(const PoseGraph<Pose>& graph,
                                             const IrrrOptions& options,
                                             std::vector<Pose>* estimate,
                                             std::vector<StepResult>* steps,
                                             const ParallelFor& parallel_for = {},
                                             int workers = 1);

extern template class Irrr<Pose2>;
extern template class Irrr<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_IRRR_H_
