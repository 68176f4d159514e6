#include "core/irrr.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <memory>

#include "core/consensus.h"
#include "core/warm_engine.h"

namespace irrr {

using internal::Consensus;
using internal::WarmEngine;

IrrrOptions IrrrOptions::PaperFaithful() {
  IrrrOptions options;
  options.engine = IrrrEngine::kCold;
  options.alpha = 0.95;
  options.require_each_cluster_consistent = false;
  options.prune_failing_clusters = false;
  options.elimination_lookahead = 1;
  options.split_failing_links = false;
  options.settle_undecided = false;
  options.revive_opponents = false;
  options.retry_within_step = false;
  return options;
}

Status IrrrOptions::Validate() const {
  if (!(alpha > 0.0 && alpha < 1.0)) return Status::Error("alpha must be in (0, 1)");
  if (!(cluster_gap >= 0.0) || !std::isfinite(cluster_gap)) {
    return Status::Error("cluster_gap must be a finite number >= 0");
  }
  if (!(variance_factor >= 0.0) || !std::isfinite(variance_factor)) {
    return Status::Error("variance_factor must be a finite number >= 0 (0: estimated)");
  }
  if (elimination_lookahead < 1) return Status::Error("elimination_lookahead must be >= 1");
  if (max_cluster_size < 0) return Status::Error("max_cluster_size must be >= 0");
  if (Status s = optimizer.Validate(); !s.ok()) return Status::Error("optimizer: " + s.message());
  return Status::Ok();
}

const char* LoopStateName(LoopState state) {
  switch (state) {
    case LoopState::kPending:
      return "pending";
    case LoopState::kAccepted:
      return "accepted";
    case LoopState::kRejectedLinkTest:
      return "rejected_link_test";
    case LoopState::kRejectedClusterTest:
      return "rejected_cluster_test";
    case LoopState::kRejectedJointTest:
      return "rejected_joint_test";
    case LoopState::kReversed:
      return "reversed";
  }
  return "unknown";
}

template <class Pose>
struct Irrr<Pose>::State {
  explicit State(const IrrrOptions& o) : options(o), clusterer(o.cluster_gap, o.max_cluster_size) {
    consensus.graph = &graph;
    consensus.options = &options;
    consensus.decisions = &decisions;
    consensus.dead_reckoning = &dead_reckoning;
  }

  // Records clusters that closed, in closing order.
  void Closed(const std::vector<int>& clusters) {
    closed.insert(closed.end(), clusters.begin(), clusters.end());
  }

