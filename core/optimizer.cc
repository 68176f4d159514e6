#include "core/optimizer.h"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace irrr {
namespace {

bool EdgeIsActive(const std::vector<char>& active, int e) { return active[e] != 0; }

int FindRoot(std::vector<int>* parent, int i) {
  while ((*parent)[i] != i) {
    (*parent)[i] = (*parent)[(*parent)[i]];  // path halving
    i = (*parent)[i];
  }
  return i;
}

}  // namespace

Status OptimizerOptions::Validate() const {
  if (max_iterations < 1) return Status::Error("max_iterations must be at least 1");
  if (!(function_tolerance >= 0.0)) return Status::Error("function_tolerance must be >= 0");
  if (!(parameter_tolerance >= 0.0)) return Status::Error("parameter_tolerance must be >= 0");
  if (!(initial_damping > 0.0)) return Status::Error("initial_damping must be > 0");
  return Status::Ok();
}

const char* TerminationTypeName(TerminationType type) {
  switch (type) {
    case TerminationType::kConvergence:
      return "CONVERGENCE";
    case TerminationType::kNoConvergence:
      return "NO_CONVERGENCE";
    case TerminationType::kOutOfReach:
      return "OUT_OF_REACH";
    case TerminationType::kFailure:
      return "FAILURE";
  }
  return "UNKNOWN";
}

template <class Pose>
double EdgeChi2(const Edge<Pose>& edge, const Pose& from, const Pose& to) {
  const typename Pose::Tangent r =
      RelativePoseResidual<Pose>(edge.measurement, from, to, nullptr, nullptr);
  return r.dot(edge.information * r);
}

template <class Pose>
double EdgeChi2(const Edge<Pose>& edge, const std::vector<Pose>& estimate) {
  return EdgeChi2(edge, estimate[edge.from], estimate[edge.to]);
}

template <class Pose>
std::vector<int> SessionComponents(const PoseGraph<Pose>& graph, const std::vector<char>& active) {
  std::vector<int> parent(graph.num_sessions());
  std::iota(parent.begin(), parent.end(), 0);
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose>& edge = graph.edge(e);
    if (!EdgeIsActive(active, e)) continue;
    const int a = FindRoot(&parent, graph.vertex(edge.from).session);
    const int b = FindRoot(&parent, graph.vertex(edge.to).session);
    // The smaller index stays root, so a component's root is its earliest session.
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
  std::vector<int> component(graph.num_sessions(), -1);
  int count = 0;
  for (int s = 0; s < graph.num_sessions(); ++s) {
    const int root = FindRoot(&parent, s);
    if (root == s) component[s] = count++;
    component[s] = component[root];
  }
  return component;
}

template <class Pose>
std::vector<char> GaugeAnchors(const PoseGraph<Pose>& graph,
                               const std::vector<char>& active,
                               int* num_components) {
  const int n = graph.num_vertices();
  std::vector<int> parent(n);
  std::iota(parent.begin(), parent.end(), 0);
  std::vector<char> touched(n, 0);
  // Orders vertices by (session, time): a component's root is its earliest session's first pose.
  auto earlier = [&graph](int a, int b) {
    const int session_a = graph.vertex(a).session;
    const int session_b = graph.vertex(b).session;
    return session_a != session_b ? session_a < session_b : a < b;
  };
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (!EdgeIsActive(active, e)) continue;
    const Edge<Pose>& edge = graph.edge(e);
    touched[edge.from] = touched[edge.to] = 1;
    const int a = FindRoot(&parent, edge.from);
    const int b = FindRoot(&parent, edge.to);
    if (a == b) continue;
    if (earlier(a, b)) {
      parent[b] = a;
    } else {
      parent[a] = b;
    }
  }
  std::vector<char> fixed(n, 0);
  int components = 0;
  for (int v = 0; v < n; ++v) {
    if (!touched[v]) {
      fixed[v] = 1;  // in no active edge: not part of this problem
    } else if (FindRoot(&parent, v) == v) {
      fixed[v] = 1;
      ++components;
    }
  }
  if (num_components != nullptr) *num_components = components;
  return fixed;
}

