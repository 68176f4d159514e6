#ifndef IRRR_CORE_INCREMENTAL_SOLVER_IMPL_H_
#define IRRR_CORE_INCREMENTAL_SOLVER_IMPL_H_

// IncrementalSolver's state and its linear algebra (CHOLMOD factor, updates, rebuilds, solves,
// relinearization, Optimize; the covariances in core/incremental_solver_covariance.cc). Private
// to core/incremental_solver*.cc: include nowhere else.

#include <cholmod.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Cholesky>

#include "core/incremental_solver.h"
#include "core/optimizer.h"

namespace irrr {
namespace incremental_internal {

// Free places kept for new poses at least, whatever the problem's size.
constexpr int kMinSpare = 64;
// The factor's size is checked against refill_ratio after this many modifications.
constexpr int kFillCheckInterval = 32;
// A rank-1 update's cost per factor entry on its path, in flops of a factorization. Updates run
// on a simplicial factor; rebuilds of larger or 3D problems (City10000, Sphere2500) on a
// supernodal one (BLAS), whose flops are cheaper. Measured over 0.5, 1, 2 and 4 (Manhattan + 100,
// City10000 + 1000 and Sphere2500 + 100 random wrong loops, CPU s): 0.5 gave 1.01 / 34.7 / 8.6 s,
// 1 0.88 / 30.6 / 5.8, 2 0.90 / 31.8 / 5.8, 4 0.90 / 34.8 / 4.9, the same decisions throughout.
constexpr double kUpdateCostRatio = 2.0;
// Optimize turns to a batch solve after this many iterations in a row whose model chi2 rose by
// more than kRiseTolerance (relative): Gauss-Newton's full steps going astray.
constexpr int kMaxRises = 3;
constexpr double kRiseTolerance = 1e-6;
// A factorization that finds no positive pivot is tried again with H's diagonal raised by this
// much (relative), then by 100 times more each time, up to kMaxRetryDamping (Rebuild).
constexpr double kRetryDamping = 1e-10;
constexpr double kMaxRetryDamping = 1e-4;

}  // namespace incremental_internal

template <class Pose>
struct IncrementalSolver<Pose>::Impl {
  // The tuning constants above, by their short names.
  static constexpr int kMinSpare = incremental_internal::kMinSpare;
  static constexpr int kFillCheckInterval = incremental_internal::kFillCheckInterval;
  static constexpr double kUpdateCostRatio = incremental_internal::kUpdateCostRatio;
  static constexpr int kMaxRises = incremental_internal::kMaxRises;
  static constexpr double kRiseTolerance = incremental_internal::kRiseTolerance;
  static constexpr double kRetryDamping = incremental_internal::kRetryDamping;
  static constexpr double kMaxRetryDamping = incremental_internal::kMaxRetryDamping;

  static constexpr int d = Pose::kDim;
  using Tangent = typename Pose::Tangent;
  using RowMajorMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

  // One edge linearized at the linearization points of its poses, whitened by Omega = U'U:
  // J_w = U J, r_w = U r, so that J'Omega J = J_w'J_w and J'Omega r = J_w'r_w.
  struct Term {
    int slot_from = -1;  // -1: the anchor (no variables)
    int slot_to = -1;
    Matrix J_from;
    Matrix J_to;
    Tangent r;
  };

  // What a trial must give back.
  struct Trial {
    std::vector<Pose> x_lin;
    std::vector<Pose> x;
    Eigen::VectorXd delta;
    Eigen::VectorXd b;
    double chi2_lin = 0.0;
    std::vector<int> edges;    // the problem's edges at the checkpoint
    std::vector<char> moved;   // per slot: relinearized during the trial
    std::vector<int> added;    // edges added during the trial (and still in)
    std::vector<int> removed;  // edges removed during the trial (and still out)
    bool rebuilt = false;
    bool analysis_valid = false;  // the symbolic analysis at the checkpoint fit its structure
    double target_chi2 = std::numeric_limits<double>::infinity();  // see Checkpoint
  };

  Impl(const PoseGraph<Pose>* g, const IncrementalSolverOptions& o)
      : graph(g), options(o), trial_batch_optimizer(TrialBatchOptions(o)) {
    cholmod_start(&common);
    common.print = 0;
    common.error_handler = nullptr;
    // LDL' (the form CHOLMOD modifies), simplicial, of a matrix Rebuild assembles already in our
    // order (the future poses' places last): CHOLMOD keeps its natural order, and does not
    // postorder (that would move the free places).
    common.supernodal = CHOLMOD_SIMPLICIAL;
    common.final_ll = 0;
    common.nmethods = 1;
    common.method[0].ordering = CHOLMOD_NATURAL;
    common.postorder = 0;
  }

