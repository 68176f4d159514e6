#include "core/irrr.h"

#include <algorithm>
#include <cmath>
#include <memory>

#include "core/paper_engine.h"
#include "core/warm_engine.h"

namespace irrr {

const char* IrrrEngineName(IrrrEngine engine) {
  switch (engine) {
    case IrrrEngine::kWarm:
      return "warm";
    case IrrrEngine::kPaper:
      return "paper";
  }
  return "unknown";
}

IrrrOptions IrrrOptions::PaperFaithful() {
  IrrrOptions options;
  options.engine = IrrrEngine::kPaper;
  options.alpha = 0.95;
  options.cluster_span = 0.0;
  return options;
}

Status IrrrOptions::Validate() const {
  if (!(alpha > 0.0 && alpha < 1.0)) return Status::Error("alpha must be in (0, 1)");
  if (!(cluster_gap >= 0.0) || !std::isfinite(cluster_gap)) {
    return Status::Error("cluster_gap must be a finite number >= 0");
  }
  if (!(cluster_span >= 0.0) || !std::isfinite(cluster_span)) {
    return Status::Error("cluster_span must be a finite number >= 0 (0: unbounded)");
  }
  if (!(variance_factor >= 0.0) || !std::isfinite(variance_factor)) {
    return Status::Error("variance_factor must be a finite number >= 0 (0: estimated)");
  }
  if (step_budget < 0) return Status::Error("step_budget must be >= 0 (0: unbounded)");
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
  explicit State(const IrrrOptions& o)
      : options(o),
        clusterer(o.cluster_gap, o.cluster_gap * o.cluster_span),
        warm(&graph, &options, &book, &estimate, &dead_reckoning),
        paper(&graph, &options, &book, &estimate, &dead_reckoning) {}

  bool IsWarm() const { return options.engine == IrrrEngine::kWarm; }

  // Records clusters that closed, in closing order (each is marked closed when its step comes).
  void Closed(const std::vector<int>& clusters) {
    closed.insert(closed.end(), clusters.begin(), clusters.end());
  }

  IrrrOptions options;
  PoseGraph<Pose> graph;
  LoopClusterer clusterer;
  DecisionBook book;
  std::vector<Pose> estimate;
  std::vector<Pose> dead_reckoning;
  std::vector<int> closed;      // clusterer clusters, in closing order
  std::vector<int> cluster_of;  // judged cluster of each clusterer cluster
  size_t next_closed = 0;
  std::vector<ArrivalEvent> arrivals;  // the inputs taken, in order
  WarmEngine<Pose> warm;
  PaperEngine<Pose> paper;
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
  return state_->graph.AddSession(session_id, session_index);
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
  for (int e = edges_before; e < st.graph.num_edges(); ++e) st.book.decisions.emplace_back();
  st.arrivals.push_back({ArrivalEvent::Kind::kPose, index});
  if (st.IsWarm()) st.warm.AddPose(index);
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
  st.arrivals.push_back({ArrivalEvent::Kind::kLoop, edge});
  const Vertex& from = st.graph.vertex(from_vertex);
  const Vertex& to = st.graph.vertex(to_vertex);
  const int cluster = st.clusterer.AddLink(edge, from.session, from.stamp, to.session, to.stamp);
  while (static_cast<int>(st.cluster_of.size()) <= cluster) {
    const LoopCluster& c = st.clusterer.cluster(static_cast<int>(st.cluster_of.size()));
    st.cluster_of.push_back(st.book.AddCluster(c.session_a, c.session_b));
  }
  st.book.clusters[st.cluster_of[cluster]].links.push_back(edge);
  st.book.decisions.emplace_back();
  st.book.decisions[edge].cluster = st.cluster_of[cluster];
  if (edge_index != nullptr) *edge_index = edge;
  return Status::Ok();
}

template <class Pose>
Status Irrr<Pose>::EndSession(int session) {
  if (session < 0 || session >= state_->graph.num_sessions()) {
    return Status::Error("unknown session index " + std::to_string(session));
  }
  state_->arrivals.push_back({ArrivalEvent::Kind::kEndSession, session});
  state_->Closed(state_->clusterer.EndSession(session));
  state_->warm.Release();
  return Status::Ok();
}

template <class Pose>
void Irrr<Pose>::Flush() {
  state_->arrivals.push_back({ArrivalEvent::Kind::kFlush, -1});
  state_->Closed(state_->clusterer.CloseAll());
  state_->warm.Release();
}

template <class Pose>
bool Irrr<Pose>::HasPendingStep() const {
  return state_->next_closed < state_->closed.size() ||
         (state_->IsWarm() && (state_->warm.HasReleased() || state_->warm.HasDeferred()));
}

template <class Pose>
StepResult Irrr<Pose>::RunStep() {
  IRRR_CHECK(HasPendingStep());
  State& st = *state_;
  StepResult result;
  result.step = st.book.step;
  if (st.next_closed < st.closed.size()) {
    result.cluster = st.cluster_of[st.closed[st.next_closed++]];
    st.book.clusters[result.cluster].closed = true;
  }
  if (st.IsWarm()) {
    st.warm.Step(result.cluster, &result);
  } else {
    st.paper.Step(result.cluster, &result);
  }
  ++st.book.step;
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
  return state_->book.decisions[edge];
}

template <class Pose>
const LoopClusterer& Irrr<Pose>::clusters() const {
  return state_->clusterer;
}

template <class Pose>
int Irrr<Pose>::num_steps() const {
  return state_->book.step;
}

template <class Pose>
const std::vector<ArrivalEvent>& Irrr<Pose>::Arrivals() const {
  return state_->arrivals;
}

template <class Pose>
const typename Irrr<Pose>::Matrix& Irrr<Pose>::GivenInformation(int edge) const {
  return state_->IsWarm() ? state_->warm.GivenInformation(edge)
                          : state_->graph.edge(edge).information;
}

template <class Pose>
std::vector<int> Irrr<Pose>::OdometryFaults() const {
  return state_->IsWarm() ? state_->warm.OdometryFaults() : std::vector<int>();
}

template <class Pose>
std::vector<int> Irrr<Pose>::Components() const {
  return state_->IsWarm() ? state_->warm.Components() : state_->paper.Components();
}

template <class Pose>
IrrrStepState<Pose> Irrr<Pose>::StepState() const {
  const State& st = *state_;
  IrrrStepState<Pose> out;
  out.decisions = st.book.decisions;
  out.estimate = st.estimate;
  out.clusters = st.book.clusters;
  out.cluster_of = st.cluster_of;
  out.steps = st.book.step;
  out.judged = static_cast<int>(st.next_closed);
  if (st.IsWarm()) out.weakened_odometry = st.warm.WeakenedOdometry();
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
  for (const JudgedCluster& cluster : state.clusters) {
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
    for (double v : {cluster.redundancy_chi2,
                     cluster.redundancy_dof,
                     cluster.accepted_variance,
                     cluster.refused_variance,
                     cluster.checked_variance}) {
      if (!(v >= 0.0) || !std::isfinite(v)) {
        return Status::Error(
            "a cluster's redundancy or variance factor is not a finite number >= 0");
      }
    }
    if (cluster.checked_links < 0) return Status::Error("a cluster's checked link count is < 0");
  }
  for (int e : state.weakened_odometry) {
    if (!fits(e, st.graph.num_edges()) || st.graph.edge(e).kind != EdgeKind::kOdometry) {
      return Status::Error("the step state weakens an edge that is not odometry of the graph");
    }
  }
  std::sort(state.weakened_odometry.begin(), state.weakened_odometry.end());
  if (std::adjacent_find(state.weakened_odometry.begin(), state.weakened_odometry.end()) !=
          state.weakened_odometry.end() ||
      (!st.IsWarm() && !state.weakened_odometry.empty())) {
    return Status::Error("the step state weakens an odometry edge twice, or for the paper engine");
  }
  st.book.decisions = std::move(state.decisions);
  st.book.clusters = std::move(state.clusters);
  st.book.step = state.steps;
  st.estimate = std::move(state.estimate);
  st.cluster_of = std::move(state.cluster_of);
  st.next_closed = static_cast<size_t>(state.judged);
  if (st.IsWarm()) {
    st.warm.RestoreWeakened(state.weakened_odometry);
    st.warm.Restore();
  }
  return Status::Ok();
}

template <class Pose>
std::vector<LoopDecision> RunBatchRrr(const PoseGraph<Pose>& graph,
                                      const IrrrOptions& options,
                                      std::vector<Pose>* estimate) {
  IRRR_CHECK(options.Validate().ok());
  DecisionBook book;
  book.decisions.resize(graph.num_edges());
  // Cluster in arrival order: a loop arrives with the later of its two poses.
  std::vector<int> loops;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kLoop) loops.push_back(e);
  }
  auto arrival = [&graph](int e) { return std::max(graph.edge(e).from, graph.edge(e).to); };
  std::stable_sort(
      loops.begin(), loops.end(), [&](int a, int b) { return arrival(a) < arrival(b); });
  LoopClusterer clusterer(options.cluster_gap, options.cluster_gap * options.cluster_span);
  for (int e : loops) {
    const Vertex& from = graph.vertex(graph.edge(e).from);
    const Vertex& to = graph.vertex(graph.edge(e).to);
    const int c = clusterer.AddLink(e, from.session, from.stamp, to.session, to.stamp);
    if (c >= static_cast<int>(book.clusters.size())) {
      book.AddCluster(clusterer.cluster(c).session_a, clusterer.cluster(c).session_b);
    }
    book.clusters[c].links.push_back(e);
    book.decisions[e].cluster = c;
  }
  const std::vector<Pose> dead_reckoning = graph.OdometryEstimate();
  std::vector<Pose> optimum = dead_reckoning;
  PaperEngine<Pose> engine(&graph, &options, &book, &optimum, &dead_reckoning);
  engine.RunBatch();
  if (estimate != nullptr) *estimate = std::move(optimum);
  return book.decisions;
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
    case ArrivalEvent::Kind::kFlush:
      irrr_->Flush();
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
std::vector<int> GraphReplay<Pose>::OdometryFaults() const {
  std::vector<int> graph_edge(irrr_->graph().num_edges(), -1);
  for (int e = 0; e < graph_.num_edges(); ++e) {
    if (edge_of_[e] >= 0) graph_edge[edge_of_[e]] = e;
  }
  std::vector<int> faults;
  for (int e : irrr_->OdometryFaults()) faults.push_back(graph_edge[e]);
  std::sort(faults.begin(), faults.end());
  return faults;
}

template <class Pose>
std::vector<LoopDecision> RunIncrementalIrrr(const PoseGraph<Pose>& graph,
                                             const IrrrOptions& options,
                                             std::vector<Pose>* estimate,
                                             std::vector<StepResult>* steps) {
  Irrr<Pose> irrr(options);
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
                                                             std::vector<StepResult>*);
template std::vector<LoopDecision> RunIncrementalIrrr<Pose3>(const PoseGraph<Pose3>&,
                                                             const IrrrOptions&,
                                                             std::vector<Pose3>*,
                                                             std::vector<StepResult>*);
template std::vector<ArrivalEvent> ArrivalOrder<Pose2>(const PoseGraph<Pose2>&);
template std::vector<ArrivalEvent> ArrivalOrder<Pose3>(const PoseGraph<Pose3>&);
template std::vector<LoopDecision> RunBatchRrr<Pose2>(const PoseGraph<Pose2>&,
                                                      const IrrrOptions&,
                                                      std::vector<Pose2>*);
template std::vector<LoopDecision> RunBatchRrr<Pose3>(const PoseGraph<Pose3>&,
                                                      const IrrrOptions&,
                                                      std::vector<Pose3>*);

}  // namespace irrr