  IrrrOptions options;
  PoseGraph<Pose> graph;
  LoopClusterer clusterer;
  std::vector<LoopDecision> decisions;
  std::vector<Pose> estimate;
  std::vector<Pose> dead_reckoning;
  std::vector<int> closed;
  std::vector<int> consensus_of;  // consensus cluster of each clusterer cluster
  size_t next_closed = 0;
  Consensus<Pose> consensus;
  WarmEngine<Pose> warm_engine{&consensus, &estimate, options.optimizer};
};

template <class Pose>
Irrr<Pose>::Irrr(const IrrrOptions& options) {
  IRRR_CHECK(options.Validate().ok());
  state_ = std::make_unique<State>(options);
}

template <class Pose>
Irrr<Pose>::~Irrr() = default;

template <class Pose>
Status Irrr<Pose>::AddSession(int64_t session_id, int* session_index) {
  int index = -1;
  if (Status s = state_->graph.AddSession(session_id, &index); !s.ok()) return s;
  state_->consensus.odometry_of_session.emplace_back();
  if (session_index != nullptr) *session_index = index;
  return Status::Ok();
}

template <class Pose>
Status Irrr<Pose>::AddPose(int session,
                           int64_t vertex_id,
                           double stamp,
                           const Pose* odometry,
                           const Matrix* odometry_information,
                           int* vertex_index) {
  State& st = *state_;
  // The new pose continues its session's current estimate (optimized or dead reckoning).
  Pose initial;
  Pose dead_reckoning;
  if (session >= 0 && session < st.graph.num_sessions() && odometry != nullptr &&
      !st.graph.session(session).vertices.empty()) {
    const int previous = st.graph.session(session).vertices.back();
    initial = st.estimate[previous] * *odometry;
    dead_reckoning = st.dead_reckoning[previous] * *odometry;
  }
  const int edges_before = st.graph.num_edges();
  int index = -1;
  if (Status s = st.graph.AddPose(
          session, vertex_id, stamp, initial, odometry, odometry_information, &index);
      !s.ok()) {
    return s;
  }
  st.estimate.push_back(initial);
  st.dead_reckoning.push_back(dead_reckoning);
  for (int e = edges_before; e < st.graph.num_edges(); ++e) {
    st.decisions.emplace_back();
    st.consensus.odometry_of_session[session].push_back(e);
  }
  st.Closed(st.clusterer.AdvanceSession(session, stamp));
  if (vertex_index != nullptr) *vertex_index = index;
  return Status::Ok();
}

template <class Pose>
Status Irrr<Pose>::AddLoop(int from_vertex,
                           int to_vertex,
                           const Pose& measurement,
                           const Matrix& information,
                           int* edge_index) {
  State& st = *state_;
  int edge = -1;
  if (Status s = st.graph.AddLoop(from_vertex, to_vertex, measurement, information, &edge);
      !s.ok()) {
    return s;
  }
  const Vertex& from = st.graph.vertex(from_vertex);
  const Vertex& to = st.graph.vertex(to_vertex);
  const int cluster = st.clusterer.AddLink(edge, from.session, from.stamp, to.session, to.stamp);
  while (static_cast<int>(st.consensus_of.size()) <= cluster) {
    const LoopCluster& c = st.clusterer.cluster(static_cast<int>(st.consensus_of.size()));
    st.consensus_of.push_back(st.consensus.AddCluster(c.session_a, c.session_b));
  }
  st.consensus.links[st.consensus_of[cluster]].push_back(edge);
  st.decisions.emplace_back();
  st.decisions[edge].cluster = st.consensus_of[cluster];
  if (edge_index != nullptr) *edge_index = edge;
  return Status::Ok();
}

template <class Pose>
Status Irrr<Pose>::EndSession(int session) {
  if (session < 0 || session >= state_->graph.num_sessions()) {
    return Status::Error("unknown session index " + std::to_string(session));
  }
  state_->Closed(state_->clusterer.EndSession(session));
  state_->warm_engine.Release();
  return Status::Ok();
}

template <class Pose>
void Irrr<Pose>::Flush() {
  state_->Closed(state_->clusterer.CloseAll());
  state_->warm_engine.Release();
}

template <class Pose>
void Irrr<Pose>::SetParallelFor(ParallelFor parallel_for, int workers) {
  state_->consensus.parallel_for = std::move(parallel_for);
  state_->consensus.workers = workers;
}

template <class Pose>
bool Irrr<Pose>::HasPendingStep() const {
  return state_->next_closed < state_->closed.size() ||
         (state_->options.engine == IrrrEngine::kWarm && state_->warm_engine.HasReleased());
}

template <class Pose>
StepResult Irrr<Pose>::RunStep() {
  IRRR_CHECK(HasPendingStep());
  State& st = *state_;
  Consensus<Pose>& consensus = st.consensus;
  if (st.next_closed == st.closed.size()) {
    // Warm engine: clusters that waited for a variance factor, released by a flush or a session's
    // end, are judged with the information as given.
    StepResult result;
    result.step = consensus.step;
    st.warm_engine.Step(-1, &result);
    ++consensus.step;
    return result;
  }
  const int cluster = st.consensus_of[st.closed[st.next_closed++]];
  StepResult result;
  result.step = consensus.step;
  result.cluster = cluster;
  consensus.solves = 0;
  consensus.iterations = 0;

  if (st.options.engine == IrrrEngine::kWarm) {
    st.warm_engine.Closed(cluster);
    st.warm_engine.Step(cluster, &result);
    ++consensus.step;
    return result;
  }
  // The components (under the current good set) that the cluster touches.
  const std::vector<int> component = Components();
  consensus.warm = &st.estimate;
  consensus.warm_group = component;
  ++consensus.warm_version;
  std::vector<char> sessions(st.graph.num_sessions(), 0);
  for (int s = 0; s < st.graph.num_sessions(); ++s) {
    sessions[s] = component[s] == component[consensus.session_a[cluster]] ||
                  component[s] == component[consensus.session_b[cluster]];
  }
  // With workers to spare, Algorithm 1's first optimization and the joint test the step runs
  // if the cluster passes it whole (the common case) go side by side.
  std::vector<int> tested = consensus.GoodWithin(sessions);
  tested.push_back(cluster);
  consensus.Prefetch({consensus.Prepare(consensus.SessionsOf({cluster}), {cluster}, false),
                      consensus.Prepare(sessions, tested, true)});

  if (consensus.IntraCluster(cluster, &result.changed_loops)) {
    consensus.Algorithm3(sessions, /*incremental=*/true, &result.changed_loops);
    const auto solution =
        consensus.Solve(sessions, consensus.GoodWithin(sessions), true, &st.estimate);
    result.final_summary = solution.summary;
    for (int s = 0; s < st.graph.num_sessions(); ++s) {
      if (!sessions[s]) continue;
      result.sessions.push_back(s);
      for (int v : st.graph.session(s).vertices) st.estimate[v] = solution.estimate[v];
    }
  }
  result.solves = consensus.solves;
  result.iterations = consensus.iterations;
  ++consensus.step;
  return result;
}

template <class Pose>
const PoseGraph<Pose>& Irrr<Pose>::graph() const {
  return state_->graph;
}

template <class Pose>
const std::vector<Pose>& Irrr<Pose>::estimate() const {
  return state_->estimate;
}

template <class Pose>
const LoopDecision& Irrr<Pose>::decision(int edge) const {
  return state_->decisions[edge];
}

template <class Pose>
const LoopClusterer& Irrr<Pose>::clusters() const {
  return state_->clusterer;
}

template <class Pose>
int Irrr<Pose>::num_steps() const {
  return state_->consensus.step;
}

template <class Pose>
IrrrStepState<Pose> Irrr<Pose>::StepState() const {
  const State& st = *state_;
  const Consensus<Pose>& c = st.consensus;
  IrrrStepState<Pose> out;
  out.decisions = st.decisions;
  out.estimate = st.estimate;
  out.clusters.resize(c.links.size());
  for (size_t k = 0; k < c.links.size(); ++k) {
    typename IrrrStepState<Pose>::Cluster& cluster = out.clusters[k];
    cluster.links = c.links[k];
    cluster.session_a = c.session_a[k];
    cluster.session_b = c.session_b[k];
    cluster.in_r = c.in_r[k] != 0;
    cluster.in_good = c.in_good[k] != 0;
    cluster.in_reject = c.in_reject[k] != 0;
    cluster.opponents = c.opponents[k];
    cluster.redundancy_chi2 = c.redundancy[k].chi2;
    cluster.redundancy_dof = c.redundancy[k].dof;
    cluster.accepted_variance = st.warm_engine.AcceptedVariance(static_cast<int>(k));
    cluster.closed = st.warm_engine.IsClosed(static_cast<int>(k));
  }
  out.cluster_of = st.consensus_of;
  out.steps = c.step;
  out.judged = static_cast<int>(st.next_closed);
  return out;
}

template <class Pose>
Status Irrr<Pose>::RestoreStepState(IrrrStepState<Pose> state) {
  State& st = *state_;
  const int num_clusters = static_cast<int>(state.clusters.size());
  const int num_sessions = st.graph.num_sessions();
  auto fits = [](int index, int size) { return index >= 0 && index < size; };
  if (state.decisions.size() != static_cast<size_t>(st.graph.num_edges()) ||
      state.estimate.size() != static_cast<size_t>(st.graph.num_vertices())) {
    return Status::Error("the step state has " + std::to_string(state.decisions.size()) +
                         " edges and " + std::to_string(state.estimate.size()) +
                         " poses, the graph " + std::to_string(st.graph.num_edges()) + " and " +
                         std::to_string(st.graph.num_vertices()));
  }
  if (state.cluster_of.size() != static_cast<size_t>(st.clusterer.num_clusters())) {
    return Status::Error("the step state maps " + std::to_string(state.cluster_of.size()) +
                         " clusters, the clusterer has " +
                         std::to_string(st.clusterer.num_clusters()));
  }
  if (state.judged < 0 || static_cast<size_t>(state.judged) > st.closed.size() || state.steps < 0) {
    return Status::Error("the step state has judged " + std::to_string(state.judged) +
                         " clusters, but only " + std::to_string(st.closed.size()) + " closed");
  }
  for (int k : state.cluster_of) {
    if (!fits(k, num_clusters)) return Status::Error("the step state maps to an unknown cluster");
  }
  for (const LoopDecision& d : state.decisions) {
    if (d.cluster != -1 && !fits(d.cluster, num_clusters)) {
      return Status::Error("a decision names an unknown cluster");
    }
  }
  for (const Pose& pose : state.estimate) {
    if (!pose.IsFinite()) return Status::Error("the step state's estimate is not finite");
  }
  for (const auto& cluster : state.clusters) {
    if (!fits(cluster.session_a, num_sessions) || !fits(cluster.session_b, num_sessions)) {
      return Status::Error("a cluster names an unknown session");
    }
    for (int e : cluster.links) {
      if (!fits(e, st.graph.num_edges()) || st.graph.edge(e).kind != EdgeKind::kLoop) {
        return Status::Error("a cluster holds an edge that is not a loop of the graph");
      }
    }
    for (int k : cluster.opponents) {
      if (!fits(k, num_clusters)) return Status::Error("a cluster names an unknown opponent");
    }
    for (double v : {cluster.redundancy_chi2, cluster.redundancy_dof, cluster.accepted_variance}) {
      if (!(v >= 0.0) || !std::isfinite(v)) {
        return Status::Error(
            "a cluster's redundancy or variance factor is not a finite number >= 0");
      }
    }
  }
  Consensus<Pose>& c = st.consensus;
  c.links.clear();
  c.session_a.clear();
  c.session_b.clear();
  c.in_r.clear();
  c.in_good.clear();
  c.in_reject.clear();
  c.opponents.clear();
  c.redundancy.clear();
  st.warm_engine.Clear();
  for (auto& cluster : state.clusters) {
    const int k = c.AddCluster(cluster.session_a, cluster.session_b);
    c.links[k] = std::move(cluster.links);
    c.in_r[k] = cluster.in_r;
    c.in_good[k] = cluster.in_good;
    c.in_reject[k] = cluster.in_reject;
    c.opponents[k] = std::move(cluster.opponents);
    c.redundancy[k] = {cluster.redundancy_chi2, cluster.redundancy_dof};
    st.warm_engine.Restore(k, cluster.accepted_variance, cluster.closed);
  }
  c.step = state.steps;
  c.memo.clear();
  c.memo_order.clear();
  ++c.warm_version;
  st.decisions = std::move(state.decisions);
  st.estimate = std::move(state.estimate);
  st.consensus_of = std::move(state.cluster_of);
  st.next_closed = static_cast<size_t>(state.judged);
  return Status::Ok();
}

template <class Pose>
std::vector<int> Irrr<Pose>::Components() const {
  const State& st = *state_;
  std::vector<char> active(st.graph.num_edges(), 0);
  for (int c = 0; c < static_cast<int>(st.consensus.in_good.size()); ++c) {
    if (!st.consensus.in_good[c]) continue;
    for (int e : st.consensus.links[c]) active[e] = 1;
  }
  return SessionComponents(st.graph, active);
}

template <class Pose>
std::vector<LoopDecision> RunBatchRrr(const PoseGraph<Pose>& graph,
                                      const IrrrOptions& options,
                                      std::vector<Pose>* estimate,
                                      const ParallelFor& parallel_for,
                                      int workers) {
  IRRR_CHECK(options.Validate().ok());
  std::vector<LoopDecision> decisions(graph.num_edges());
  Consensus<Pose> consensus;
  consensus.parallel_for = parallel_for;
  consensus.workers = workers;
  consensus.graph = &graph;
  consensus.options = &options;
  consensus.decisions = &decisions;
  const std::vector<Pose> dead_reckoning = graph.OdometryEstimate();
  consensus.dead_reckoning = &dead_reckoning;
  consensus.odometry_of_session.resize(graph.num_sessions());

  // Cluster in arrival order: a loop arrives with the later of its two poses.
  std::vector<int> loops;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kOdometry) {
      consensus.odometry_of_session[graph.vertex(graph.edge(e).to).session].push_back(e);
    } else {
      loops.push_back(e);
    }
  }
  auto arrival = [&graph](int e) { return std::max(graph.edge(e).from, graph.edge(e).to); };
  std::stable_sort(
      loops.begin(), loops.end(), [&](int a, int b) { return arrival(a) < arrival(b); });
  LoopClusterer clusterer(options.cluster_gap, options.max_cluster_size);
  for (int e : loops) {
    const Vertex& from = graph.vertex(graph.edge(e).from);
    const Vertex& to = graph.vertex(graph.edge(e).to);
    const int c = clusterer.AddLink(e, from.session, from.stamp, to.session, to.stamp);
    if (c >= static_cast<int>(consensus.links.size())) {
      consensus.AddCluster(clusterer.cluster(c).session_a, clusterer.cluster(c).session_b);
    }
    consensus.links[c].push_back(e);
    decisions[e].cluster = c;
  }
  clusterer.CloseAll();

  // Clusters split off by Algorithm 1 are appended and judged in the same pass. Their first
  // optimizations are independent: prefetched a batch at a time.
  const int batch = 2 * std::max(workers, 1);
  for (int c = 0; c < clusterer.num_clusters(); ++c) {
    if (c % batch == 0) {
      std::vector<typename Consensus<Pose>::Problem> next;
      for (int k = c; k < std::min(c + batch, clusterer.num_clusters()); ++k) {
        next.push_back(consensus.Prepare(consensus.SessionsOf({k}), {k}, false));
      }
      consensus.Prefetch(next);
    }
    consensus.IntraCluster(c, nullptr);
  }
  const std::vector<char> all_sessions(graph.num_sessions(), 1);
  consensus.Algorithm3(all_sessions, /*incremental=*/false, nullptr);
  const auto solution =
      consensus.Solve(all_sessions, consensus.GoodWithin(all_sessions), false, &dead_reckoning);
  if (estimate != nullptr) *estimate = solution.estimate;
  return decisions;
}