  ~Impl() {
    FreeFactor();
    FreeSymbolic();
    if (solution != nullptr) cholmod_free_dense(&solution, &common);
    if (work_y != nullptr) cholmod_free_dense(&work_y, &common);
    if (work_e != nullptr) cholmod_free_dense(&work_e, &common);
    cholmod_finish(&common);
  }

  void FreeFactor() {
    if (factor != nullptr) cholmod_free_factor(&factor, &common);
  }

  void FreeSymbolic() {
    if (symbolic != nullptr) cholmod_free_factor(&symbolic, &common);
  }

  // ---- the problem -------------------------------------------------------------------------

  const Pose& LinearizationPoint(int v) const {
    return v == anchor ? anchor_pose : x_lin[slot_of[v]];
  }
  const Pose& Estimate(int v) const { return v == anchor ? anchor_pose : x[slot_of[v]]; }
  int SlotOf(int v) const { return v < static_cast<int>(slot_of.size()) ? slot_of[v] : -1; }

  // U with U'U = the information of edge `e` (its Cholesky factor), computed once per edge: every
  // linearization and model check whitens by it. Kept for the edges this solver has seen (a
  // fleet's graph may hold many components' edges).
  const Matrix& Whitening(int e) const {
    if (static_cast<int>(whitening_of_edge.size()) <= e) {
      whitening_of_edge.resize(graph->num_edges(), -1);
    }
    if (whitening_of_edge[e] < 0) {
      whitening_of_edge[e] = static_cast<int>(whitening.size());
      whitening.push_back(Eigen::LLT<Matrix>(graph->edge(e).information).matrixU());
    }
    return whitening[whitening_of_edge[e]];
  }

  Term Linearize(int e) const {
    const Edge<Pose>& edge = graph->edge(e);
    Term t;
    t.slot_from = edge.from == anchor ? -1 : slot_of[edge.from];
    t.slot_to = edge.to == anchor ? -1 : slot_of[edge.to];
    const Tangent r = RelativePoseResidual<Pose>(edge.measurement,
                                                 LinearizationPoint(edge.from),
                                                 LinearizationPoint(edge.to),
                                                 &t.J_from,
                                                 &t.J_to);
    const Matrix& U = Whitening(e);
    t.J_from = U * t.J_from;
    t.J_to = U * t.J_to;
    t.r = U * r;
    return t;
  }

  // b -= sign * J'Omega r, chi2_lin += sign * r'Omega r.
  void AccumulateRightHandSide(const Term& t, double sign) {
    if (t.slot_from >= 0) b.segment<d>(t.slot_from * d) -= sign * t.J_from.transpose() * t.r;
    if (t.slot_to >= 0) b.segment<d>(t.slot_to * d) -= sign * t.J_to.transpose() * t.r;
    chi2_lin += sign * t.r.squaredNorm();
  }

  // ---- the factor --------------------------------------------------------------------------

  // Updates (sign > 0) or downdates the factor by the terms' J'Omega J: C = [J_w' ...] with rows
  // in the factor's order (CHOLMOD's updown does not permute).
  bool Modify(const std::vector<Term>& terms, bool update) {
    if (terms.empty()) return true;
    const int n = capacity * d;
    const int ncol = static_cast<int>(terms.size()) * d;
    cholmod_sparse* C =
        cholmod_allocate_sparse(n, ncol, ncol * 2 * d, 1, 1, 0, CHOLMOD_REAL, &common);
    if (C == nullptr) return false;
    int* Cp = static_cast<int*>(C->p);
    int* Ci = static_cast<int*>(C->i);
    double* Cx = static_cast<double*>(C->x);
    int nz = 0;
    std::vector<std::pair<int, double>> column;
    for (size_t t = 0; t < terms.size(); ++t) {
      const Term& term = terms[t];
      for (int k = 0; k < d; ++k) {
        Cp[t * d + k] = nz;
        column.clear();
        for (int a = 0; a < d; ++a) {
          if (term.slot_from >= 0) {
            column.push_back({position[term.slot_from * d + a], term.J_from(k, a)});
          }
          if (term.slot_to >= 0)
            column.push_back({position[term.slot_to * d + a], term.J_to(k, a)});
        }
        std::sort(column.begin(), column.end());
        for (const auto& [row, value] : column) {
          Ci[nz] = row;
          Cx[nz] = value;
          ++nz;
        }
      }
    }
    Cp[ncol] = nz;
    const int ok = cholmod_updown(update ? 1 : 0, C, factor, &common);
    cholmod_free_sparse(&C, &common);
    counters.updates += static_cast<long>(terms.size());
    NoteModification(static_cast<int>(terms.size()));
    return ok && common.status == CHOLMOD_OK;
  }

