#include "core/good_set.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "core/local_problem.h"
#include "core/optimizer.h"

namespace irrr {
namespace {

// Loops linearized per covariance recovery (LinearizeEach; bounds its size: 2 x 32 poses).
constexpr size_t kLinearizeChunk = 32;
// A trial of this many loops or more that Gauss-Newton does not settle is settled by a batch
// solve (so that a large cluster failing names its suspects); smaller ones fail, as wrong groups
// of a few links often do, without a batch solve each.
constexpr size_t kSettleByBatchLoops = 10;

}  // namespace

template <class Pose>
struct GoodSet<Pose>::Impl {
  Impl(const PoseGraph<Pose>* g, std::vector<Pose>* e, const IncrementalSolverOptions& o)
      : graph(g), estimate(e), options(o) {}

  IncrementalSolver<Pose>* SolverOfVertex(int v) const {
    const int c = component_of_session[graph->vertex(v).session];
    if (trial_merged != nullptr && (c == merge_a || c == merge_b)) return trial_merged.get();
    return solvers[c].get();
  }

  void Publish(const IncrementalSolver<Pose>& solver) {
    for (int v : solver.vertices()) (*estimate)[v] = solver.estimate(v);
  }

  void Retire(std::unique_ptr<IncrementalSolver<Pose>>* solver) {
    if (*solver == nullptr) return;
    retired_solves += (*solver)->counters().solves;
    solver->reset();
  }

  std::vector<int> SessionsOf(int component) const {
    std::vector<int> sessions;
    for (int s = 0; s < static_cast<int>(component_of_session.size()); ++s) {
      if (component_of_session[s] == component) sessions.push_back(s);
    }
    return sessions;
  }

  // A solver for the poses of `sessions` (in session order) with odometry and `loops`, started
  // from `start` (the sessions in one frame), its earliest session's first pose held at the
  // identity: `start` is moved rigidly so that it is, then optimized by a batch solve (which
  // controls its steps, for starts far from the optimum) before the solver takes over.
  std::unique_ptr<IncrementalSolver<Pose>> Build(const std::vector<int>& sessions,
                                                 const std::vector<int>& loops,
                                                 std::vector<Pose>* start) {
    std::vector<int> vertices;
    std::vector<int> edges;
    for (int s : sessions) {
      for (int v : graph->session(s).vertices) {
        vertices.push_back(v);
        if (graph->OdometryInto(v) >= 0) edges.push_back(graph->OdometryInto(v));
      }
    }
    edges.insert(edges.end(), loops.begin(), loops.end());
    const Pose origin_T_anchor = (*start)[vertices.front()].Inverse();
    for (int v : vertices) (*start)[v] = origin_T_anchor * (*start)[v];
    if (!loops.empty()) {
      std::vector<char> active(graph->num_edges(), 0);
      for (int e : edges) active[e] = 1;
      batch.Solve(*graph, active, start);
    }
    auto solver = std::make_unique<IncrementalSolver<Pose>>(graph, options);
    solver->Reset(vertices, edges, *start);
    return solver;
  }

  const PoseGraph<Pose>* graph;
  std::vector<Pose>* estimate;
  IncrementalSolverOptions options;
  std::vector<std::unique_ptr<IncrementalSolver<Pose>>> solvers;  // per component id
  std::vector<int> component_of_session;                          // -1: no pose yet
  Optimizer<Pose> batch;
  Counters counters;
  long retired_solves = 0;

  // The components RebuildKeeping kept aside, with their sessions' component ids.
  std::vector<std::unique_ptr<IncrementalSolver<Pose>>> kept_solvers;
  std::vector<int> kept_component_of_session;
  bool keeping = false;