template <class Pose>
bool Optimizer<Pose>::PrepareLayout(const PoseGraph<Pose>& graph, const std::vector<char>& active) {
  constexpr int d = Pose::kDim;
  const int n = graph.num_vertices();
  std::vector<std::vector<int>> neighbors(n);
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose>& edge = graph.edge(e);
    if (options_.pattern == SparsityPattern::kActiveEdges && !EdgeIsActive(active, e)) {
      continue;
    }
    neighbors[std::max(edge.from, edge.to)].push_back(std::min(edge.from, edge.to));
  }
  for (std::vector<int>& column : neighbors) {
    std::sort(column.begin(), column.end());
    column.erase(std::unique(column.begin(), column.end()), column.end());
  }
  if (cholesky_.size() == n * d && neighbors == column_neighbors_) return false;

  column_neighbors_ = std::move(neighbors);
  block_column_start_.assign(n + 1, 0);
  diagonal_value_index_.assign(n * d, 0);
  std::vector<int> column_starts(n * d + 1, 0);
  std::vector<int> row_indices;
  for (int c = 0; c < n; ++c) {
    block_column_start_[c] = static_cast<int>(row_indices.size());
    for (int b = 0; b < d; ++b) {
      column_starts[c * d + b] = static_cast<int>(row_indices.size());
      for (int r : column_neighbors_[c]) {
        for (int a = 0; a < d; ++a) row_indices.push_back(r * d + a);
      }
      for (int a = 0; a <= b; ++a) row_indices.push_back(c * d + a);
      diagonal_value_index_[c * d + b] = static_cast<int>(row_indices.size()) - 1;
    }
  }
  column_starts[n * d] = static_cast<int>(row_indices.size());
  block_column_start_[n] = static_cast<int>(row_indices.size());
  cholesky_.SetPattern(n * d, column_starts, row_indices);
  return true;
}

// Index into the values of entry (row, column) of block (row_vertex, column_vertex), which must
// be in the pattern with row_vertex <= column_vertex (and row <= column on the diagonal).
// Block column c holds, for its scalar column b, d rows per neighbour r < c and then b + 1
// diagonal rows, so its scalar column b starts at start_c + b * n_c * d + b * (b + 1) / 2.
template <class Pose>
int Optimizer<Pose>::ValueIndex(int row_vertex, int column_vertex, int row, int column) const {
  constexpr int d = Pose::kDim;
  const std::vector<int>& neighbors = column_neighbors_[column_vertex];
  const int n_c = static_cast<int>(neighbors.size());
  const int column_start =
      block_column_start_[column_vertex] + column * n_c * d + column * (column + 1) / 2;
  if (row_vertex == column_vertex) return column_start + n_c * d + row;
  const int slot = static_cast<int>(
      std::lower_bound(neighbors.begin(), neighbors.end(), row_vertex) - neighbors.begin());
  return column_start + slot * d + row;
}

template <class Pose>
double Optimizer<Pose>::Linearize(const PoseGraph<Pose>& graph,
                                  const std::vector<char>& active,
                                  const std::vector<char>& fixed,
                                  const std::vector<Pose>& estimate,
                                  Eigen::VectorXd* gradient) {
  constexpr int d = Pose::kDim;
  using Matrix = typename Pose::Matrix;
  double* values = cholesky_.mutable_values();
  std::fill_n(values, cholesky_.num_nonzeros(), 0.0);
  gradient->setZero(graph.num_vertices() * d);

  // Adds M (rows of vertex r, columns of vertex c) to the upper triangle. The block's place in
  // each scalar column is found once; entries within it are consecutive rows.
  auto add_block = [&](int r, int c, const Matrix& m) {
    const bool transpose = r > c;
    const int row_vertex = transpose ? c : r;
    const int column_vertex = transpose ? r : c;
    for (int b = 0; b < d; ++b) {
      double* column = values + ValueIndex(row_vertex, column_vertex, 0, b);
      if (row_vertex == column_vertex) {
        for (int a = 0; a <= b; ++a) column[a] += m(a, b);
      } else if (transpose) {
        for (int a = 0; a < d; ++a) column[a] += m(b, a);
      } else {
        for (int a = 0; a < d; ++a) column[a] += m(a, b);
      }
    }
  };

  double chi2 = 0.0;
  Matrix J_from;
  Matrix J_to;
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose>& edge = graph.edge(e);
    if (!EdgeIsActive(active, e)) continue;
    const typename Pose::Tangent r = RelativePoseResidual<Pose>(
        edge.measurement, estimate[edge.from], estimate[edge.to], &J_from, &J_to);
    const Matrix information = Weight(e) * edge.information;
    const typename Pose::Tangent weighted_r = information * r;
    chi2 += r.dot(weighted_r);
    const bool from_free = !fixed[edge.from];
    const bool to_free = !fixed[edge.to];
    const Matrix Jt_W_from = J_from.transpose() * information;
    const Matrix Jt_W_to = J_to.transpose() * information;
    if (from_free) {
      add_block(edge.from, edge.from, Jt_W_from * J_from);
      gradient->template segment<d>(edge.from * d) += J_from.transpose() * weighted_r;
    }
    if (to_free) {
      add_block(edge.to, edge.to, Jt_W_to * J_to);
      gradient->template segment<d>(edge.to * d) += J_to.transpose() * weighted_r;
    }
    if (from_free && to_free) add_block(edge.from, edge.to, Jt_W_from * J_to);
  }
  for (int v = 0; v < graph.num_vertices(); ++v) {
    if (!fixed[v]) continue;
    for (int k = 0; k < d; ++k) values[diagonal_value_index_[v * d + k]] = 1.0;
  }
  return chi2;
}