  void NoteModification(int count) {
    modifications_since_check += count;
    if (modifications_since_check < kFillCheckInterval) return;
    modifications_since_check = 0;
    if (FactorNonzeros() > options.refill_ratio * nonzeros_after_build) rebuild_due = true;
  }

  // The work of a rank-d modification of the factor by the terms of `edges`: the entries of the
  // factor on the elimination-tree paths from their poses' columns to the root (each is touched
  // d times), against a rebuild's (the last factorization's flop count): Add and Optimize take
  // the cheaper.
  bool CheaperToRebuild(const std::vector<int>& modified_edges, int times) const {
    const int* Lp = static_cast<const int*>(factor->p);
    const int* Li = static_cast<const int*>(factor->i);
    const int* Lnz = static_cast<const int*>(factor->nz);
    const double budget = rebuild_flops / (kUpdateCostRatio * d * times);
    double work = 0.0;
    mark.resize(factor->n, 0);
    std::vector<int> visited;
    for (int e : modified_edges) {
      for (int v : {graph->edge(e).from, graph->edge(e).to}) {
        const int s = SlotOf(v);
        if (s < 0) continue;
        for (int j = position[s * d]; j >= 0 && !mark[j]; j = Lnz[j] > 1 ? Li[Lp[j] + 1] : -1) {
          mark[j] = 1;
          visited.push_back(j);
          work += Lnz[j];
        }
      }
      for (int j : visited) mark[j] = 0;
      visited.clear();
      if (work > budget) return true;
    }
    return false;
  }

  // Multiplies the diagonal of the upper triangle A by 1 + `relative`.
  static void RaiseDiagonal(cholmod_sparse* A, double relative) {
    const int* Ap = static_cast<const int*>(A->p);
    const int* Ai = static_cast<const int*>(A->i);
    double* Ax = static_cast<double*>(A->x);
    for (size_t j = 0; j < A->ncol; ++j) {
      for (int p = Ap[j]; p < Ap[j + 1]; ++p) {
        if (Ai[p] == static_cast<int>(j)) Ax[p] *= 1.0 + relative;
      }
    }
  }

  double FactorNonzeros() const {
    const int* nz = static_cast<const int*>(factor->nz);
    double total = 0.0;
    for (size_t j = 0; j < factor->n; ++j) total += nz[j];
    return total;
  }

  // P H P' from the edges' terms: its upper triangle in the factor's order (`position`), each
  // column's rows sorted, identity on the free places. Given H and the order, CHOLMOD would
  // permute H with two transposes at every factorization (a tenth of a reversal-heavy run), and
  // its triplet form needs a sort; assembled in place, H is factorized as it comes. A pose's
  // column block holds the blocks of its neighbours ordered before it, then the upper triangle of
  // its own (a pose's variables keep their order in the factor's). nullptr: out of memory.
  cholmod_sparse* AssemblePermuted(const std::vector<Term>& terms) {
    const int used = static_cast<int>(vertex_of_slot.size());
    const int n = capacity * d;
    std::vector<int> pose_at(capacity);  // a place's pose in the factor's order
    std::vector<int> place_at(capacity);
    for (int s = 0; s < capacity; ++s) {
      pose_at[s] = position[s * d] / d;
      place_at[pose_at[s]] = s;
    }
    // Per place: the poses (in the factor's order) of its neighbours ordered before it.
    std::vector<std::vector<int>> before(used);
    for (const Term& t : terms) {
      if (t.slot_from < 0 || t.slot_to < 0) continue;
      const int a = pose_at[t.slot_from];
      const int c = pose_at[t.slot_to];
      if (a < c) {
        before[t.slot_to].push_back(a);
      } else {
        before[t.slot_from].push_back(c);
      }
    }
    size_t entries = static_cast<size_t>(n - used * d);  // the free places' diagonal
    for (std::vector<int>& poses : before) {
      std::sort(poses.begin(), poses.end());
      poses.erase(std::unique(poses.begin(), poses.end()), poses.end());
      entries += poses.size() * d * d + d * (d + 1) / 2;
    }
    cholmod_sparse* A = cholmod_allocate_sparse(n, n, entries, 1, 1, 1, CHOLMOD_REAL, &common);
    if (A == nullptr) return nullptr;
    int* Ap = static_cast<int*>(A->p);
    int* Ai = static_cast<int*>(A->i);
    double* Ax = static_cast<double*>(A->x);
    int k = 0;
    for (int pose = 0; pose < capacity; ++pose) {
      const int s = place_at[pose];
      for (int c = 0; c < d; ++c) {
        Ap[pose * d + c] = k;
        if (s >= used) {
          Ai[k] = pose * d + c;
          Ax[k++] = 1.0;
          continue;
        }
        for (int q : before[s]) {
          for (int a = 0; a < d; ++a) {
            Ai[k] = q * d + a;
            Ax[k++] = 0.0;
          }
        }
        for (int a = 0; a <= c; ++a) {
          Ai[k] = pose * d + a;
          Ax[k++] = 0.0;
        }
      }
    }
    Ap[n] = k;
    // Adds `block` (rows: place row_slot's variables, columns: place column_slot's) where the
    // factor's order puts it; a diagonal block's upper triangle only.
    auto add_block = [&](int row_slot, int column_slot, const Matrix& block) {
      const int column_pose = pose_at[column_slot];
      const std::vector<int>& poses = before[column_slot];
      const int offset =
          row_slot == column_slot
              ? static_cast<int>(poses.size()) * d
              : static_cast<int>(std::lower_bound(poses.begin(), poses.end(), pose_at[row_slot]) -
                                 poses.begin()) *
                    d;
      for (int c = 0; c < d; ++c) {
        double* column = Ax + Ap[column_pose * d + c] + offset;
        const int rows = row_slot == column_slot ? c + 1 : d;
        for (int a = 0; a < rows; ++a) column[a] += block(a, c);
      }
    };
    for (const Term& t : terms) {
      if (t.slot_from >= 0) add_block(t.slot_from, t.slot_from, t.J_from.transpose() * t.J_from);
      if (t.slot_to >= 0) add_block(t.slot_to, t.slot_to, t.J_to.transpose() * t.J_to);
      if (t.slot_from >= 0 && t.slot_to >= 0) {
        const Matrix cross = t.J_from.transpose() * t.J_to;
        if (pose_at[t.slot_from] < pose_at[t.slot_to]) {
          add_block(t.slot_from, t.slot_to, cross);
        } else {
          add_block(t.slot_to, t.slot_from, cross.transpose());
        }
      }
    }
    return A;
  }