template <class Pose>
std::vector<ArrivalEvent> ArrivalOrder(const PoseGraph<Pose>& graph) {
  std::vector<std::vector<int>> loops_at(graph.num_vertices());
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose>& edge = graph.edge(e);
    if (edge.kind == EdgeKind::kLoop) loops_at[std::max(edge.from, edge.to)].push_back(e);
  }
  std::vector<ArrivalEvent> events;
  events.reserve(graph.num_vertices() + graph.num_edges() + graph.num_sessions());
  for (int v = 0; v < graph.num_vertices(); ++v) {
    events.push_back({ArrivalEvent::Kind::kPose, v});
    for (int e : loops_at[v]) events.push_back({ArrivalEvent::Kind::kLoop, e});
    const int session = graph.vertex(v).session;
    if (graph.session(session).vertices.back() == v) {
      events.push_back({ArrivalEvent::Kind::kEndSession, session});
    }
  }
  return events;
}

template <class Pose>
GraphReplay<Pose>::GraphReplay(const PoseGraph<Pose>& graph, Irrr<Pose>* irrr)
    : graph_(graph),
      irrr_(irrr),
      odometry_into_(graph.num_vertices(), -1),
      session_of_(graph.num_sessions(), -1),
      vertex_of_(graph.num_vertices(), -1),
      edge_of_(graph.num_edges(), -1) {
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kOdometry) odometry_into_[graph.edge(e).to] = e;
  }
}