template <class Pose>
OptimizerSummary Optimizer<Pose>::Solve(const PoseGraph<Pose>& graph,
                                        const std::vector<char>& active,
                                        std::vector<Pose>* estimate,
                                        double target_chi2) {
  constexpr int d = Pose::kDim;
  IRRR_CHECK(options_.Validate().ok());
  IRRR_CHECK(static_cast<int>(active.size()) == graph.num_edges());
  IRRR_CHECK(estimate != nullptr && static_cast<int>(estimate->size()) == graph.num_vertices());

  OptimizerSummary summary;
  covariance_fixed_.clear();
  const int n = graph.num_vertices();
  const std::vector<char> fixed = GaugeAnchors(graph, active, &summary.num_components);
  for (int e = 0; e < graph.num_edges(); ++e) {
    summary.num_active_edges += EdgeIsActive(active, e) ? 1 : 0;
  }
  summary.residual_dimension = d * summary.num_active_edges;
  int touched = 0;
  {
    std::vector<char> in_problem(n, 0);
    for (int e = 0; e < graph.num_edges(); ++e) {
      if (EdgeIsActive(active, e))
        in_problem[graph.edge(e).from] = in_problem[graph.edge(e).to] = 1;
    }
    for (char flag : in_problem) touched += flag;
  }
  summary.free_parameters = d * (touched - summary.num_components);

  const int analyses_before = cholesky_.num_analyses();
  std::vector<Pose>& x = *estimate;
  std::vector<Pose> candidate(n);
  Eigen::VectorXd gradient;
  Eigen::VectorXd step;
  const bool levenberg_marquardt = options_.algorithm == OptimizerAlgorithm::kLevenbergMarquardt;

  auto apply_step = [&](const Eigen::VectorXd& delta) {
    for (int v = 0; v < n; ++v) {
      candidate[v] = fixed[v] ? x[v] : x[v].Retract(delta.template segment<d>(v * d));
    }
  };
  auto chi2_at = [&](const std::vector<Pose>& poses) {
    double chi2 = 0.0;
    for (int e = 0; e < graph.num_edges(); ++e) {
      if (EdgeIsActive(active, e)) chi2 += Weight(e) * EdgeChi2(graph.edge(e), poses);
    }
    return chi2;
  };

  if (n > 0) {
    PrepareLayout(graph, active);
    double chi2 = Linearize(graph, active, fixed, x, &gradient);
    summary.initial_chi2 = chi2;
    summary.termination = TerminationType::kNoConvergence;
    summary.message = "maximum number of iterations reached";
    double damping = 0.0;
    double initial_damping = 0.0;
    double damping_growth = 2.0;
    if (levenberg_marquardt) {
      double max_diagonal = 0.0;
      for (int k : diagonal_value_index_) {
        max_diagonal = std::max(max_diagonal, cholesky_.mutable_values()[k]);
      }
      damping = options_.initial_damping * std::max(max_diagonal, 1.0);
      initial_damping = damping;
    }
    std::vector<double> saved_diagonal(diagonal_value_index_.size());
    while (summary.iterations < options_.max_iterations) {
      ++summary.iterations;
      double* values = cholesky_.mutable_values();
      if (levenberg_marquardt) {
        for (size_t k = 0; k < diagonal_value_index_.size(); ++k) {
          saved_diagonal[k] = values[diagonal_value_index_[k]];
          if (!fixed[k / d]) values[diagonal_value_index_[k]] += damping;
        }
      }
      std::string solver_message;
      const LinearSolverStatus status = cholesky_.Factorize(&solver_message);
      if (levenberg_marquardt) {
        for (size_t k = 0; k < diagonal_value_index_.size(); ++k) {
          values[diagonal_value_index_[k]] = saved_diagonal[k];
        }
      }
      if (status == LinearSolverStatus::kNotPositiveDefinite && levenberg_marquardt) {
        damping *= damping_growth;
        damping_growth *= 2.0;
        continue;
      }
      if (status != LinearSolverStatus::kSuccess || !cholesky_.Solve(-gradient, &step)) {
        summary.termination = TerminationType::kFailure;
        summary.message = "linear solver: " + solver_message;
        break;
      }
      if (!step.allFinite()) {
        summary.termination = TerminationType::kFailure;
        summary.message = "the step has non-finite entries";
        break;
      }
      apply_step(step);
      double step_size = step.lpNorm<Eigen::Infinity>();
      double new_chi2;
      bool accept = true;
      if (levenberg_marquardt) {
        new_chi2 = chi2_at(candidate);
        // Predicted decrease of the linear model: -g'dx + lambda |dx|^2 (with (H + lambda I) dx =
        // -g).
        const double predicted = -gradient.dot(step) + damping * step.squaredNorm();
        const double gain = (chi2 - new_chi2) / predicted;
        accept = std::isfinite(new_chi2) && predicted > 0.0 && gain > 0.0;
        if (accept) {
          damping *= std::max(1.0 / 3.0, 1.0 - std::pow(2.0 * gain - 1.0, 3));
          damping_growth = 2.0;
        } else {
          damping *= damping_growth;
          damping_growth *= 2.0;
        }
      } else {
        // Gauss-Newton: linearizing at the candidate serves the next iteration and gives its
        // chi2. A step that raises chi2 (far from the optimum, or with inconsistent loops, full
        // steps can diverge) is halved until chi2 falls; if none of kMaxBacktracks halvings does,
        // the estimate is as good as this direction gets.
        new_chi2 = Linearize(graph, active, fixed, candidate, &gradient);
        if (!(new_chi2 <= chi2)) {
          constexpr int kMaxBacktracks = 8;
          double scale = 1.0;
          bool decreased = false;
          for (int k = 0; k < kMaxBacktracks && !decreased; ++k) {
            scale *= 0.5;
            apply_step(scale * step);
            new_chi2 = chi2_at(candidate);
            decreased = new_chi2 <= chi2;
          }
          if (!decreased) {
            summary.termination = TerminationType::kConvergence;
            summary.message = "no decrease along the Gauss-Newton step";
            break;
          }
          step_size *= scale;
          new_chi2 = Linearize(graph, active, fixed, candidate, &gradient);
        }
      }
      if (!std::isfinite(new_chi2)) {
        summary.termination = TerminationType::kFailure;
        summary.message = "chi2 became non-finite";
        break;
      }
      if (!accept) {
        if (step_size <= options_.parameter_tolerance) {
          summary.termination = TerminationType::kConvergence;
          summary.message = "parameter tolerance reached (rejected step)";
          break;
        }
        continue;
      }
      x.swap(candidate);
      summary.estimate_updated = true;
      const double decrease = chi2 - new_chi2;
      // A step shortened by heavy damping also decreases chi2 little: Levenberg-Marquardt only
      // calls that convergence while the damping is no larger than it started.
      const bool small_decrease = std::abs(decrease) <= options_.function_tolerance * chi2 &&
                                  (!levenberg_marquardt || damping <= initial_damping);
      chi2 = new_chi2;
      if (step_size <= options_.parameter_tolerance) {
        summary.termination = TerminationType::kConvergence;
        summary.message = "parameter tolerance reached";
        break;
      }
      if (small_decrease) {
        summary.termination = TerminationType::kConvergence;
        summary.message = "function tolerance reached";
        break;
      }
      const int iterations_left = options_.max_iterations - summary.iterations;
      if (summary.iterations >= 2 && chi2 - target_chi2 > iterations_left * decrease) {
        summary.termination = TerminationType::kOutOfReach;
        summary.message = "the target chi2 is out of reach";
        break;
      }
      if (levenberg_marquardt) Linearize(graph, active, fixed, x, &gradient);
    }
  } else {
    summary.termination = TerminationType::kConvergence;
    summary.message = "empty graph";
  }

  summary.linear_solver_analyses = cholesky_.num_analyses() - analyses_before;
  summary.edge_chi2.resize(graph.num_edges());
  summary.final_chi2 = 0.0;
  for (int e = 0; e < graph.num_edges(); ++e) {
    summary.edge_chi2[e] = EdgeChi2(graph.edge(e), x);
    if (EdgeIsActive(active, e)) summary.final_chi2 += Weight(e) * summary.edge_chi2[e];
  }
  return summary;
}