  // Linearizes every edge at x (which becomes x_lin), orders the poses afresh (AMD on the pose
  // graph, the free places last) and factorizes. delta is zero afterwards. With `grow`, the free
  // places are replenished (never during a trial, whose saved vectors keep their size).
  bool Rebuild(bool grow) {
    ++counters.rebuilds;
    ++rebuilds_this_call;
    if (trial_active) trial.rebuilt = true;
    const int used = static_cast<int>(vertex_of_slot.size());
    if (grow) {
      IRRR_CHECK(!trial_active);
      const int spare = std::max(kMinSpare, static_cast<int>(options.spare_fraction * used));
      const int grown = std::max(used + spare, capacity);
      if (grown != capacity) ++structure_version;
      capacity = grown;
    }
    IRRR_CHECK(capacity >= used);
    // The problem's structure is the one last analyzed (only values changed: relinearization):
    // its symbolic analysis serves again, and only the numeric factorization is redone.
    const bool reuse_analysis = symbolic != nullptr && analyzed_version == structure_version;
    const int n = capacity * d;
    x_lin.resize(capacity);
    x.resize(capacity);
    for (int s = 0; s < used; ++s) x_lin[s] = x[s];
    delta = Eigen::VectorXd::Zero(n);
    b = Eigen::VectorXd::Zero(n);
    chi2_lin = 0.0;

    // The fill-reducing order of the poses, from their adjacency.
    std::vector<int> order;
    if (used > 0 && !reuse_analysis) {
      std::vector<std::vector<int>> neighbors(used);
      for (int e : edges) {
        const int a = SlotOf(graph->edge(e).from);
        const int c = SlotOf(graph->edge(e).to);
        if (a < 0 || c < 0 || a == c) continue;
        neighbors[std::max(a, c)].push_back(std::min(a, c));
      }
      int entries = 0;
      for (auto& column : neighbors) {
        std::sort(column.begin(), column.end());
        column.erase(std::unique(column.begin(), column.end()), column.end());
        entries += static_cast<int>(column.size()) + 1;
      }
      cholmod_sparse* pattern =
          cholmod_allocate_sparse(used, used, entries, 1, 1, 1, CHOLMOD_PATTERN, &common);
      if (pattern == nullptr) return false;
      int* p = static_cast<int*>(pattern->p);
      int* i = static_cast<int*>(pattern->i);
      int k = 0;
      for (int c = 0; c < used; ++c) {
        p[c] = k;
        for (int r : neighbors[c]) i[k++] = r;
        i[k++] = c;
      }
      p[used] = k;
      order.resize(used);
      const int ok = cholmod_amd(pattern, nullptr, 0, order.data(), &common);
      cholmod_free_sparse(&pattern, &common);
      if (!ok) return false;
    }
    if (!reuse_analysis) {
      // Each pose's variables in the AMD order of the poses, the free places last.
      position.assign(n, 0);
      int row = 0;
      for (int s : order) {
        for (int a = 0; a < d; ++a) position[s * d + a] = row++;
      }
      for (int s = used; s < capacity; ++s) {
        for (int a = 0; a < d; ++a) position[s * d + a] = row++;
      }
    }

    // The edges' terms at x_lin: b, and P H P'.
    std::vector<Term> terms;
    terms.reserve(edges.size());
    for (int e : edges) terms.push_back(Linearize(e));
    for (const Term& t : terms) AccumulateRightHandSide(t, 1.0);
    cholmod_sparse* A = AssemblePermuted(terms);
    if (A == nullptr) return false;
    FreeFactor();
    // Supernodal where CHOLMOD judges it faster (3D graphs: six times), then converted to the
    // simplicial LDL' that updates need.
    if (reuse_analysis) {
      factor = cholmod_copy_factor(symbolic, &common);
    } else {
      if (symbolic != nullptr) cholmod_free_factor(&symbolic, &common);
      common.supernodal = CHOLMOD_AUTO;
      factor = cholmod_analyze(A, &common);
      rebuild_flops = common.fl;
      if (factor != nullptr) symbolic = cholmod_copy_factor(factor, &common);
      analyzed_version = structure_version;
    }
    bool ok =
        factor != nullptr && cholmod_factorize(A, factor, &common) && common.status == CHOLMOD_OK;
    // H is positive definite in exact arithmetic, but rounding can leave an ill-conditioned one
    // without a positive pivot (the parking garage + 1000 local wrong loops, seed 11, 845 poses:
    // the factor was left supernodal and the next covariance read out of bounds). Its diagonal
    // is then raised by a relative 1e-10, and by 100 times more while that does not suffice, as
    // Levenberg-Marquardt's damping would: the step changes by as little.
    double damping = kRetryDamping;
    while (!ok && factor != nullptr && symbolic != nullptr && common.status == CHOLMOD_NOT_POSDEF &&
           damping <= kMaxRetryDamping) {
      RaiseDiagonal(A, damping);
      damping *= 100.0;
      FreeFactor();
      factor = cholmod_copy_factor(symbolic, &common);
      ok =
          factor != nullptr && cholmod_factorize(A, factor, &common) && common.status == CHOLMOD_OK;
    }
    cholmod_free_sparse(&A, &common);
    if (ok && factor->is_super) {
      ok = cholmod_change_factor(CHOLMOD_REAL, false, false, true, true, factor, &common) &&
           common.status == CHOLMOD_OK;
    }
    if (!ok) return false;
    // The factor is of P H P': its permutation is ours (the inverse of `position`), for the
    // solves (updates and covariances work in the factor's order already).
    int* factor_order = static_cast<int*>(factor->Perm);
    for (int k = 0; k < n; ++k) factor_order[position[k]] = k;
    factor->ordering = CHOLMOD_GIVEN;
    nonzeros_after_build = FactorNonzeros();
    modifications_since_check = 0;
    rebuild_due = false;
    return true;
  }