  // The open trial: in one component (trial_component), or a merge of two (trial_merged).
  bool trial_open = false;
  int trial_component = -1;
  std::unique_ptr<IncrementalSolver<Pose>> trial_merged;
  int merge_a = -1;
  int merge_b = -1;
};

template <class Pose>
GoodSet<Pose>::GoodSet(const PoseGraph<Pose>* graph,
                       std::vector<Pose>* estimate,
                       const IncrementalSolverOptions& options)
    : impl_(std::make_unique<Impl>(graph, estimate, options)) {}

template <class Pose>
GoodSet<Pose>::~GoodSet() = default;

template <class Pose>
void GoodSet<Pose>::AddPose(int vertex) {
  Impl& m = *impl_;
  IRRR_CHECK(!m.trial_open);
  const PoseGraph<Pose>& graph = *m.graph;
  if (static_cast<int>(m.estimate->size()) < graph.num_vertices()) {
    m.estimate->resize(graph.num_vertices());
  }
  if (static_cast<int>(m.component_of_session.size()) < graph.num_sessions()) {
    m.component_of_session.resize(graph.num_sessions(), -1);
  }
  const int session = graph.vertex(vertex).session;
  const int odometry = graph.OdometryInto(vertex);
  if (odometry < 0) {
    (*m.estimate)[vertex] = Pose();
    m.component_of_session[session] = static_cast<int>(m.solvers.size());
    m.solvers.push_back(std::make_unique<IncrementalSolver<Pose>>(m.graph, m.options));
    m.solvers.back()->Reset({vertex}, {}, *m.estimate);
    return;
  }
  IncrementalSolver<Pose>& solver = *m.solvers[m.component_of_session[session]];
  solver.Extend(vertex, odometry);
  (*m.estimate)[vertex] = solver.estimate(vertex);
}

template <class Pose>
int GoodSet<Pose>::ComponentOf(int session) const {
  const auto& of = impl_->component_of_session;
  return session < static_cast<int>(of.size()) ? of[session] : -1;
}

template <class Pose>
std::vector<int> GoodSet<Pose>::SessionsOf(int component) const {
  return impl_->SessionsOf(component);
}

template <class Pose>
std::vector<int> GoodSet<Pose>::Components() const {
  const Impl& m = *impl_;
  std::vector<int> out(m.graph->num_sessions(), -1);
  std::vector<int> number(m.solvers.size(), -1);
  int next = 0;
  for (int s = 0; s < m.graph->num_sessions(); ++s) {
    const int c = ComponentOf(s);
    if (c < 0) {
      out[s] = next++;  // no pose yet: a component of its own
      continue;
    }
    if (number[c] < 0) number[c] = next++;
    out[s] = number[c];
  }
  return out;
}

template <class Pose>
std::vector<Eigen::MatrixXd> GoodSet<Pose>::Covariances(
    const std::vector<std::vector<int>>& sets) const {
  IRRR_CHECK(!sets.empty() && !sets.front().empty());
  return impl_->SolverOfVertex(sets.front().front())->Covariances(sets);
}

template <class Pose>
std::vector<Eigen::MatrixXd> GoodSet<Pose>::ProjectedCovariances(
    const std::vector<CovarianceProjection>& projections) const {
  IRRR_CHECK(!projections.empty() && !projections.front().vertices.empty());
  return impl_->SolverOfVertex(projections.front().vertices.front())
      ->ProjectedCovariances(projections);
}

namespace {

// For groups of edges each of whose ends lie in one component of `good` (its open trial's, during
// one; groups of different components are recovered apart):
// visit(k, stack, projected) with group k's loops stacked at `estimate`, their Jacobians at
// `linearization` if given (StackEdges, against their end poses), and J Sigma J' from the
// factorization. Groups of at most kLinearizeChunk loops together (a larger one alone) share one
// recovery, which costs d sparse solves per column of what it recovers: by projection (A = J'), d
// per loop; Sigma itself, d per distinct end pose of the chunk, then projected block by block.
// Whichever is fewer: lone loops and runs project, a large cluster whose loops share poses (the
// parking garage's: 41 -> 66 s by projection) does not.
template <class Pose, class Visit>
void ForEachProjectedCovariance(const GoodSet<Pose>& good,
                                const PoseGraph<Pose>& graph,
                                const std::vector<std::vector<int>>& groups,
                                const std::vector<Pose>& estimate,
                                const std::vector<Pose>* linearization,
                                Visit visit) {
  // A chunk is recovered from one solver: its groups lie in one component.
  auto component = [&](size_t k) {
    return good.ComponentOf(graph.vertex(graph.edge(groups[k].front()).from).session);
  };
  for (size_t first = 0; first < groups.size();) {
    size_t last = first;
    size_t loops = 0;
    while (last < groups.size() &&
           (last == first || (loops + groups[last].size() <= kLinearizeChunk &&
                              component(last) == component(first)))) {
      loops += groups[last].size();
      ++last;
    }
    std::vector<StackedEdges<Pose>> stacks;
    std::vector<CovarianceProjection> projections;  // each group's ends; A once chosen
    std::vector<int> poses;                         // of the chunk, each once
    for (size_t k = first; k < last; ++k) {
      CovarianceProjection projection;
      std::vector<const Edge<Pose>*> edges;
      for (int e : groups[k]) {
        edges.push_back(&graph.edge(e));
        for (int v : {graph.edge(e).from, graph.edge(e).to}) {
          if (std::find(projection.vertices.begin(), projection.vertices.end(), v) ==
              projection.vertices.end()) {
            projection.vertices.push_back(v);
          }
        }
      }
      poses.insert(poses.end(), projection.vertices.begin(), projection.vertices.end());
      stacks.push_back(StackEdges<Pose>(edges, estimate, projection.vertices, linearization));
      projections.push_back(std::move(projection));
    }
    std::sort(poses.begin(), poses.end());
    poses.erase(std::unique(poses.begin(), poses.end()), poses.end());
    std::vector<Eigen::MatrixXd> projected;
    if (loops < poses.size()) {
      for (size_t k = 0; k < stacks.size(); ++k) projections[k].A = stacks[k].TransposedJacobian();
      projected = good.ProjectedCovariances(projections);
    } else {
      std::vector<std::vector<int>> sets;
      for (const CovarianceProjection& p : projections) sets.push_back(p.vertices);
      std::vector<Eigen::MatrixXd> sigma = good.Covariances(sets);
      for (size_t k = 0; k < stacks.size(); ++k) {
        projected.push_back(ProjectCovariance(stacks[k], sigma[k]));
        sigma[k] = Eigen::MatrixXd();  // a large cluster's is tens of megabytes
      }
    }
    for (size_t k = first; k < last; ++k) {
      visit(k, stacks[k - first], std::move(projected[k - first]));
    }
    first = last;
  }
}

}  // namespace

template <class Pose>
std::vector<LinearizedAddition> GoodSet<Pose>::LinearizeEach(const std::vector<int>& loops) const {
  IRRR_CHECK(!impl_->trial_open);
  std::vector<std::vector<int>> groups;
  for (int e : loops) groups.push_back({e});
  std::vector<LinearizedAddition> out(loops.size());
  ForEachProjectedCovariance<Pose>(
      *this,
      *impl_->graph,
      groups,
      *impl_->estimate,
      // The loops are not in H: their Jacobians stay where their residuals are. At the
      // linearization points they changed the screen of Manhattan + 2000 local-grouped, seed 2,
      // and a wrong group stayed in (3 wrong, 2086 of 2099 true loops).
      nullptr,
      [&](size_t k, const StackedEdges<Pose>& stack, Eigen::MatrixXd projected) {
        out[k] = AdditionStatistic(stack, std::move(projected));
      });
  return out;
}

template <class Pose>
std::vector<double> GoodSet<Pose>::LinearizeRemovals(
    const std::vector<std::vector<int>>& groups) const {
  // The groups' end poses: each residual at the estimate (the open trial's, during one), its
  // Jacobians where H holds them (the solver's linearization points). Taken at the estimate
  // instead, they disagree with H wherever a pose has moved without being relinearized
  // (IncrementalSolverOptions::model_tolerance), and C - J Sigma J' was not positive definite for
  // a quarter of BendingParts' groups on Manhattan + 100 local-grouped, seed 36: the wrong group
  // whose removal statistic came out NaN there stayed in (ATE 2.03 m, oracle 0.79).
  const PoseGraph<Pose>& graph = *impl_->graph;
  std::vector<Pose> at = *impl_->estimate;
  std::vector<Pose> linearization = at;
  for (const std::vector<int>& group : groups) {
    for (int e : group) {
      for (int v : {graph.edge(e).from, graph.edge(e).to}) {
        const IncrementalSolver<Pose>& solver = *impl_->SolverOfVertex(v);
        at[v] = solver.estimate(v);
        linearization[v] = solver.linearization_point(v);
      }
    }
  }
  std::vector<double> out(groups.size());
  ForEachProjectedCovariance<Pose>(
      *this,
      graph,
      groups,
      at,
      &linearization,
      [&](size_t k, const StackedEdges<Pose>& stack, Eigen::MatrixXd projected) {
        out[k] = RemovalStatistic(stack, std::move(projected));
      });
  return out;
}

template <class Pose>
const Pose& GoodSet<Pose>::Estimate(int vertex) const {
  return impl_->SolverOfVertex(vertex)->estimate(vertex);
}

template <class Pose>
typename GoodSet<Pose>::Trial GoodSet<Pose>::Try(const std::vector<int>& loops,
                                                 double alignment_cap,
                                                 double max_increase) {
  Impl& m = *impl_;
  IRRR_CHECK(!m.trial_open && !loops.empty());
  const PoseGraph<Pose>& graph = *m.graph;
  ++m.counters.trials;
  std::vector<int> components;
  for (int e : loops) {
    for (int v : {graph.edge(e).from, graph.edge(e).to}) {
      components.push_back(m.component_of_session[graph.vertex(v).session]);
    }
  }
  std::sort(components.begin(), components.end());
  components.erase(std::unique(components.begin(), components.end()), components.end());
  IRRR_CHECK(components.size() <= 2);
  Trial trial;
  if (components.size() == 1) {
    IncrementalSolver<Pose>& solver = *m.solvers[components[0]];
    const double before = solver.chi2();
    solver.Checkpoint(before + max_increase);
    const IncrementalSummary summary = solver.Add(loops);
    m.counters.iterations += summary.iterations;
    if (!summary.ok) {
      solver.Rollback();
      if (loops.size() < kSettleByBatchLoops) return trial;
      // Gauss-Newton did not settle: the optimum by a batch solve with step control instead, in a
      // solver of its own (as a merge's, of one component).
      std::vector<int> all_loops = loops;
      for (int e : solver.edges()) {
        if (graph.edge(e).kind == EdgeKind::kLoop) all_loops.push_back(e);
      }
      std::vector<Pose> start = *m.estimate;
      m.trial_merged = m.Build(m.SessionsOf(components[0]), all_loops, &start);
      if (!std::isfinite(m.trial_merged->chi2())) {
        m.Retire(&m.trial_merged);
        return trial;
      }
      m.trial_open = true;
      m.merge_a = m.merge_b = components[0];
      trial.ok = true;
      trial.increase = m.trial_merged->chi2() - before;
      trial.dof = Pose::kDim * static_cast<double>(loops.size());
      return trial;
    }
    m.trial_open = true;
    m.trial_component = components[0];
    trial.ok = true;
    trial.increase = solver.chi2() - before;
    trial.dof = Pose::kDim * static_cast<double>(loops.size());
    return trial;
  }
  // Two components: the one holding the earlier session keeps its frame.
  int a = components[0];
  int b = components[1];
  auto earliest = [&m](int c) { return m.SessionsOf(c).front(); };
  if (earliest(b) < earliest(a)) std::swap(a, b);
  ++m.counters.merges;
  std::vector<int> sessions = m.SessionsOf(a);
  const std::vector<int> sessions_b = m.SessionsOf(b);
  sessions.insert(sessions.end(), sessions_b.begin(), sessions_b.end());
  std::sort(sessions.begin(), sessions.end());
  std::vector<int> merged_loops = loops;
  for (int c : {a, b}) {
    for (int e : m.solvers[c]->edges()) {
      if (graph.edge(e).kind == EdgeKind::kLoop) merged_loops.push_back(e);
    }
  }
  std::vector<Pose> start = *m.estimate;
  std::vector<int> group_of_session(graph.num_sessions(), -1);
  for (int s = 0; s < graph.num_sessions(); ++s) group_of_session[s] = ComponentOf(s);
  for (int s = 0; s < graph.num_sessions(); ++s) {
    if (group_of_session[s] < 0) group_of_session[s] = static_cast<int>(m.solvers.size()) + s;
  }
  // One frame for both (Build then moves it so that a's anchor, the earliest session's first
  // pose, is at the identity again).
  AlignFrames(graph, loops, group_of_session, alignment_cap, &start);
  m.trial_merged = m.Build(sessions, merged_loops, &start);
  const double before = m.solvers[a]->chi2() + m.solvers[b]->chi2();
  trial.ok = true;
  trial.merges = true;
  trial.increase = m.trial_merged->chi2() - before;
  trial.dof = Pose::kDim * (static_cast<double>(loops.size()) - 1.0);
  m.trial_open = true;
  m.merge_a = a;
  m.merge_b = b;
  return trial;
}

template <class Pose>
void GoodSet<Pose>::Commit() {
  Impl& m = *impl_;
  IRRR_CHECK(m.trial_open);
  m.trial_open = false;
  if (m.trial_merged == nullptr) {
    IncrementalSolver<Pose>& solver = *m.solvers[m.trial_component];
    solver.Commit();
    m.Publish(solver);
    return;
  }
  for (int s : m.SessionsOf(m.merge_b)) m.component_of_session[s] = m.merge_a;
  m.Retire(&m.solvers[m.merge_a]);
  m.Retire(&m.solvers[m.merge_b]);
  m.solvers[m.merge_a] = std::move(m.trial_merged);
  m.Publish(*m.solvers[m.merge_a]);
  m.merge_a = m.merge_b = -1;
}

template <class Pose>
void GoodSet<Pose>::Rollback() {
  Impl& m = *impl_;
  IRRR_CHECK(m.trial_open);
  m.trial_open = false;
  if (m.trial_merged == nullptr) {
    m.solvers[m.trial_component]->Rollback();
    return;
  }
  m.Retire(&m.trial_merged);
  m.merge_a = m.merge_b = -1;
}

template <class Pose>
double GoodSet<Pose>::EdgeChi2(int edge) const {
  const Impl& m = *impl_;
  const Edge<Pose>& e = m.graph->edge(edge);
  const IncrementalSolver<Pose>* from = m.SolverOfVertex(e.from);
  const IncrementalSolver<Pose>* to = m.SolverOfVertex(e.to);
  IRRR_CHECK(from == to);
  return irrr::EdgeChi2(e, from->estimate(e.from), from->estimate(e.to));
}

template <class Pose>
void GoodSet<Pose>::Rebuild(const std::vector<int>& good_loops, double alignment_cap) {
  Impl& m = *impl_;
  IRRR_CHECK(!m.trial_open);
  const PoseGraph<Pose>& graph = *m.graph;
  ++m.counters.rebuilds;
  std::vector<Pose> start = *m.estimate;
  std::vector<int> group_of_session(graph.num_sessions());
  for (int s = 0; s < graph.num_sessions(); ++s) {
    group_of_session[s] =
        ComponentOf(s) >= 0 ? ComponentOf(s) : static_cast<int>(m.solvers.size()) + s;
  }
  AlignFrames(graph, good_loops, group_of_session, alignment_cap, &start);
  std::vector<char> active(graph.num_edges(), 0);
  for (int e : good_loops) active[e] = 1;
  const std::vector<int> component = SessionComponents(graph, active);
  for (auto& solver : m.solvers) m.Retire(&solver);
  m.solvers.clear();
  m.component_of_session.assign(graph.num_sessions(), -1);
  std::vector<int> id_of(graph.num_sessions(), -1);
  for (int s = 0; s < graph.num_sessions(); ++s) {
    if (graph.session(s).vertices.empty()) continue;
    if (id_of[component[s]] < 0) {
      id_of[component[s]] = static_cast<int>(m.solvers.size());
      m.solvers.emplace_back();
    }
    m.component_of_session[s] = id_of[component[s]];
  }
  for (int c = 0; c < static_cast<int>(m.solvers.size()); ++c) {
    const std::vector<int> sessions = m.SessionsOf(c);
    std::vector<int> loops;
    for (int e : good_loops) {
      if (m.component_of_session[graph.vertex(graph.edge(e).from).session] == c) loops.push_back(e);
    }
    m.solvers[c] = m.Build(sessions, loops, &start);
    m.Publish(*m.solvers[c]);
  }
}

template <class Pose>
void GoodSet<Pose>::RebuildKeeping(const std::vector<int>& good_loops, double alignment_cap) {
  Impl& m = *impl_;
  IRRR_CHECK(!m.trial_open && !m.keeping);
  m.keeping = true;
  m.kept_component_of_session = m.component_of_session;
  m.kept_solvers.clear();
  for (auto& solver : m.solvers) m.kept_solvers.push_back(std::move(solver));
  // Rebuild retires what is left in the solvers' places: nothing.
  Rebuild(good_loops, alignment_cap);
}

template <class Pose>
void GoodSet<Pose>::Restore() {
  Impl& m = *impl_;
  IRRR_CHECK(!m.trial_open && m.keeping);
  for (auto& solver : m.solvers) m.Retire(&solver);
  m.solvers = std::move(m.kept_solvers);
  m.kept_solvers.clear();
  m.component_of_session = m.kept_component_of_session;
  m.keeping = false;
  for (const auto& solver : m.solvers) {
    if (solver != nullptr) m.Publish(*solver);  // (a merged component's place is empty)
  }
}

template <class Pose>
void GoodSet<Pose>::Release() {
  Impl& m = *impl_;
  IRRR_CHECK(m.keeping);
  for (auto& solver : m.kept_solvers) m.Retire(&solver);
  m.kept_solvers.clear();
  m.keeping = false;
}

template <class Pose>
const IncrementalSolver<Pose>& GoodSet<Pose>::Solver(int component) const {
  return *impl_->solvers[component];
}

template <class Pose>
typename GoodSet<Pose>::Counters GoodSet<Pose>::counters() const {
  Counters counters = impl_->counters;
  counters.solves = impl_->retired_solves;
  for (const auto& solver : impl_->solvers) {
    if (solver != nullptr) counters.solves += solver->counters().solves;
  }
  return counters;
}

template class GoodSet<Pose2>;
template class GoodSet<Pose3>;

}  // namespace irrr