template <class Pose>
void GraphReplay<Pose>::Apply(const ArrivalEvent& event) {
  switch (event.kind) {
    case ArrivalEvent::Kind::kPose: {
      const int v = event.index;
      const Vertex& vertex = graph_.vertex(v);
      int& session = session_of_[vertex.session];
      if (session < 0) {
        IRRR_CHECK(irrr_->AddSession(graph_.session(vertex.session).id, &session).ok());
      }
      const int odometry = odometry_into_[v];
      const Edge<Pose>* edge = odometry >= 0 ? &graph_.edge(odometry) : nullptr;
      IRRR_CHECK(irrr_
                     ->AddPose(session,
                               vertex.id,
                               vertex.stamp,
                               edge ? &edge->measurement : nullptr,
                               edge ? &edge->information : nullptr,
                               &vertex_of_[v])
                     .ok());
      if (odometry >= 0) edge_of_[odometry] = irrr_->graph().num_edges() - 1;
      break;
    }
    case ArrivalEvent::Kind::kLoop: {
      const Edge<Pose>& loop = graph_.edge(event.index);
      IRRR_CHECK(irrr_
                     ->AddLoop(vertex_of_[loop.from],
                               vertex_of_[loop.to],
                               loop.measurement,
                               loop.information,
                               &edge_of_[event.index])
                     .ok());
      break;
    }
    case ArrivalEvent::Kind::kEndSession:
      IRRR_CHECK(irrr_->EndSession(session_of_[event.index]).ok());
      break;
  }
}