  // delta = H^-1 b; x = x_lin (+) delta.
  bool SolveSystem() {
    ++counters.solves;
    const int n = capacity * d;
    cholmod_dense rhs;
    rhs.nrow = n;
    rhs.ncol = 1;
    rhs.nzmax = n;
    rhs.d = n;
    rhs.x = b.data();
    rhs.z = nullptr;
    rhs.xtype = CHOLMOD_REAL;
    rhs.dtype = CHOLMOD_DOUBLE;
    if (!cholmod_solve2(
            CHOLMOD_A, factor, &rhs, nullptr, &solution, nullptr, &work_y, &work_e, &common)) {
      return false;
    }
    // A solution that is not finite leaves delta as it was: Extend reads it.
    const Eigen::Map<const Eigen::VectorXd> solved(static_cast<const double*>(solution->x), n);
    if (!solved.allFinite()) return false;
    delta = solved;
    const int used = static_cast<int>(vertex_of_slot.size());
    for (int s = 0; s < used; ++s) x[s] = x_lin[s].Retract(delta.segment<d>(s * d));
    return true;
  }

  double ModelChi2() const { return chi2_lin - b.dot(delta); }
  // Degrees of freedom of the problem: residual rows less free pose variables.
  double DegreesOfFreedom() const {
    const double used = static_cast<double>(vertex_of_slot.size());
    return static_cast<double>(d) * (static_cast<double>(edges.size()) - used);
  }

  // Records D^2 per degree of freedom of the problem as it stands (not in a trial): the scale of
  // the model tolerance until the next settled change, so that a change that raises D^2 (a wrong
  // loop in a trial) does not widen its own tolerance.
  void NoteSettled() {
    if (trial_active) return;
    const double dof = DegreesOfFreedom();
    settled_chi2_per_dof = dof >= 1.0 ? ModelChi2() / dof : 0.0;
  }

