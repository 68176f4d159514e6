#include "core/test_statistics.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <tuple>
#include <utility>
#include <vector>

#include <Eigen/Cholesky>
#include <boost/math/distributions/chi_squared.hpp>
#include <boost/math/distributions/fisher_f.hpp>

namespace irrr {

namespace {

// The engine asks for the same few quantiles over and over (a handful of dof per step), and each
// is an inverse incomplete gamma or beta function: remembered per thread, at most 4096 of them,
// by (alpha, dof, the F distribution's second dof or -1 for chi-square).
template <class Compute>
double Remembered(double alpha, double dof, double dof2, Compute compute) {
  constexpr size_t kCached = 4096;
  thread_local std::map<std::tuple<double, double, double>, double> cache;
  const auto key = std::make_tuple(alpha, dof, dof2);
  auto it = cache.find(key);
  if (it == cache.end()) {
    if (cache.size() >= kCached) cache.clear();
    it = cache.emplace(key, compute()).first;
  }
  return it->second;
}

}  // namespace

double ChiSquareQuantile(double alpha, double dof) {
  return Remembered(alpha, dof, -1.0, [&] {
    return boost::math::quantile(boost::math::chi_squared(dof), alpha);
  });
}

double ChiSquareMedian(double dof) { return ChiSquareQuantile(0.5, dof); }

double ScaledChiSquareThreshold(double alpha, double dof, double variance, double variance_dof) {
  if (!std::isfinite(variance_dof)) return variance * ChiSquareQuantile(alpha, dof);
  return variance * dof * Remembered(alpha, dof, variance_dof, [&] {
           return boost::math::quantile(boost::math::fisher_f(dof, variance_dof), alpha);
         });
}

double RobustVarianceFactor(const std::vector<RedundancySample>& samples) {
  std::vector<std::pair<double, double>> ratios;  // (chi2 / median, dof)
  double total = 0.0;
  for (const RedundancySample& s : samples) {
    if (s.dof > 0.0 && std::isfinite(s.chi2)) {
      ratios.push_back({s.chi2 / ChiSquareMedian(s.dof), s.dof});
      total += s.dof;
    }
  }
  if (ratios.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::sort(ratios.begin(), ratios.end());
  // The weighted median: the ratio at which half the degrees of freedom lie below, halfway
  // between two samples where the half falls exactly between them.
  double below = 0.0;
  for (size_t k = 0; k < ratios.size(); ++k) {
    below += ratios[k].second;
    if (below > 0.5 * total) return ratios[k].first;
    if (below == 0.5 * total) return 0.5 * (ratios[k].first + ratios[k + 1].first);
  }
  return ratios.back().first;
}

template <class Pose>
StackedEdges<Pose> StackEdges(const std::vector<const Edge<Pose>*>& edges,
                              const std::vector<Pose>& estimate,
                              const std::vector<int>& vertices,
                              const std::vector<Pose>* linearization) {
  constexpr int d = Pose::kDim;
  const int n = static_cast<int>(edges.size());
  auto column_of = [&vertices](int v) {
    const auto it = std::find(vertices.begin(), vertices.end(), v);
    IRRR_CHECK(it != vertices.end());
    return static_cast<int>(it - vertices.begin()) * d;
  };
  StackedEdges<Pose> out;
  out.vertices = static_cast<int>(vertices.size());
  out.r.resize(d * n);
  out.C.resize(n);
  out.jacobians.resize(n);
  out.columns.resize(n);
  for (int k = 0; k < n; ++k) {
    const Edge<Pose>& edge = *edges[k];
    typename Pose::Matrix* J_from = &out.jacobians[k][0];
    typename Pose::Matrix* J_to = &out.jacobians[k][1];
    if (linearization != nullptr) {
      RelativePoseResidual<Pose>(
          edge.measurement, (*linearization)[edge.from], (*linearization)[edge.to], J_from, J_to);
      J_from = J_to = nullptr;
    }
    out.r.template segment<d>(k * d) = RelativePoseResidual<Pose>(
        edge.measurement, estimate[edge.from], estimate[edge.to], J_from, J_to);
    out.columns[k] = {column_of(edge.from), column_of(edge.to)};
    out.C[k] = edge.information.inverse();
  }
  return out;
}

template <class Pose>
Eigen::MatrixXd StackedEdges<Pose>::TransposedJacobian() const {
  constexpr int d = Pose::kDim;
  const int n = static_cast<int>(jacobians.size());
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(d * vertices, d * n);
  for (int k = 0; k < n; ++k) {
    A.template block<d, d>(columns[k][0], k * d) += jacobians[k][0].transpose();
    A.template block<d, d>(columns[k][1], k * d) += jacobians[k][1].transpose();
  }
  return A;
}

// Each edge's rows of J are two d x d blocks (its end poses), so J Sigma J' is summed block by
// block: the dense product cost d^3 n m^2 and held most of the parking garage's time.
template <class Pose>
Eigen::MatrixXd ProjectCovariance(const StackedEdges<Pose>& stack,
                                  const Eigen::MatrixXd& covariance) {
  constexpr int d = Pose::kDim;
  using Block = typename Pose::Matrix;
  const int n = static_cast<int>(stack.jacobians.size());
  const int m = stack.vertices;
  IRRR_CHECK(covariance.rows() == d * m && covariance.cols() == d * m);
  const auto& jacobians = stack.jacobians;
  const auto& columns = stack.columns;
  Eigen::MatrixXd out = Eigen::MatrixXd::Zero(d * n, d * n);
  Eigen::Matrix<double, d, Eigen::Dynamic> J_sigma(d, d * m);  // J_k Sigma, edge k's rows
  for (int k = 0; k < n; ++k) {
    J_sigma.noalias() = jacobians[k][0] * covariance.middleRows<d>(columns[k][0]);
    J_sigma.noalias() += jacobians[k][1] * covariance.middleRows<d>(columns[k][1]);
    for (int l = 0; l < n; ++l) {
      Block block = J_sigma.template middleCols<d>(columns[l][0]) * jacobians[l][0].transpose();
      block.noalias() +=
          J_sigma.template middleCols<d>(columns[l][1]) * jacobians[l][1].transpose();
      out.block<d, d>(k * d, l * d) = block;
    }
  }
  return out;
}

namespace {

// r' S^-1 r and, when asked, tr(C S^-1) / rows with S = C + sign * J Sigma J'
// (LinearizeAddition: +1; LinearizeRemoval: -1).
template <class Pose>
LinearizedAddition Statistic(const StackedEdges<Pose>& stack,
                             Eigen::MatrixXd projected,
                             double sign,
                             bool with_redundancy) {
  constexpr int d = Pose::kDim;
  const int rows = static_cast<int>(stack.r.size());
  IRRR_CHECK(projected.rows() == rows && projected.cols() == rows);
  // S in place of J Sigma J' (a large cluster's are tens of megabytes).
  Eigen::MatrixXd& S = projected;
  S *= sign;
  for (size_t k = 0; k < stack.C.size(); ++k) S.block<d, d>(k * d, k * d) += stack.C[k];
  const Eigen::LLT<Eigen::MatrixXd> llt(0.5 * (S + S.transpose()));
  LinearizedAddition out;
  if (llt.info() != Eigen::Success) {
    out.chi2_increase = out.redundancy = std::numeric_limits<double>::quiet_NaN();
    return out;
  }
  out.chi2_increase = stack.r.dot(llt.solve(stack.r));
  if (with_redundancy) {
    Eigen::MatrixXd C = Eigen::MatrixXd::Zero(rows, rows);
    for (size_t k = 0; k < stack.C.size(); ++k) C.block<d, d>(k * d, k * d) = stack.C[k];
    out.redundancy = llt.solve(C).trace() / rows;  // tr(S^-1 C) = tr(C S^-1)
  }
  return out;
}

}  // namespace

template <class Pose>
LinearizedAddition AdditionStatistic(const StackedEdges<Pose>& stack, Eigen::MatrixXd projected) {
  return Statistic(stack, std::move(projected), 1.0, true);
}

template <class Pose>
double RemovalStatistic(const StackedEdges<Pose>& stack, Eigen::MatrixXd projected) {
  return Statistic(stack, std::move(projected), -1.0, false).chi2_increase;
}

template <class Pose>
LinearizedAddition LinearizeAddition(const std::vector<const Edge<Pose>*>& edges,
                                     const std::vector<Pose>& estimate,
                                     const std::vector<int>& vertices,
                                     const Eigen::MatrixXd& covariance) {
  const StackedEdges<Pose> stack = StackEdges(edges, estimate, vertices);
  return AdditionStatistic(stack, ProjectCovariance(stack, covariance));
}

template <class Pose>
double LinearizeRemoval(const std::vector<const Edge<Pose>*>& edges,
                        const std::vector<Pose>& estimate,
                        const std::vector<int>& vertices,
                        const Eigen::MatrixXd& covariance) {
  const StackedEdges<Pose> stack = StackEdges(edges, estimate, vertices);
  return RemovalStatistic(stack, ProjectCovariance(stack, covariance));
}

#define IRRR_INSTANTIATE_STACKED(Pose)                                                             \
  template struct StackedEdges<Pose>;                                                              \
  template StackedEdges<Pose> StackEdges<Pose>(const std::vector<const Edge<Pose>*>&,              \
                                               const std::vector<Pose>&,                           \
                                               const std::vector<int>&,                            \
                                               const std::vector<Pose>*);                          \
  template Eigen::MatrixXd ProjectCovariance<Pose>(const StackedEdges<Pose>&,                      \
                                                   const Eigen::MatrixXd&);                        \
  template LinearizedAddition AdditionStatistic<Pose>(const StackedEdges<Pose>&, Eigen::MatrixXd); \
  template double RemovalStatistic<Pose>(const StackedEdges<Pose>&, Eigen::MatrixXd);
IRRR_INSTANTIATE_STACKED(Pose2)
IRRR_INSTANTIATE_STACKED(Pose3)
#undef IRRR_INSTANTIATE_STACKED

template LinearizedAddition LinearizeAddition<Pose2>(const std::vector<const Edge<Pose2>*>&,
                                                     const std::vector<Pose2>&,
                                                     const std::vector<int>&,
                                                     const Eigen::MatrixXd&);
template LinearizedAddition LinearizeAddition<Pose3>(const std::vector<const Edge<Pose3>*>&,
                                                     const std::vector<Pose3>&,
                                                     const std::vector<int>&,
                                                     const Eigen::MatrixXd&);

template double LinearizeRemoval<Pose2>(const std::vector<const Edge<Pose2>*>&,
                                        const std::vector<Pose2>&,
                                        const std::vector<int>&,
                                        const Eigen::MatrixXd&);
template double LinearizeRemoval<Pose3>(const std::vector<const Edge<Pose3>*>&,
                                        const std::vector<Pose3>&,
                                        const std::vector<int>&,
                                        const Eigen::MatrixXd&);

}  // namespace irrr
