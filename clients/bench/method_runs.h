#ifndef IRRR_CLIENTS_BENCH_METHOD_RUNS_H_
#define IRRR_CLIENTS_BENCH_METHOD_RUNS_H_

// The accuracy benchmark's methods (iRRR, batch RRR, DCS, GNC) and one run of a method on a
// graph: timed, in a child process of its own, its decisions and map read back.

#include <string>
#include <vector>

#include "core/irrr.h"
#include "core/status.h"

namespace irrr {

// One algorithm configuration of the matrix.
enum class Algorithm {
  kIrrr,  // iRRR, Irrr driven step by step in arrival order
  kRrr,   // batch RRR (RunBatchRrr)
  kDcs,   // dynamic covariance scaling (core/robust_solve.h)
  kGnc,   // graduated non-convexity, truncated least squares (core/robust_solve.h)
};

struct Method {
  Algorithm algorithm = Algorithm::kIrrr;
  GraphDegreesOfFreedom dof = GraphDegreesOfFreedom::kResidualRows;
  bool paper_faithful = false;
  double alpha = 0.0;             // > 0: overrides the preset's
  double variance_factor = -1.0;  // >= 0: overrides the default (0: estimated)
  int step_budget = -1;           // >= 0: overrides the default (0: unbounded)

  bool IsRobustKernel() const {
    return algorithm == Algorithm::kDcs || algorithm == Algorithm::kGnc;
  }
};

std::string MethodName(const Method& m);
std::string DofName(GraphDegreesOfFreedom dof);
// "-" for the robust kernels, which count no degrees of freedom.
std::string DofName(const Method& m);
// "default" or "paper"; "-" for the robust kernels.
std::string VariantName(const Method& m);

// What one method's run leaves for the table: it runs in a child process (RunInChild), so that
// its peak memory is its own.
template <class Pose>
struct MethodRun {
  std::vector<char> accepted;        // per graph edge
  std::vector<int> odometry_faults;  // iRRR: the odometry edges it flags (Irrr::OdometryFaults)
  std::vector<Pose> estimate;        // per vertex
  double seconds = 0.0;
  double cpu_seconds = 0.0;
  int steps = -1;  // -1: not incremental
  int solves = 0;
  int capped_steps = 0;  // steps that reached IrrrOptions::step_budget
  std::vector<double> step_ms;
  long peak_rss_kb = 0;  // the child's maximum resident set size
  bool stopped = false;  // ran past RunInChild's limit_seconds and was stopped: no result
};

// Runs `method` on `graph` in a child process (child_process.h) and reads its result back, with
// the child's peak resident memory (what this process had loaded before the fork included). With
// `limit_seconds` > 0, a run still going after that long is stopped and marked so. `label` names
// the run in progress lines and errors.
template <class Pose>
Status RunInChild(const std::string& label,
                  const Method& method,
                  const PoseGraph<Pose>& graph,
                  double limit_seconds,
                  MethodRun<Pose>* run);

extern template Status RunInChild(
    const std::string&, const Method&, const PoseGraph<Pose2>&, double, MethodRun<Pose2>*);
extern template Status RunInChild(
    const std::string&, const Method&, const PoseGraph<Pose3>&, double, MethodRun<Pose3>*);

}  // namespace irrr

#endif  // IRRR_CLIENTS_BENCH_METHOD_RUNS_H_