  // Whether the quadratic model at x_lin still predicts the residuals at x: the squared
  // (whitened) differences between the exact residuals of `moved_edges` and the model's, at most
  // model_tolerance times the settled D^2 per degree of freedom. The model's optimum is then as
  // good as the exact one's to about that much D^2: the misfit's projection on the Jacobians
  // bounds what relinearizing would gain.
  bool ModelHolds(const std::vector<int>& moved_edges) const {
    const double budget = options.model_tolerance * settled_chi2_per_dof;
    if (!(budget > 0.0)) return false;
    double misfit = 0.0;
    for (int e : moved_edges) {
      const Term t = Linearize(e);
      Tangent predicted = t.r;
      if (t.slot_from >= 0) predicted += t.J_from * delta.segment<d>(t.slot_from * d);
      if (t.slot_to >= 0) predicted += t.J_to * delta.segment<d>(t.slot_to * d);
      const Edge<Pose>& edge = graph->edge(e);
      const Tangent r = RelativePoseResidual<Pose>(
          edge.measurement, Estimate(edge.from), Estimate(edge.to), nullptr, nullptr);
      misfit += (Whitening(e) * r - predicted).squaredNorm();
      if (misfit > budget) return false;
    }
    return true;
  }
  double ExactChi2() const {
    double chi2 = 0.0;
    for (int e : edges) {
      const Edge<Pose>& edge = graph->edge(e);
      const typename Pose::Tangent r = RelativePoseResidual<Pose>(
          edge.measurement, Estimate(edge.from), Estimate(edge.to), nullptr, nullptr);
      chi2 += r.dot(edge.information * r);
    }
    return chi2;
  }

  // Relinearizes the poses `slots` at x: every edge touching them gets its term at the new
  // linearization points (the new terms added before the old ones leave, so that H stays
  // positive definite throughout).
  bool Relinearize(const std::vector<int>& slots) {
    std::vector<char> touched(edge_position.size(), 0);
    std::vector<int> affected;
    for (int s : slots) {
      for (int e : incident[s]) {
        if (!touched[e]) {
          touched[e] = 1;
          affected.push_back(e);
        }
      }
    }
    std::vector<Term> old_terms;
    for (int e : affected) old_terms.push_back(Linearize(e));
    for (int s : slots) {
      if (trial_active && !trial.moved[s]) trial.moved[s] = 1;
      x_lin[s] = x[s];
      delta.segment<d>(s * d).setZero();
    }
    std::vector<Term> new_terms;
    for (int e : affected) new_terms.push_back(Linearize(e));
    for (const Term& t : old_terms) AccumulateRightHandSide(t, -1.0);
    for (const Term& t : new_terms) AccumulateRightHandSide(t, 1.0);
    counters.relinearized += static_cast<long>(slots.size());
    return Modify(new_terms, true) && Modify(old_terms, false);
  }