template <class Pose>
OptimizerSummary Optimizer<Pose>::SolveWeighted(const PoseGraph<Pose>& graph,
                                                const std::vector<char>& active,
                                                const std::vector<double>& weights,
                                                std::vector<Pose>* estimate) {
  IRRR_CHECK(static_cast<int>(weights.size()) == graph.num_edges());
  weights_ = &weights;
  OptimizerSummary summary = Solve(graph, active, estimate);
  weights_ = nullptr;
  return summary;
}

template <class Pose>
bool Optimizer<Pose>::FactorizeAt(const PoseGraph<Pose>& graph,
                                  const std::vector<char>& active,
                                  const std::vector<Pose>& estimate) {
  IRRR_CHECK(static_cast<int>(active.size()) == graph.num_edges());
  IRRR_CHECK(static_cast<int>(estimate.size()) == graph.num_vertices());
  covariance_fixed_.clear();
  if (graph.num_vertices() == 0) return false;
  std::vector<char> fixed = GaugeAnchors(graph, active, nullptr);
  PrepareLayout(graph, active);
  Eigen::VectorXd gradient;
  Linearize(graph, active, fixed, estimate, &gradient);
  if (cholesky_.Factorize(nullptr) != LinearSolverStatus::kSuccess) return false;
  covariance_fixed_ = std::move(fixed);
  return true;
}

