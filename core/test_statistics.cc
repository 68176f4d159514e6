#include "core/test_statistics.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <tuple>
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

namespace {

// r' S^-1 r and, when asked, tr(C S^-1) / rows with S = C + sign * J Sigma J'
// (LinearizeAddition: +1; LinearizeRemoval: -1). Each edge's rows of J are two d x d blocks (its
// end poses), so J Sigma J' is summed block by block: the dense product cost d^3 n m^2 and held
// most of the parking garage's time.
template <class Pose>
LinearizedAddition Linearize(const std::vector<const Edge<Pose>*>& edges,
                             const std::vector<Pose>& estimate,
                             const std::vector<int>& vertices,
                             const Eigen::MatrixXd& covariance,
                             double sign,
                             bool with_redundancy) {
  constexpr int d = Pose::kDim;
  using Block = typename Pose::Matrix;
  const int n = static_cast<int>(edges.size());
  const int m = static_cast<int>(vertices.size());
  IRRR_CHECK(covariance.rows() == d * m && covariance.cols() == d * m);
  auto column_of = [&vertices](int v) {
    const auto it = std::find(vertices.begin(), vertices.end(), v);
    IRRR_CHECK(it != vertices.end());
    return static_cast<int>(it - vertices.begin()) * d;
  };
  Eigen::VectorXd r(d * n);
  std::vector<std::array<int, 2>> columns(n);
  std::vector<std::array<Block, 2>> jacobians(n);
  Eigen::MatrixXd S = Eigen::MatrixXd::Zero(d * n, d * n);
  for (int k = 0; k < n; ++k) {
    const Edge<Pose>& edge = *edges[k];
    r.segment<d>(k * d) = RelativePoseResidual<Pose>(edge.measurement,
                                                     estimate[edge.from],
                                                     estimate[edge.to],
                                                     &jacobians[k][0],
                                                     &jacobians[k][1]);
    columns[k] = {column_of(edge.from), column_of(edge.to)};
    S.block<d, d>(k * d, k * d) = edge.information.inverse();
  }
  Eigen::MatrixXd C;
  if (with_redundancy) C = S;
  Eigen::Matrix<double, d, Eigen::Dynamic> J_sigma(d, d * m);  // J_k Sigma, edge k's rows
  for (int k = 0; k < n; ++k) {
    J_sigma.noalias() = jacobians[k][0] * covariance.middleRows<d>(columns[k][0]);
    J_sigma.noalias() += jacobians[k][1] * covariance.middleRows<d>(columns[k][1]);
    for (int l = 0; l < n; ++l) {
      Block block = J_sigma.template middleCols<d>(columns[l][0]) * jacobians[l][0].transpose();
      block.noalias() +=
          J_sigma.template middleCols<d>(columns[l][1]) * jacobians[l][1].transpose();
      S.block<d, d>(k * d, l * d) += sign * block;
    }
  }
  const Eigen::LLT<Eigen::MatrixXd> llt(0.5 * (S + S.transpose()));
  LinearizedAddition out;
  if (llt.info() != Eigen::Success) {
    out.chi2_increase = out.redundancy = std::numeric_limits<double>::quiet_NaN();
    return out;
  }
  out.chi2_increase = r.dot(llt.solve(r));
  if (with_redundancy) {
    out.redundancy = llt.solve(C).trace() / (d * n);  // tr(S^-1 C) = tr(C S^-1)
  }
  return out;
}

}  // namespace

template <class Pose>
LinearizedAddition LinearizeAddition(const std::vector<const Edge<Pose>*>& edges,
                                     const std::vector<Pose>& estimate,
                                     const std::vector<int>& vertices,
                                     const Eigen::MatrixXd& covariance) {
  return Linearize(edges, estimate, vertices, covariance, 1.0, true);
}

template <class Pose>
double LinearizeRemoval(const std::vector<const Edge<Pose>*>& edges,
                        const std::vector<Pose>& estimate,
                        const std::vector<int>& vertices,
                        const Eigen::MatrixXd& covariance) {
  return Linearize(edges, estimate, vertices, covariance, -1.0, false).chi2_increase;
}

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