  // Gauss-Newton to convergence: solve, relinearize what moved past the bounds, again. Full
  // Gauss-Newton steps suit the small corrections of most changes. When a change moves much of
  // the graph (a loop closing a long cycle), or the iteration does not settle, the optimum is
  // found by a batch solve with step control (Optimizer: Gauss-Newton that halves a step raising
  // chi2) from the better of the start and the last iterate, and the system is rebuilt there.
  IncrementalSummary Optimize() {
    IncrementalSummary summary;
    constexpr int kt = Pose::kTranslationDim;
    const int used = static_cast<int>(vertex_of_slot.size());
    const std::vector<Pose> start(x.begin(), x.begin() + used);
    double previous = std::numeric_limits<double>::infinity();
    int rises = 0;
    bool batch_solved = false;
    std::vector<Pose> batch_estimate;
    const int max_iterations = trial_active ? options.trial_max_iterations : options.max_iterations;
    for (int iteration = 0; iteration < max_iterations; ++iteration) {
      if (rebuild_due && !Rebuild(false)) return Failed(summary, "factorization failed (rebuild)");
      if (!SolveSystem()) return Failed(summary, "the linear system could not be solved");
      ++summary.iterations;
      const double chi2 = ModelChi2();
      rises = chi2 > previous * (1.0 + kRiseTolerance) ? rises + 1 : 0;
      previous = chi2;
      std::vector<int> moved;
      for (int s = 0; s < used; ++s) {
        const auto step = delta.segment<d>(s * d);
        if (step.template tail<d - kt>().norm() > options.relinearize_rotation_rad ||
            step.template head<kt>().norm() > options.relinearize_translation) {
          moved.push_back(s);
        }
      }
      std::vector<int> moved_edge_list;
      for (int q : moved)
        moved_edge_list.insert(moved_edge_list.end(), incident[q].begin(), incident[q].end());
      std::sort(moved_edge_list.begin(), moved_edge_list.end());
      moved_edge_list.erase(std::unique(moved_edge_list.begin(), moved_edge_list.end()),
                            moved_edge_list.end());
      if (moved.empty() || ModelHolds(moved_edge_list)) return Settled(summary, chi2, "");
      summary.relinearized += static_cast<int>(moved.size());
      const bool large = CheaperToRebuild(moved_edge_list, 2);
      // Unsettled: rising, or running out of iterations (a trial gets a batch solve half way and
      // fails if that does not settle it).
      const bool unsettled =
          rises >= kMaxRises ||
          iteration + 2 >= (trial_active && !batch_solved ? max_iterations / 2 : max_iterations);
      if (unsettled && trial_active && batch_solved) return Failed(summary, "did not converge");
      if (unsettled && batch_solved) {
        // Gauss-Newton's full steps went astray again from the batch solve's estimate, which
        // never raised D^2: that estimate stands. (The parking garage + 1000 local-grouped wrong
        // loops, seed 11: after a reversal they went on to a chi2 of 4e25, then to NaN.)
        std::copy(batch_estimate.begin(), batch_estimate.end(), x.begin());
        if (!Rebuild(false)) return Failed(summary, "factorization failed (rebuild)");
        return Settled(summary, ModelChi2(), "unsettled after the batch solve: its estimate kept");
      }
      if (unsettled) {
        batch_solved = true;
        bool out_of_reach = false;
        if (!BatchSolve(start, &out_of_reach)) return Failed(summary, "the batch solve failed");
        if (out_of_reach) return Failed(summary, "the trial's target chi2 is out of reach");
        batch_estimate.assign(x.begin(), x.begin() + used);
        if (!Rebuild(false)) return Failed(summary, "factorization failed (rebuild)");
      } else if (large) {
        if (!Rebuild(false)) return Failed(summary, "factorization failed (rebuild)");
      } else if (!Relinearize(moved)) {
        // A downdate that fails numerically leaves the factor unusable: start afresh.
        if (!Rebuild(false)) return Failed(summary, "factorization failed (rebuild)");
      }
    }
    return Settled(summary, ModelChi2(), "stopped at max_iterations");
  }

  // x = the optimum of the problem by Optimizer, from `start` or the current x, whichever has the
  // lower chi2. During a trial, `out_of_reach` tells whether it gave up on the trial's target.
  bool BatchSolve(const std::vector<Pose>& start, bool* out_of_reach) {
    ++counters.batch_solves;
    const int used = static_cast<int>(vertex_of_slot.size());
    const double chi2_now = ExactChi2();
    std::vector<Pose> poses(graph->num_vertices());
    for (int s = 0; s < used; ++s) poses[vertex_of_slot[s]] = x[s];
    poses[anchor] = anchor_pose;
    double chi2_start = 0.0;
    for (int e : edges) {
      const Edge<Pose>& edge = graph->edge(e);
      const Pose& from = edge.from == anchor ? anchor_pose : start[slot_of[edge.from]];
      const Pose& to = edge.to == anchor ? anchor_pose : start[slot_of[edge.to]];
      const Tangent r = RelativePoseResidual<Pose>(edge.measurement, from, to, nullptr, nullptr);
      chi2_start += r.dot(edge.information * r);
    }
    if (chi2_start < chi2_now) {
      for (int s = 0; s < used; ++s) poses[vertex_of_slot[s]] = start[s];
    }
    std::vector<char> active(graph->num_edges(), 0);
    for (int e : edges) active[e] = 1;
    Optimizer<Pose>& optimizer = trial_active ? trial_batch_optimizer : batch_optimizer;
    const double target =
        trial_active ? trial.target_chi2 : std::numeric_limits<double>::infinity();
    const OptimizerSummary summary = optimizer.Solve(*graph, active, &poses, target);
    if (!summary.IsSolutionUsable()) return false;
    *out_of_reach = summary.termination == TerminationType::kOutOfReach;
    for (int s = 0; s < used; ++s) x[s] = poses[vertex_of_slot[s]];
    return true;
  }

  IncrementalSummary& Settled(IncrementalSummary& summary,
                              double chi2,
                              const std::string& message) {
    summary.ok = true;
    summary.chi2 = chi2;
    summary.message = message;
    NoteSettled();
    return summary;
  }

  IncrementalSummary& Failed(IncrementalSummary& summary, const std::string& message) {
    summary.ok = false;
    summary.message = message;
    return summary;
  }