template <class Pose>
std::vector<LoopDecision> GraphReplay<Pose>::Decisions() const {
  std::vector<LoopDecision> decisions(graph_.num_edges());
  for (int e = 0; e < graph_.num_edges(); ++e) decisions[e] = irrr_->decision(edge_of_[e]);
  return decisions;
}

template <class Pose>
std::vector<Pose> GraphReplay<Pose>::Estimate() const {
  std::vector<Pose> estimate(graph_.num_vertices());
  for (int v = 0; v < graph_.num_vertices(); ++v) estimate[v] = irrr_->estimate()[vertex_of_[v]];
  return estimate;
}

template <class Pose>
std::vector<LoopDecision> RunIncrementalIrrr(const PoseGraph<Pose>& graph,
                                             const IrrrOptions& options,
                                             std::vector<Pose>* estimate,
                                             std::vector<StepResult>* steps,
                                             const ParallelFor& parallel_for,
                                             int workers) {
  Irrr<Pose> irrr(options);
  irrr.SetParallelFor(parallel_for, workers);
  GraphReplay<Pose> replay(graph, &irrr);
  auto run_steps = [&]() {
    while (irrr.HasPendingStep()) {
      StepResult step = irrr.RunStep();
      if (steps != nullptr) steps->push_back(std::move(step));
    }
  };
  for (const ArrivalEvent& event : ArrivalOrder(graph)) {
    replay.Apply(event);
    run_steps();
  }
  irrr.Flush();
  run_steps();
  if (estimate != nullptr) *estimate = replay.Estimate();
  return replay.Decisions();
}