template <class Pose>
bool Optimizer<Pose>::Covariance(const std::vector<int>& vertices, Eigen::MatrixXd* covariance) {
  constexpr int d = Pose::kDim;
  if (covariance_fixed_.empty()) return false;
  const int m = static_cast<int>(vertices.size());
  Eigen::MatrixXd unit = Eigen::MatrixXd::Zero(cholesky_.size(), d * m);
  for (int k = 0; k < m; ++k) {
    IRRR_CHECK(vertices[k] >= 0 && vertices[k] < static_cast<int>(covariance_fixed_.size()));
    if (covariance_fixed_[vertices[k]]) continue;
    for (int a = 0; a < d; ++a) unit(vertices[k] * d + a, k * d + a) = 1.0;
  }
  Eigen::MatrixXd columns;
  if (!cholesky_.Solve(unit, &columns)) return false;
  covariance->setZero(d * m, d * m);
  for (int k = 0; k < m; ++k) {
    if (covariance_fixed_[vertices[k]]) continue;
    for (int j = 0; j < m; ++j) {
      if (covariance_fixed_[vertices[j]]) continue;
      covariance->block<d, d>(k * d, j * d) = columns.block<d, d>(vertices[k] * d, j * d);
    }
  }
  return true;
}

template double EdgeChi2<Pose2>(const Edge<Pose2>&, const std::vector<Pose2>&);
template double EdgeChi2<Pose3>(const Edge<Pose3>&, const std::vector<Pose3>&);
template double EdgeChi2<Pose2>(const Edge<Pose2>&, const Pose2&, const Pose2&);
template double EdgeChi2<Pose3>(const Edge<Pose3>&, const Pose3&, const Pose3&);
template std::vector<int> SessionComponents<Pose2>(const PoseGraph<Pose2>&,
                                                   const std::vector<char>&);
template std::vector<int> SessionComponents<Pose3>(const PoseGraph<Pose3>&,
                                                   const std::vector<char>&);
template std::vector<char> GaugeAnchors<Pose2>(const PoseGraph<Pose2>&,
                                               const std::vector<char>&,
                                               int*);
template std::vector<char> GaugeAnchors<Pose3>(const PoseGraph<Pose3>&,
                                               const std::vector<char>&,
                                               int*);
template class Optimizer<Pose2>;
template class Optimizer<Pose3>;

}  // namespace irrr