  void SetEdges(const std::vector<int>& new_edges) {
    ++structure_version;
    edges = new_edges;
    edge_position.assign(graph->num_edges(), -1);
    for (size_t k = 0; k < edges.size(); ++k) edge_position[edges[k]] = static_cast<int>(k);
    incident.assign(vertex_of_slot.size(), {});
    for (int e : edges) AddIncidence(e);
  }

  void AddIncidence(int e) {
    ++structure_version;
    const int a = SlotOf(graph->edge(e).from);
    const int c = SlotOf(graph->edge(e).to);
    if (a >= 0) incident[a].push_back(e);
    if (c >= 0 && c != a) incident[c].push_back(e);
  }

  void RemoveIncidence(int e) {
    ++structure_version;
    for (int v : {graph->edge(e).from, graph->edge(e).to}) {
      const int s = SlotOf(v);
      if (s < 0) continue;
      auto& list = incident[s];
      list.erase(std::remove(list.begin(), list.end(), e), list.end());
    }
  }

  void EnsureEdgeIndex() {
    if (static_cast<int>(edge_position.size()) < graph->num_edges()) {
      edge_position.resize(graph->num_edges(), -1);
    }
  }

  // ---- covariance (core/incremental_solver_covariance.cc) ---------------------------------

  // Y = L^-1 P B and D^-1, on the rows of the elimination-tree paths from the variables of
  // `query` (sorted, each once) to the root, where Y can be nonzero: B holds d rows per queried
  // pose (the anchor's are not read: it is fixed) and is zero on every other pose; nullptr: the
  // identity (a large cluster's would take tens of megabytes). The covariance of the queried
  // poses' variables is then Y' D^-1 Y (P A P' = L D L').
  void ForwardSolve(const std::vector<int>& query,
                    const Eigen::MatrixXd* B,
                    RowMajorMatrix* Y,
                    Eigen::VectorXd* inverse_d) const;
  std::vector<Eigen::MatrixXd> Covariances(const std::vector<std::vector<int>>& sets) const;
  std::vector<Eigen::MatrixXd> ProjectedCovariances(
      const std::vector<CovarianceProjection>& projections) const;

  const PoseGraph<Pose>* graph;
  IncrementalSolverOptions options;
  Counters counters;
  Optimizer<Pose> batch_optimizer;
  Optimizer<Pose> trial_batch_optimizer;  // at most options.trial_batch_max_iterations

  static OptimizerOptions TrialBatchOptions(const IncrementalSolverOptions& options) {
    OptimizerOptions batch;
    batch.max_iterations = options.trial_batch_max_iterations;
    return batch;
  }

  int anchor = -1;
  Pose anchor_pose;
  std::vector<int> vertices;               // in the problem, the anchor first
  std::vector<int> edges;                  // in the problem
  std::vector<int> edge_position;          // per graph edge: index in `edges`, or -1
  std::vector<int> slot_of;                // per graph vertex: its place, -1 (none, or the anchor)
  std::vector<int> vertex_of_slot;         // per place in use
  std::vector<std::vector<int>> incident;  // per place in use: the problem's edges touching it
  std::vector<Pose> x_lin;                 // per place: linearization point
  std::vector<Pose> x;                     // per place: estimate, x_lin (+) delta
  Eigen::VectorXd delta;                   // per scalar variable (original order)
  Eigen::VectorXd b;
  double chi2_lin = 0.0;                       // sum of r'Omega r at the linearization points
  mutable std::vector<Matrix> whitening;       // Whitening, per edge seen
  mutable std::vector<int> whitening_of_edge;  // per graph edge: its place there, or -1
  double settled_chi2_per_dof = 0.0;  // NoteSettled; 0: not known (every moved pose relinearized)

  int capacity = 0;  // places in the factor
  cholmod_common common;
  cholmod_factor* factor = nullptr;
  // The symbolic analysis of the structure (poses, free places and edges) of version
  // analyzed_version; structure_version counts the structure's changes.
  cholmod_factor* symbolic = nullptr;
  long structure_version = 0;
  long analyzed_version = -1;
  std::vector<int> position;  // per scalar variable: its row in the factor
  double nonzeros_after_build = 0.0;
  double rebuild_flops = 0.0;  // of the last factorization
  int modifications_since_check = 0;
  bool rebuild_due = false;
  int rebuilds_this_call = 0;
  cholmod_dense* solution = nullptr;
  cholmod_dense* work_y = nullptr;
  cholmod_dense* work_e = nullptr;
  mutable std::vector<char> mark;  // Covariance's workspace
  mutable std::vector<int> row_of;

  bool trial_active = false;
  Trial trial;
};

}  // namespace irrr

#endif  // IRRR_CORE_INCREMENTAL_SOLVER_IMPL_H_
