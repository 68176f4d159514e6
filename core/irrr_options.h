#ifndef IRRR_CORE_IRRR_OPTIONS_H_
#define IRRR_CORE_IRRR_OPTIONS_H_

// iRRR's options and what one step reports (core/irrr.h runs the steps).

#include <cmath>
#include <vector>

#include "core/optimizer.h"
#include "core/status.h"

namespace irrr {

// Degrees of freedom of the paper engine's graph test D_G^2 < chi2(alpha, d_G) (the warm engine
// always counts them exactly).
enum class GraphDegreesOfFreedom {
  kResidualRows,  // reference code: Pose::kDim x active edges
  kExact,         // residual rows minus free state dimensions
};

// Which decision engine judges the clusters.
enum class IrrrEngine {
  // The default: every check on the component's good-set optimum, kept up to date incrementally,
  // a linearized screen before any nonlinear solve, every threshold scaled by the estimated
  // variance factor (core/warm_engine.h).
  kWarm,
  // The paper's Algorithms 1-3 as written, every check from dead reckoning, as the reference code
  // (core/paper_engine.h): for comparison.
  kPaper,
};

const char* IrrrEngineName(IrrrEngine engine);

struct IrrrOptions {
  IrrrEngine engine = IrrrEngine::kWarm;
  // Confidence of every chi-square test, in (0, 1). 0.999 by default: with the variance factor
  // estimated, a true cluster fails a test at 0.95 one time in twenty (a recall of about 0.7 on
  // Manhattan), while wrong ones stand far above either threshold. The paper engine: 0.95.
  double alpha = 0.999;
  // Warm engine: the variance factor of the information matrices (the residuals' real covariance
  // over the one the information claims). 0: estimated from the data's redundancy, used within
  // [1e-6, 1]; a positive value fixes it (1: trust the information as given).
  double variance_factor = 0.0;
  double cluster_gap = 50.0;  // t_g of eq. (6), in stamp units (poses for files, seconds live)
  // Beyond the paper: a cluster closes at the latest when its later side spans this many cluster
  // gaps (LoopClusterer's max_span), so that a place revisited without pause is judged in pieces
  // as it goes, not once at the end. 0: unbounded (the paper).
  double cluster_span = 4.0;
  // Warm engine: conflicts between good clusters and refused ones are settled by a robust solve
  // of their component, confirmed by the joint tests (core/warm_arbiter.cc).
  bool arbiter = true;
  // Warm engine: the decision work one step may do, in nonlinear solves (local problems, trials
  // and rebuilds of the good set). Once a step has used it, the clusters not judged yet, the held
  // clusters due to be judged again and the challenges due wait for later steps (Irrr's
  // HasPendingStep stays true until they are done); a step always does at least one of them.
  // 0: unbounded (each step settles all it finds).
  int step_budget = 0;
  GraphDegreesOfFreedom graph_dof = GraphDegreesOfFreedom::kResidualRows;  // paper engine
  OptimizerOptions optimizer;  // Algorithm 1's optimizations, and all of the paper engine's

  // The paper's tests as written: the paper engine at alpha 0.95.
  static IrrrOptions PaperFaithful();

  Status Validate() const;
};

struct StepResult {
  int step = -1;
  int cluster = -1;                // the cluster that triggered it (-1: clusters that waited)
  std::vector<int> changed_loops;  // graph edge indices whose decision changed
  std::vector<int> sessions;       // sessions whose estimate was recomputed
  int solves = 0;                  // nonlinear optimizations run (local problems and trials)
  int iterations = 0;              // their Gauss-Newton iterations (a linear solve each)
  double chi2 = 0.0;               // of the good set of the sessions the step touched, at the end
  double variance_factor = 1.0;    // the variance factor the step's tests used
  double variance_estimate = 1.0;  // the one the data gave (warm engine; tests: within [1e-6, 1])
  int reversals = 0;               // good clusters reversed by later evidence
  int arbitrations = 0;            // robust solves asked which side of a conflict the map supports
  // Warm engine, with a step budget: whether this step stopped at it, and the decision work it
  // left for later steps (clusters not judged yet, held clusters due to be judged again,
  // good clusters whose challenge is due).
  bool capped = false;
  int deferred = 0;

  // Whether the tests used another factor than the data's estimate: the estimate was bounded to
  // [1e-6, 1], or irrr.variance_factor fixed the factor.
  bool VarianceEstimateDiffers() const {
    return std::abs(variance_estimate - variance_factor) > 1e-6 * variance_factor;
  }
};

}  // namespace irrr

#endif  // IRRR_CORE_IRRR_OPTIONS_H_
