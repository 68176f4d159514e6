#ifndef IRRR_CORE_TEST_STATISTICS_H_
#define IRRR_CORE_TEST_STATISTICS_H_

// The statistics iRRR's tests compare with chi-square quantiles (algorithm-notes, "Tests" and
// "Beyond the paper"):
//  - chi-square quantiles and medians (Boost.Math);
//  - the variance factor of the information matrices, estimated from the data's redundancy: how
//    many times larger the residuals' real covariance is than the information matrices claim
//    (1: as given). Public datasets are often far off (Manhattan about 0.02, so every test with
//    the information as given is 50 times too lenient);
//  - the linearized chi2 increase of a set of links at an optimum: their residuals against
//    S = J Sigma J' + Omega^-1, with Sigma the marginal covariance of their end poses. On a
//    linear-Gaussian problem it equals the chi2 increase of the optimum exactly; on a pose graph
//    it costs a few sparse solves instead of a nonlinear optimization.

#include <array>
#include <limits>
#include <vector>

#include <Eigen/Core>

#include "core/pose_graph.h"

namespace irrr {

// The value below which a chi-square variable with `dof` degrees of freedom falls with
// probability `alpha`.
double ChiSquareQuantile(double alpha, double dof);
// Its median (ChiSquareQuantile(0.5, dof)).
double ChiSquareMedian(double dof);

// The threshold of a test whose statistic is a chi2 over `dof` degrees of freedom divided by an
// estimated variance factor: variance * dof * F(alpha; dof, variance_dof), the F distribution's
// quantile, when the factor is known with `variance_dof` degrees of freedom; variance *
// ChiSquareQuantile(alpha, dof) when it is known exactly (variance_dof infinite). The F quantile
// allows for the factor's own uncertainty, which dominates for large dof: a cluster of 600 links
// has a chi2 quantile only 10% above its mean, less than the factor varies along a trajectory.
double ScaledChiSquareThreshold(double alpha, double dof, double variance, double variance_dof);

// The thresholds of one set of tests: chi-square quantiles at confidence `alpha`, scaled by the
// variance factor `variance` known with `variance_dof` degrees of freedom (infinite: exactly, as
// the paper's tests with the information as given).
struct TestThresholds {
  double alpha = 0.95;
  double variance = 1.0;
  double variance_dof = std::numeric_limits<double>::infinity();

  // The threshold of a statistic with `dof` degrees of freedom.
  double Of(double dof) const {
    return ScaledChiSquareThreshold(alpha, dof, variance, variance_dof);
  }
};

// One piece of redundancy: a chi2 at an optimum and its degrees of freedom (residual rows minus
// free parameters). Under a variance factor s, chi2 ~ s * chi-square(dof).
struct RedundancySample {
  double chi2 = 0.0;
  double dof = 0.0;
};

// The estimate of s from redundancy (NaN when there is none): the median of
// chi2 / ChiSquareMedian(dof) over the samples, each weighted by its dof, so that samples holding
// less than half the redundancy (wrong links clustered by chance) cannot set it.
double RobustVarianceFactor(const std::vector<RedundancySample>& samples);

// Adding `edges` to a least-squares problem whose optimum is `estimate`, to first order: r the
// stacked residuals at `estimate`, J their Jacobians with respect to the poses `vertices`, Sigma
// those poses' joint covariance (d*m x d*m in the order of `vertices`, as Optimizer::Covariance
// returns it), C = blockdiag(Omega^-1) and S = J Sigma J' + C. Every endpoint of `edges` must be
// in `vertices`. The information is taken as given: divide chi2_increase by a variance factor to
// test.
struct LinearizedAddition {
  // r' S^-1 r: the chi2 increase (NaN when S is not positive definite).
  double chi2_increase = 0.0;
  // tr(C S^-1) / rows: the links' mean redundancy number (Baarda's reliability). 1 when the
  // problem knows their end poses exactly, so that all of an error shows in the residual; towards
  // 0 when it knows them far worse than the links measure them, so that the poses absorb an error
  // and no test can see it. NaN when S is not positive definite.
  double redundancy = 0.0;
};
template <class Pose>
LinearizedAddition LinearizeAddition(const std::vector<const Edge<Pose>*>& edges,
                                     const std::vector<Pose>& estimate,
                                     const std::vector<int>& vertices,
                                     const Eigen::MatrixXd& covariance);

// The same statistics in two steps, for a caller that gets J Sigma J' some other way (from a
// factorization, without Sigma itself: IncrementalSolver::ProjectedCovariances with A = J'):
// the edges stacked at `estimate` (their residuals, C's blocks and Jacobians, against
// `vertices`), then the statistic from J Sigma J'. Given `linearization`, the Jacobians are taken
// there instead: the points a factorization's H was linearized at, in whose tangent its Sigma is.
// Only with J and H at the same points is C - J Sigma J' of a removal positive definite.
template <class Pose>
struct StackedEdges {
  Eigen::VectorXd r;                                            // d*n
  std::vector<typename Pose::Matrix> C;                         // per edge: Omega^-1
  std::vector<std::array<typename Pose::Matrix, 2>> jacobians;  // per edge: from, to
  std::vector<std::array<int, 2>> columns;  // per edge: its end poses' first columns in Sigma
  int vertices = 0;                         // m

  // J' (d*m x d*n), dense.
  Eigen::MatrixXd TransposedJacobian() const;
};
template <class Pose>
StackedEdges<Pose> StackEdges(const std::vector<const Edge<Pose>*>& edges,
                              const std::vector<Pose>& estimate,
                              const std::vector<int>& vertices,
                              const std::vector<Pose>* linearization = nullptr);
// J Sigma J' from Sigma (d*m x d*m).
template <class Pose>
Eigen::MatrixXd ProjectCovariance(const StackedEdges<Pose>& stack,
                                  const Eigen::MatrixXd& covariance);
// LinearizeAddition and LinearizeRemoval from J Sigma J' (`projected`, d*n x d*n; its storage
// serves for S).
template <class Pose>
LinearizedAddition AdditionStatistic(const StackedEdges<Pose>& stack, Eigen::MatrixXd projected);
template <class Pose>
double RemovalStatistic(const StackedEdges<Pose>& stack, Eigen::MatrixXd projected);

// Removing `edges` from a least-squares problem whose optimum with them is `estimate`, to first
// order: r' S^-1 r with S = C - J Sigma J', Sigma the poses' covariance with the edges in. The
// chi2 the optimum loses without them (exact on a linear-Gaussian problem): Baarda's w-test of
// a group of observations. A group the rest of the problem checks poorly has a small residual
// and a small S: its error shows in the other edges, and this statistic finds it there. NaN when
// S is not positive definite (the edges alone determine a pose).
template <class Pose>
double LinearizeRemoval(const std::vector<const Edge<Pose>*>& edges,
                        const std::vector<Pose>& estimate,
                        const std::vector<int>& vertices,
                        const Eigen::MatrixXd& covariance);

}  // namespace irrr

#endif  // IRRR_CORE_TEST_STATISTICS_H_
