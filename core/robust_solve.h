#ifndef IRRR_CORE_ROBUST_SOLVE_H_
#define IRRR_CORE_ROBUST_SOLVE_H_

// The field's robust-kernel baselines, on the project's optimizer, for comparison with iRRR.
// Odometry is a known inlier (weight 1); each loop hypothesis e gets a weight w_e in [0, 1] that
// scales its information, found by iteratively reweighted least squares (IRLS):
//
//  - Dynamic covariance scaling (Agarwal, Tipaldi, Spinello, Stachniss, Burgard, ICRA 2013):
//    a loop's scale s = min(1, 2 Phi / (Phi + d^2)) at the current estimate, its information
//    scaled by s^2 (eq. 15 of the paper, as g2o's RobustKernelDCS applies it), one Gauss-Newton
//    step per reweighting, from the estimate given. A loop counts as accepted when its final
//    s > 0.5, that is d^2 < 3 Phi.
//  - Graduated non-convexity with a truncated least squares cost (Yang, Antonante, Tzoumas,
//    Carlone, RA-L 2020, eq. 11-14 and Remark 5), run as GTSAM's GncOptimizer runs it: set
//    mu = c^2 / (2 max d^2 - c^2) with d^2 at the dead reckoning; solve with every weight 1;
//    then repeat { w_e = 1 if d^2 <= mu/(mu+1) c^2, 0 if d^2 >= (mu+1)/mu c^2, else
//    c sqrt(mu (mu+1) / d^2) - mu, d^2 at the last solution; solve with those weights from the
//    dead reckoning; mu *= mu_step } until every weight is within weight_tolerance of 0 or 1 or
//    the weighted cost stops changing. c^2 is the chi-square quantile of inlier_probability over
//    the pose's dimension. A loop counts as accepted when its final weight is above 0.5.
//
// d^2 = r' Omega r is the loop's chi2 with the information as given (no variance factor: as the
// published methods, the kernels read the front end's information at face value).

#include <string>
#include <vector>

#include "core/pose_graph.h"
#include "core/status.h"

namespace irrr {

enum class RobustKernel { kDcs, kGncTls };

// "dcs", "gnc".
const char* RobustKernelName(RobustKernel kernel);

struct RobustOptions {
  RobustKernel kernel = RobustKernel::kDcs;
  // DCS: Phi, the d^2 scale of the kernel (the paper's default 1).
  double dcs_phi = 1.0;
  // DCS: > 0, odometry is weighed too, with this Phi (its scale at the end in `weight`); 0:
  // odometry is a known inlier.
  double dcs_odometry_phi = 0.0;
  // DCS: reweighted Gauss-Newton steps (g2o's usual 30); fewer when the robust cost stops falling
  // by more than function_tolerance of itself.
  int dcs_iterations = 30;
  double function_tolerance = 1e-9;
  // GNC-TLS: c^2 = ChiSquareQuantile(inlier_probability, Pose::kDim) bounds an inlier's d^2.
  double inlier_probability = 0.99;
  // GNC-TLS: mu's growth per outer iteration (the paper's 1.4), and the outer iteration limit.
  double gnc_mu_step = 1.4;
  int gnc_max_outer_iterations = 100;
  // GNC-TLS: converged when every weight is within this of 0 or 1, or when the weighted cost
  // changes by less than gnc_cost_tolerance of itself (GTSAM's defaults).
  double gnc_weight_tolerance = 1e-4;
  double gnc_cost_tolerance = 1e-5;
  // GNC-TLS: Levenberg-Marquardt iterations of each weighted solve at most.
  int gnc_inner_iterations = 100;

  // Ok, or a sentence naming the first option out of range.
  Status Validate() const;
};

template <class Pose>
struct RobustResult {
  std::vector<Pose> estimate;  // per vertex
  // Per graph edge: 1 for odometry; for a loop, its weight (GNC) or scale s (DCS) at the end.
  std::vector<double> weight;
  // Per graph edge: d^2 at the final estimate, and the d^2 at which the loop's weight would be
  // 0.5 (3 Phi for DCS; for GNC, at the final mu): accepted exactly when weight > 0.5.
  std::vector<double> edge_chi2;
  std::vector<double> threshold;
  int outer_iterations = 0;   // reweightings
  int solver_iterations = 0;  // linear solves in all
  bool converged = false;
  std::string message;

  bool Accepted(int edge) const { return weight[edge] > 0.5; }
};

// Runs the kernel of `options` over every edge of `graph` from `initial_estimate` (DCS; GNC
// starts from the dead reckoning, as the paper's experiments). Fails (result untouched) on
// invalid options, an estimate of the wrong size, or a linear solver failure.
template <class Pose>
Status RobustSolve(const PoseGraph<Pose>& graph,
                   const RobustOptions& options,
                   const std::vector<Pose>& initial_estimate,
                   RobustResult<Pose>* result);

}  // namespace irrr

#endif  // IRRR_CORE_ROBUST_SOLVE_H_