template class Irrr<Pose2>;
template class Irrr<Pose3>;
template class GraphReplay<Pose2>;
template class GraphReplay<Pose3>;
template std::vector<LoopDecision> RunIncrementalIrrr<Pose2>(const PoseGraph<Pose2>&,
                                                             const IrrrOptions&,
                                                             std::vector<Pose2>*,
                                                             std::vector<StepResult>*,
                                                             const ParallelFor&,
                                                             int);
template std::vector<LoopDecision> RunIncrementalIrrr<Pose3>(const PoseGraph<Pose3>&,
                                                             const IrrrOptions&,
                                                             std::vector<Pose3>*,
                                                             std::vector<StepResult>*,
                                                             const ParallelFor&,
                                                             int);
template std::vector<ArrivalEvent> ArrivalOrder<Pose2>(const PoseGraph<Pose2>&);
template std::vector<ArrivalEvent> ArrivalOrder<Pose3>(const PoseGraph<Pose3>&);
template std::vector<LoopDecision> RunBatchRrr<Pose2>(
    const PoseGraph<Pose2>&, const IrrrOptions&, std::vector<Pose2>*, const ParallelFor&, int);
template std::vector<LoopDecision> RunBatchRrr<Pose3>(
    const PoseGraph<Pose3>&, const IrrrOptions&, std::vector<Pose3>*, const ParallelFor&, int);

}  // namespace irrr
