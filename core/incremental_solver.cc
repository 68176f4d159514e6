#include "core/incremental_solver.h"

#include "core/incremental_solver_impl.h"

namespace irrr {

Status IncrementalSolverOptions::Validate() const {
  if (!(relinearize_rotation_rad > 0.0)) {
    return Status::Error("relinearize_rotation_rad must be > 0");
  }
  if (!(relinearize_translation > 0.0)) return Status::Error("relinearize_translation must be > 0");
  if (max_iterations < 1) return Status::Error("max_iterations must be at least 1");
  if (trial_max_iterations < 1) return Status::Error("trial_max_iterations must be at least 1");
  if (trial_batch_max_iterations < 1) {
    return Status::Error("trial_batch_max_iterations must be at least 1");
  }
  if (!(model_tolerance >= 0.0)) return Status::Error("model_tolerance must be >= 0");
  if (!(spare_fraction >= 0.0)) return Status::Error("spare_fraction must be >= 0");
  if (!(refill_ratio > 1.0)) return Status::Error("refill_ratio must be > 1");
  return Status::Ok();
}

template <class Pose>
IncrementalSolver<Pose>::IncrementalSolver(const PoseGraph<Pose>* graph,
                                           const IncrementalSolverOptions& options)
    : impl_(std::make_unique<Impl>(graph, options)) {
  IRRR_CHECK(options.Validate().ok());
}

template <class Pose>
IncrementalSolver<Pose>::~IncrementalSolver() = default;

template <class Pose>
IncrementalSummary IncrementalSolver<Pose>::Reset(const std::vector<int>& vertices,
                                                  const std::vector<int>& edges,
                                                  const std::vector<Pose>& estimate) {
  Impl& m = *impl_;
  IRRR_CHECK(!vertices.empty());
  m.trial_active = false;
  m.anchor = vertices.front();
  m.anchor_pose = estimate[m.anchor];
  m.vertices = vertices;
  m.slot_of.assign(m.graph->num_vertices(), -1);
  m.vertex_of_slot.assign(vertices.begin() + 1, vertices.end());
  m.x.resize(m.vertex_of_slot.size());
  for (size_t s = 0; s < m.vertex_of_slot.size(); ++s) {
    m.slot_of[m.vertex_of_slot[s]] = static_cast<int>(s);
    m.x[s] = estimate[m.vertex_of_slot[s]];
  }
  m.SetEdges(edges);
  m.capacity = 0;
  m.rebuilds_this_call = 0;
  IncrementalSummary summary;
  if (!m.Rebuild(true)) return m.Failed(summary, "factorization failed");
  summary = m.Optimize();
  summary.rebuilds = m.rebuilds_this_call;
  return summary;
}

template <class Pose>
void IncrementalSolver<Pose>::Extend(int vertex, int edge) {
  constexpr int d = Pose::kDim;
  Impl& m = *impl_;
  IRRR_CHECK(!m.trial_active);
  const Edge<Pose>& odometry = m.graph->edge(edge);
  IRRR_CHECK(odometry.to == vertex && Contains(odometry.from) && !Contains(vertex));
  if (static_cast<int>(m.slot_of.size()) < m.graph->num_vertices()) {
    m.slot_of.resize(m.graph->num_vertices(), -1);
  }
  m.EnsureEdgeIndex();
  const int slot = static_cast<int>(m.vertex_of_slot.size());
  if (slot >= m.capacity || m.rebuild_due) {
    // No free place (or the order has filled in): a fresh order with room to grow. The new pose
    // is not in it yet; the rebuild solves, so x is the optimum it was.
    IRRR_CHECK(m.Rebuild(true));
    IRRR_CHECK(m.SolveSystem());
  }
  m.vertices.push_back(vertex);
  m.vertex_of_slot.push_back(vertex);
  m.slot_of[vertex] = slot;
  m.incident.emplace_back();
  m.x_lin[slot] = m.Estimate(odometry.from) * odometry.measurement;
  m.edge_position[edge] = static_cast<int>(m.edges.size());
  m.edges.push_back(edge);
  m.AddIncidence(edge);

  const typename Impl::Term t = m.Linearize(edge);
  // H_from,from gains J_from'Omega J_from (an update), then the new pose's rows are added: its
  // block J_to'Omega J_to and the cross block J_from'Omega J_to.
  if (t.slot_from >= 0) {
    typename Impl::Term from_only = t;
    from_only.slot_to = -1;
    IRRR_CHECK(m.Modify({from_only}, true));
  }
  const Matrix cross = t.J_from.transpose() * t.J_to;
  const Matrix own = t.J_to.transpose() * t.J_to;
  cholmod_sparse* R =
      cholmod_allocate_sparse(m.capacity * d, 1, 2 * d, 0, 1, 0, CHOLMOD_REAL, &m.common);
  IRRR_CHECK(R != nullptr);
  for (int a = 0; a < d; ++a) {
    int* Rp = static_cast<int*>(R->p);
    int* Ri = static_cast<int*>(R->i);
    double* Rx = static_cast<double*>(R->x);
    int nz = 0;
    if (t.slot_from >= 0) {
      for (int c = 0; c < d; ++c) {
        Ri[nz] = m.position[t.slot_from * d + c];
        Rx[nz++] = cross(c, a);
      }
    }
    for (int c = 0; c <= a; ++c) {
      Ri[nz] = m.position[slot * d + c];
      Rx[nz++] = own(c, a);
    }
    Rp[0] = 0;
    Rp[1] = nz;
    IRRR_CHECK(cholmod_rowadd(m.position[slot * d + a], R, m.factor, &m.common) &&
               m.common.status == CHOLMOD_OK);
  }
  cholmod_free_sparse(&R, &m.common);
  ++m.counters.updates;
  m.NoteModification(1);
  m.AccumulateRightHandSide(t, 1.0);
  // The new pose's equations decouple: with the others' steps unchanged, its step makes the
  // odometry residual zero in the linear model.
  Eigen::Matrix<double, d, 1> from_step = Eigen::Matrix<double, d, 1>::Zero();
  if (t.slot_from >= 0) from_step = m.delta.template segment<d>(t.slot_from * d);
  m.delta.template segment<d>(slot * d) = -t.J_to.inverse() * (t.r + t.J_from * from_step);
  m.x[slot] = m.x_lin[slot].Retract(m.delta.template segment<d>(slot * d));
}

template <class Pose>
IncrementalSummary IncrementalSolver<Pose>::Add(const std::vector<int>& edges) {
  Impl& m = *impl_;
  m.EnsureEdgeIndex();
  m.rebuilds_this_call = 0;
  std::vector<typename Impl::Term> terms;
  for (int e : edges) {
    IRRR_CHECK(m.edge_position[e] < 0);
    IRRR_CHECK(Contains(m.graph->edge(e).from) && Contains(m.graph->edge(e).to));
    m.edge_position[e] = static_cast<int>(m.edges.size());
    m.edges.push_back(e);
    m.AddIncidence(e);
    terms.push_back(m.Linearize(e));
    m.AccumulateRightHandSide(terms.back(), 1.0);
    if (m.trial_active) {
      auto& removed = m.trial.removed;
      const auto it = std::find(removed.begin(), removed.end(), e);
      if (it != removed.end()) {
        removed.erase(it);
      } else {
        m.trial.added.push_back(e);
      }
    }
  }
  IncrementalSummary summary;
  if (m.CheaperToRebuild(edges, 1)) {
    if (!m.Rebuild(false)) return m.Failed(summary, "factorization failed");
  } else if (!m.Modify(terms, true) && !m.Rebuild(false)) {
    return m.Failed(summary, "factorization failed");
  }
  summary = m.Optimize();
  summary.rebuilds = m.rebuilds_this_call;
  return summary;
}

template <class Pose>
IncrementalSummary IncrementalSolver<Pose>::Remove(const std::vector<int>& edges) {
  Impl& m = *impl_;
  m.rebuilds_this_call = 0;
  std::vector<typename Impl::Term> terms;
  for (int e : edges) {
    IRRR_CHECK(e < static_cast<int>(m.edge_position.size()) && m.edge_position[e] >= 0);
    terms.push_back(m.Linearize(e));
    m.AccumulateRightHandSide(terms.back(), -1.0);
    m.RemoveIncidence(e);
    m.edge_position[e] = -1;
    if (m.trial_active) {
      auto& added = m.trial.added;
      const auto it = std::find(added.begin(), added.end(), e);
      if (it != added.end()) {
        added.erase(it);
      } else {
        m.trial.removed.push_back(e);
      }
    }
  }
  m.edges.erase(std::remove_if(
                    m.edges.begin(), m.edges.end(), [&m](int e) { return m.edge_position[e] < 0; }),
                m.edges.end());
  for (size_t k = 0; k < m.edges.size(); ++k) m.edge_position[m.edges[k]] = static_cast<int>(k);
  IncrementalSummary summary;
  if (!m.Modify(terms, false) && !m.Rebuild(false))
    return m.Failed(summary, "factorization failed");
  summary = m.Optimize();
  summary.rebuilds = m.rebuilds_this_call;
  return summary;
}

template <class Pose>
void IncrementalSolver<Pose>::Checkpoint(double target_chi2) {
  Impl& m = *impl_;
  IRRR_CHECK(!m.trial_active);
  m.trial_active = true;
  typename Impl::Trial& t = m.trial;
  t.x_lin = m.x_lin;
  t.x = m.x;
  t.delta = m.delta;
  t.b = m.b;
  t.chi2_lin = m.chi2_lin;
  t.edges = m.edges;
  t.moved.assign(m.capacity, 0);
  t.added.clear();
  t.removed.clear();
  t.rebuilt = false;
  t.analysis_valid = m.analyzed_version == m.structure_version;
  t.target_chi2 = target_chi2;
}

template <class Pose>
void IncrementalSolver<Pose>::Rollback() {
  Impl& m = *impl_;
  IRRR_CHECK(m.trial_active);
  typename Impl::Trial& t = m.trial;
  m.trial_active = false;
  // The factor: each edge whose term differs from the checkpoint's (added, removed, or touching
  // a relinearized pose) gets its checkpoint term back. Terms at the checkpoint's points first,
  // then the trial's leave, so that H stays positive definite.
  std::vector<int> now_terms;   // to downdate (current linearization)
  std::vector<int> then_terms;  // to update (checkpoint linearization)
  for (int e : m.edges) {
    const bool added = std::find(t.added.begin(), t.added.end(), e) != t.added.end();
    const int a = m.SlotOf(m.graph->edge(e).from);
    const int c = m.SlotOf(m.graph->edge(e).to);
    const bool moved = (a >= 0 && t.moved[a]) || (c >= 0 && t.moved[c]);
    if (added || moved) now_terms.push_back(e);
    if (!added && moved) then_terms.push_back(e);
  }
  for (int e : t.removed) then_terms.push_back(e);
  std::vector<typename Impl::Term> now;
  for (int e : now_terms) now.push_back(m.Linearize(e));
  m.x_lin = t.x_lin;
  m.x = t.x;
  m.delta = t.delta;
  m.b = t.b;
  m.chi2_lin = t.chi2_lin;
  m.SetEdges(t.edges);
  std::vector<typename Impl::Term> then;
  for (int e : then_terms) then.push_back(m.Linearize(e));
  // A trial that only added edges analyzed (if it did) a structure that holds the checkpoint's:
  // that analysis serves the checkpoint's factorization.
  const bool analysis_fits =
      t.removed.empty() && (t.analysis_valid || m.analyzed_version >= 0) && m.symbolic != nullptr;
  if (analysis_fits) m.analyzed_version = m.structure_version;
  bool ok = !t.rebuilt && m.Modify(then, true) && m.Modify(now, false);
  if (!ok) {
    // Rebuilt during the trial (or a downdate failed): factorize the checkpoint's system anew.
    const std::vector<Pose> x = m.x;
    for (size_t s = 0; s < m.vertex_of_slot.size(); ++s) m.x[s] = m.x_lin[s];
    IRRR_CHECK(m.Rebuild(false));
    m.x = x;
    m.delta = t.delta;
    m.b = t.b;
    m.chi2_lin = t.chi2_lin;
  }
  t = typename Impl::Trial();
}

template <class Pose>
void IncrementalSolver<Pose>::Commit() {
  Impl& m = *impl_;
  IRRR_CHECK(m.trial_active);
  m.trial_active = false;
  m.trial = typename Impl::Trial();
  m.NoteSettled();
}

template <class Pose>
bool IncrementalSolver<Pose>::InTrial() const {
  return impl_->trial_active;
}

template <class Pose>
Eigen::MatrixXd IncrementalSolver<Pose>::Covariance(const std::vector<int>& vertices) const {
  return impl_->Covariances({vertices}).front();
}

template <class Pose>
std::vector<Eigen::MatrixXd> IncrementalSolver<Pose>::Covariances(
    const std::vector<std::vector<int>>& sets) const {
  return impl_->Covariances(sets);
}

template <class Pose>
std::vector<Eigen::MatrixXd> IncrementalSolver<Pose>::ProjectedCovariances(
    const std::vector<CovarianceProjection>& projections) const {
  return impl_->ProjectedCovariances(projections);
}

template <class Pose>
bool IncrementalSolver<Pose>::Contains(int vertex) const {
  return vertex == impl_->anchor || impl_->SlotOf(vertex) >= 0;
}

template <class Pose>
int IncrementalSolver<Pose>::anchor() const {
  return impl_->anchor;
}

template <class Pose>
const Pose& IncrementalSolver<Pose>::estimate(int vertex) const {
  IRRR_CHECK(Contains(vertex));
  return impl_->Estimate(vertex);
}

template <class Pose>
const Pose& IncrementalSolver<Pose>::linearization_point(int vertex) const {
  IRRR_CHECK(Contains(vertex));
  return impl_->LinearizationPoint(vertex);
}

template <class Pose>
const std::vector<int>& IncrementalSolver<Pose>::vertices() const {
  return impl_->vertices;
}

template <class Pose>
const std::vector<int>& IncrementalSolver<Pose>::edges() const {
  return impl_->edges;
}

template <class Pose>
double IncrementalSolver<Pose>::chi2() const {
  return impl_->ModelChi2();
}

template <class Pose>
double IncrementalSolver<Pose>::ExactChi2() const {
  return impl_->ExactChi2();
}

template <class Pose>
double IncrementalSolver<Pose>::DegreesOfFreedom() const {
  return impl_->DegreesOfFreedom();
}

template <class Pose>
const typename IncrementalSolver<Pose>::Counters& IncrementalSolver<Pose>::counters() const {
  return impl_->counters;
}

template class IncrementalSolver<Pose2>;
template class IncrementalSolver<Pose3>;

}  // namespace irrr
