// IncrementalSolver's marginal covariances and their projections, read from its factor
// (core/incremental_solver.h): sparse solves along the elimination tree.
#include <algorithm>
#include <vector>

#include "core/incremental_solver.h"
#include "core/incremental_solver_impl.h"

namespace irrr {
namespace {

std::vector<int> SortedUnique(std::vector<int> vertices) {
  std::sort(vertices.begin(), vertices.end());
  vertices.erase(std::unique(vertices.begin(), vertices.end()), vertices.end());
  return vertices;
}

// ForwardSolve reads the marks across a range of columns up to this many times the union's size
// rather than sorting it (a byte read against a comparison sort's several per element).
constexpr int kMarkScanRatio = 16;

int IndexIn(const std::vector<int>& query, int vertex) {
  return static_cast<int>(std::lower_bound(query.begin(), query.end(), vertex) - query.begin());
}

}  // namespace

template <class Pose>
void IncrementalSolver<Pose>::Impl::ForwardSolve(const std::vector<int>& query,
                                                 const Eigen::MatrixXd* B,
                                                 RowMajorMatrix* Y,
                                                 Eigen::VectorXd* inverse_d) const {
  const int m = static_cast<int>(query.size());
  const int* Lp = static_cast<const int*>(factor->p);
  const int* Li = static_cast<const int*>(factor->i);
  const int* Lnz = static_cast<const int*>(factor->nz);
  const double* Lx = static_cast<const double*>(factor->x);
  // The union of the paths, in ascending (topological) order.
  std::vector<int> columns;
  std::vector<int> starts(d * m, -1);
  for (int k = 0; k < m; ++k) {
    const int s = SlotOf(query[k]);
    IRRR_CHECK(s >= 0 || query[k] == anchor);
    if (s < 0) continue;
    for (int a = 0; a < d; ++a) starts[k * d + a] = position[s * d + a];
  }
  mark.resize(factor->n, 0);
  int lowest = factor->n;
  int highest = -1;
  for (int start : starts) {
    for (int j = start; j >= 0 && !mark[j];) {
      mark[j] = 1;
      columns.push_back(j);
      lowest = std::min(lowest, j);
      highest = std::max(highest, j);
      j = Lnz[j] > 1 ? Li[Lp[j] + 1] : -1;
    }
  }
  // A path climbs to ever higher columns, so the union lies between its lowest start and its
  // highest column. Where that range is not much longer than the union (odometry chains make
  // both about the factor's size), reading the marks across it is cheaper than sorting: on a
  // 100 000-pose fleet the sort took half the covariances' time.
  if (highest - lowest + 1 <= kMarkScanRatio * static_cast<int>(columns.size())) {
    columns.clear();
    for (int j = lowest; j <= highest; ++j) {
      if (mark[j]) columns.push_back(j);
    }
  } else {
    std::sort(columns.begin(), columns.end());
  }
  row_of.resize(factor->n, -1);
  for (size_t k = 0; k < columns.size(); ++k) row_of[columns[k]] = static_cast<int>(k);
  *Y = RowMajorMatrix::Zero(columns.size(), B != nullptr ? B->cols() : d * m);
  for (int r = 0; r < d * m; ++r) {
    if (starts[r] < 0) continue;
    if (B != nullptr) {
      Y->row(row_of[starts[r]]) = B->row(r);
    } else {
      (*Y)(row_of[starts[r]], r) = 1.0;
    }
  }
  inverse_d->resize(columns.size());
  for (size_t k = 0; k < columns.size(); ++k) {
    const int j = columns[k];
    const int p = Lp[j];
    (*inverse_d)(k) = 1.0 / Lx[p];
    const auto yj = Y->row(k);
    for (int q = p + 1; q < p + Lnz[j]; ++q) Y->row(row_of[Li[q]]) -= Lx[q] * yj;
  }
  for (int j : columns) {
    mark[j] = 0;
    row_of[j] = -1;
  }
}

template <class Pose>
std::vector<Eigen::MatrixXd> IncrementalSolver<Pose>::Impl::Covariances(
    const std::vector<std::vector<int>>& sets) const {
  std::vector<int> all;
  for (const std::vector<int>& set : sets) all.insert(all.end(), set.begin(), set.end());
  const std::vector<int> query = SortedUnique(std::move(all));
  RowMajorMatrix Y;
  Eigen::VectorXd inverse_d;
  ForwardSolve(query, nullptr, &Y, &inverse_d);
  // A set's covariance is Y_set' D^-1 Y_set, with Y_set its poses' columns of Y.
  std::vector<Eigen::MatrixXd> covariances;
  for (const std::vector<int>& set : sets) {
    const int n = static_cast<int>(set.size());
    Eigen::MatrixXd Y_set(Y.rows(), d * n);
    for (int k = 0; k < n; ++k) {
      Y_set.middleCols(k * d, d) = Y.middleCols(IndexIn(query, set[k]) * d, d);
    }
    covariances.push_back(Y_set.transpose() * inverse_d.asDiagonal() * Y_set);
  }
  return covariances;
}

template <class Pose>
std::vector<Eigen::MatrixXd> IncrementalSolver<Pose>::Impl::ProjectedCovariances(
    const std::vector<CovarianceProjection>& projections) const {
  std::vector<int> all;
  for (const CovarianceProjection& p : projections) {
    all.insert(all.end(), p.vertices.begin(), p.vertices.end());
  }
  const std::vector<int> query = SortedUnique(std::move(all));
  // B: each projection's A in its own columns, on its poses' rows.
  std::vector<int> first_column(projections.size() + 1, 0);
  for (size_t g = 0; g < projections.size(); ++g) {
    const CovarianceProjection& p = projections[g];
    IRRR_CHECK(p.A.rows() == d * static_cast<int>(p.vertices.size()));
    first_column[g + 1] = first_column[g] + static_cast<int>(p.A.cols());
  }
  Eigen::MatrixXd B = Eigen::MatrixXd::Zero(d * query.size(), first_column.back());
  for (size_t g = 0; g < projections.size(); ++g) {
    const CovarianceProjection& p = projections[g];
    for (size_t k = 0; k < p.vertices.size(); ++k) {
      B.block(IndexIn(query, p.vertices[k]) * d, first_column[g], d, p.A.cols()) +=
          p.A.middleRows(k * d, d);
    }
  }
  RowMajorMatrix Y;
  Eigen::VectorXd inverse_d;
  ForwardSolve(query, &B, &Y, &inverse_d);
  std::vector<Eigen::MatrixXd> out;
  for (size_t g = 0; g < projections.size(); ++g) {
    const auto Y_g = Y.middleCols(first_column[g], first_column[g + 1] - first_column[g]);
    out.push_back(Y_g.transpose() * inverse_d.asDiagonal() * Y_g);
  }
  return out;
}

#define IRRR_INSTANTIATE_COVARIANCE(Pose)                                                        \
  template void IncrementalSolver<Pose>::Impl::ForwardSolve(                                     \
      const std::vector<int>&, const Eigen::MatrixXd*, RowMajorMatrix*, Eigen::VectorXd*) const; \
  template std::vector<Eigen::MatrixXd> IncrementalSolver<Pose>::Impl::Covariances(              \
      const std::vector<std::vector<int>>&) const;                                               \
  template std::vector<Eigen::MatrixXd> IncrementalSolver<Pose>::Impl::ProjectedCovariances(     \
      const std::vector<CovarianceProjection>&) const;
IRRR_INSTANTIATE_COVARIANCE(Pose2)
IRRR_INSTANTIATE_COVARIANCE(Pose3)
#undef IRRR_INSTANTIATE_COVARIANCE

}  // namespace irrr
