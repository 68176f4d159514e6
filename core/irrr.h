#ifndef IRRR_CORE_IRRR_H_
#define IRRR_CORE_IRRR_H_

// iRRR: which loop hypotheses to trust (Latif, Cadena, Neira 2012, section III; open points as in
// algorithm-notes.md).
//
// An Irrr object is fed sessions, poses with their odometry and loop hypotheses in arrival order.
// Loop hypotheses are grouped into clusters (loop_clustering.h); every cluster that closes
// triggers a step, which one of two engines runs (IrrrOptions::engine):
//  - the warm engine (default, core/warm_engine.h) judges the cluster against the good set's
//    optimum kept incrementally: a linearized screen, Algorithm 1, the joint test as a trial on
//    the good set, reversal of earlier acceptances as evidence adds up;
//  - the paper engine (core/paper_engine.h) runs Algorithm 1 and the incremental Algorithm 3 as
//    the paper writes them, every check from dead reckoning.
// Sessions are independent until an accepted inter-session cluster joins them (III.C); a step
// only touches the components its cluster involves, and each component keeps its own frame (that
// of its earliest session's first pose).
//
// RunBatchRrr is the paper's batch Algorithm 3 (with its reject-set clearing) on a whole graph.

#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include "core/decisions.h"
#include "core/irrr_options.h"
#include "core/loop_clustering.h"
#include "core/pose_graph.h"
#include "core/status.h"

namespace irrr {

// One input event, as an Irrr takes them (Irrr::Arrivals) or a graph is replayed in arrival order
// (algorithm-notes, "Files as input").
struct ArrivalEvent {
  enum class Kind {
    kPose,        // vertex `index` arrives with its odometry edge (none for a session's first)
    kLoop,        // loop edge `index` arrives (right after the later of its two poses)
    kEndSession,  // session `index` ends (right after its last pose and that pose's loops)
    kFlush,       // every open cluster closes (Irrr::Flush; `index` unused)
  };
  Kind kind = Kind::kPose;
  int index = -1;
};

// What an Irrr's steps have computed. Everything else an Irrr holds (graph, clusters, dead
// reckoning) follows from its inputs alone, so an Irrr fed the same inputs without running their
// steps and then given this state continues as the Irrr that ran them (the daemon's snapshots).
template <class Pose>
struct IrrrStepState {
  using Cluster = JudgedCluster;
  std::vector<LoopDecision> decisions;  // per graph edge
  std::vector<Pose> estimate;           // per vertex
  std::vector<Cluster> clusters;        // the judged clusters (splits included)
  std::vector<int> cluster_of;          // per clusterer cluster: its index in `clusters`
  int steps = 0;                        // steps run
  int judged = 0;                       // closed clusters judged so far, in closing order
  std::vector<int> weakened_odometry;   // odometry edges found faulty (WarmEngine)
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

  bool HasPendingStep() const;
  // Judges the oldest closed cluster not judged yet. Requires HasPendingStep().
  StepResult RunStep();

  const PoseGraph<Pose>& graph() const;
  // Current estimate: each component in the frame of its earliest session's first pose.
  const std::vector<Pose>& estimate() const;
  // Decision of graph edge `edge` (odometry edges are never judged: kPending, cluster -1).
  const LoopDecision& decision(int edge) const;
  const LoopClusterer& clusters() const;
  // Odometry edges found faulty (graph edge indices, ascending; WarmEngine::OdometryFaults). The
  // paper engine trusts odometry: none.
  std::vector<int> OdometryFaults() const;
  // Component of every session under the current good set (numbered by earliest session).
  std::vector<int> Components() const;
  int num_steps() const;

  // The inputs taken so far (the calls that succeeded), in the order taken: a session's AddSession
  // goes with its first pose. Fed again to a new Irrr in this order, from graph() with every edge's
  // GivenInformation, without running their steps, they rebuild this Irrr's graph and clusters, to
  // which RestoreStepState(StepState()) adds what the steps computed (the daemon's compacted
  // journal).
  const std::vector<ArrivalEvent>& Arrivals() const;
  // The information graph edge `edge` was given with (the engine may have weakened it since).
  const Matrix& GivenInformation(int edge) const;

  // What the steps have computed, and its restoration into an Irrr that was fed the same inputs
  // without running their steps. RestoreStepState fails, changing nothing, on a state that does
  // not fit this Irrr's graph and clusters. The warm engine rebuilds its good-set estimate from
  // the restored poses: the decisions that follow are those of the Irrr that ran the steps, the
  // poses agree with its to the rounding of its factor's updates.
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
                                      std::vector<Pose>* estimate);

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
  // Irrr::OdometryFaults as the graph's edge indices (ascending).
  std::vector<int> OdometryFaults() const;

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
                                             std::vector<StepResult>* steps);

// Odometry edges (ascending, as OdometryFaults gives them) grouped into stretches of adjacent
// edges: an error between two poses the loops hold shows in every edge between them.
template <class Pose>
std::vector<std::vector<int>> OdometryStretches(const PoseGraph<Pose>& graph,
                                                const std::vector<int>& edges) {
  std::vector<std::vector<int>> stretches;
  for (size_t k = 0; k < edges.size(); ++k) {
    if (k == 0 || graph.edge(edges[k]).from != graph.edge(edges[k - 1]).to)
      stretches.emplace_back();
    stretches.back().push_back(edges[k]);
  }
  return stretches;
}

extern template class Irrr<Pose2>;
extern template class Irrr<Pose3>;

}  // namespace irrr

#endif  // IRRR_CORE_IRRR_H_
