#include "clients/bench/method_runs.h"

#include <time.h>

#include <chrono>

#include <fmt/core.h>

#include "clients/bench/child_process.h"
#include "clients/common/graph_files.h"
#include "clients/common/progress_line.h"
#include "core/robust_solve.h"

namespace irrr {

std::string MethodName(const Method& m) {
  switch (m.algorithm) {
    case Algorithm::kIrrr:
      return "irrr";
    case Algorithm::kRrr:
      return "rrr";
    case Algorithm::kDcs:
      return "dcs";
    case Algorithm::kGnc:
      return "gnc";
  }
  return "unknown";
}
std::string DofName(GraphDegreesOfFreedom dof) {
  return dof == GraphDegreesOfFreedom::kResidualRows ? "residual_rows" : "exact";
}
std::string DofName(const Method& m) { return m.IsRobustKernel() ? "-" : DofName(m.dof); }
std::string VariantName(const Method& m) {
  if (m.IsRobustKernel()) return "-";
  return m.paper_faithful ? "paper" : "default";
}

IrrrOptions OptionsFor(const Method& m) {
  IrrrOptions options = m.paper_faithful ? IrrrOptions::PaperFaithful() : IrrrOptions();
  options.graph_dof = m.dof;
  if (m.alpha > 0.0) options.alpha = m.alpha;
  if (m.variance_factor >= 0.0) options.variance_factor = m.variance_factor;
  if (m.step_budget >= 0) options.step_budget = m.step_budget;
  return options;
}

namespace {

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

double ProcessCpuSeconds() {
  timespec now{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &now);
  return static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec);
}

struct RunResult {
  std::vector<LoopDecision> decisions;
  double seconds = 0.0;
  double cpu_seconds = 0.0;  // of this process: tells a loaded machine from a slow algorithm
  int steps = -1;            // -1: batch
  int solves = 0;
  int capped_steps = 0;  // steps that reached IrrrOptions::step_budget
  std::vector<double> step_ms;
  std::vector<int> odometry_faults;
};

// What RunIncrementalIrrr does, with every RunStep timed. Long runs report their progress on
// stderr: a progress line on a terminal, otherwise a line every kProgressSeconds.
template <class Pose>
RunResult RunIncrementalTimed(const std::string& label,
                              const PoseGraph<Pose>& graph,
                              const IrrrOptions& options,
                              std::vector<Pose>* estimate) {
  constexpr double kProgressSeconds = 30.0;
  RunResult result;
  const auto start = std::chrono::steady_clock::now();
  double next_progress_s = kProgressSeconds;
  Irrr<Pose> irrr(options);
  GraphReplay<Pose> replay(graph, &irrr);
  ProgressLine line;
  ReplayProgress<Pose> progress(graph, "  " + label, &line);
  ReplayTimed(graph, &irrr, &replay, &progress, [&](const StepResult& step, double ms) {
    result.step_ms.push_back(ms);
    result.solves += step.solves;
    result.capped_steps += step.capped ? 1 : 0;
    if (line.enabled()) return true;
    if (const double elapsed_s = SecondsSince(start); elapsed_s >= next_progress_s) {
      fmt::print(stderr,
                 "  {}: {:.0f} s, {} steps, pose {}/{}\n",
                 label,
                 elapsed_s,
                 irrr.num_steps(),
                 progress.poses_in(),
                 graph.num_vertices());
      next_progress_s = elapsed_s + kProgressSeconds;
    }
    return true;
  });
  line.Clear();
  result.seconds = SecondsSince(start);
  result.steps = irrr.num_steps();
  result.decisions = replay.Decisions();
  result.odometry_faults = replay.OdometryFaults();
  *estimate = replay.Estimate();
  return result;
}

// The method's decisions and map on `graph`, timed.
template <class Pose>
Status RunMethod(const std::string& label,
                 const Method& method,
                 const PoseGraph<Pose>& graph,
                 MethodRun<Pose>* run) {
  const double cpu_start_s = ProcessCpuSeconds();
  const auto start = std::chrono::steady_clock::now();
  run->accepted.assign(graph.num_edges(), 0);
  if (method.IsRobustKernel()) {
    RobustOptions options;
    options.kernel =
        method.algorithm == Algorithm::kDcs ? RobustKernel::kDcs : RobustKernel::kGncTls;
    RobustResult<Pose> result;
    if (Status s = RobustSolve(graph, options, graph.initial_estimate(), &result); !s.ok()) {
      return s;
    }
    for (int e = 0; e < graph.num_edges(); ++e) {
      run->accepted[e] = graph.edge(e).kind == EdgeKind::kLoop && result.Accepted(e);
    }
    run->estimate = std::move(result.estimate);
    run->solves = result.solver_iterations;
    run->seconds = SecondsSince(start);
  } else {
    std::vector<LoopDecision> decisions;
    if (method.algorithm == Algorithm::kIrrr) {
      RunResult result = RunIncrementalTimed(label, graph, OptionsFor(method), &run->estimate);
      decisions = std::move(result.decisions);
      run->seconds = result.seconds;
      run->steps = result.steps;
      run->solves = result.solves;
      run->capped_steps = result.capped_steps;
      run->step_ms = std::move(result.step_ms);
      run->odometry_faults = std::move(result.odometry_faults);
    } else {
      decisions = RunBatchRrr(graph, OptionsFor(method), &run->estimate);
      run->seconds = SecondsSince(start);
    }
    for (int e = 0; e < graph.num_edges(); ++e) {
      run->accepted[e] =
          graph.edge(e).kind == EdgeKind::kLoop && decisions[e].state == LoopState::kAccepted;
    }
  }
  run->cpu_seconds = ProcessCpuSeconds() - cpu_start_s;
  return Status::Ok();
}

// A MethodRun as numbers through a pipe, and back.
template <class Pose>
std::vector<double> Serialize(const MethodRun<Pose>& run) {
  std::vector<double> out = {run.seconds,
                             run.cpu_seconds,
                             static_cast<double>(run.steps),
                             static_cast<double>(run.solves),
                             static_cast<double>(run.step_ms.size()),
                             static_cast<double>(run.accepted.size()),
                             static_cast<double>(run.estimate.size()),
                             static_cast<double>(run.odometry_faults.size()),
                             static_cast<double>(run.capped_steps)};
  out.insert(out.end(), run.step_ms.begin(), run.step_ms.end());
  for (char a : run.accepted) out.push_back(a);
  out.insert(out.end(), run.odometry_faults.begin(), run.odometry_faults.end());
  for (const Pose& pose : run.estimate) {
    if constexpr (Pose::kDim == 3) {
      out.insert(out.end(), {pose.translation().x(), pose.translation().y(), pose.yaw_rad()});
    } else {
      const Eigen::Quaterniond& q = pose.quaternion();
      out.insert(out.end(),
                 {q.w(),
                  q.x(),
                  q.y(),
                  q.z(),
                  pose.translation().x(),
                  pose.translation().y(),
                  pose.translation().z()});
    }
  }
  return out;
}

template <class Pose>
bool Deserialize(const std::vector<double>& in, MethodRun<Pose>* run) {
  constexpr size_t kHeader = 9;
  constexpr size_t kPoseNumbers = Pose::kDim == 3 ? 3 : 7;
  if (in.size() < kHeader) return false;
  const auto num_steps = static_cast<size_t>(in[4]);
  const auto num_edges = static_cast<size_t>(in[5]);
  const auto num_poses = static_cast<size_t>(in[6]);
  const auto num_faults = static_cast<size_t>(in[7]);
  if (in.size() != kHeader + num_steps + num_edges + num_faults + kPoseNumbers * num_poses) {
    return false;
  }
  run->seconds = in[0];
  run->cpu_seconds = in[1];
  run->steps = static_cast<int>(in[2]);
  run->solves = static_cast<int>(in[3]);
  run->capped_steps = static_cast<int>(in[8]);
  auto next = in.begin() + kHeader;
  run->step_ms.assign(next, next + num_steps);
  next += num_steps;
  run->accepted.assign(num_edges, 0);
  for (size_t e = 0; e < num_edges; ++e) run->accepted[e] = *next++ != 0.0 ? 1 : 0;
  run->odometry_faults.assign(next, next + num_faults);
  next += num_faults;
  run->estimate.resize(num_poses);
  for (size_t v = 0; v < num_poses; ++v, next += kPoseNumbers) {
    if constexpr (Pose::kDim == 3) {
      run->estimate[v] = Pose(next[0], next[1], next[2]);
    } else {
      run->estimate[v] = Pose(Eigen::Quaterniond(next[0], next[1], next[2], next[3]),
                              Eigen::Vector3d(next[4], next[5], next[6]));
    }
  }
  return true;
}

}  // namespace

template <class Pose>
Status RunInChild(const std::string& label,
                  const Method& method,
                  const PoseGraph<Pose>& graph,
                  double limit_seconds,
                  MethodRun<Pose>* run) {
  auto work = [&](std::vector<double>* numbers) {
    MethodRun<Pose> result;
    const Status s = RunMethod(label, method, graph, &result);
    if (!s.ok()) {
      fmt::print(stderr, "{}: {}: {}\n", label, MethodName(method), s.message());
      return false;
    }
    *numbers = Serialize(result);
    return true;
  };
  ChildResult child;
  if (Status s = RunInChildProcess(work, limit_seconds, &child); !s.ok()) return s;
  if (child.stopped) {
    run->stopped = true;
    run->seconds = limit_seconds;
    return Status::Ok();
  }
  if (!Deserialize(child.numbers, run)) return Status::Error("the run's result did not read back");
  run->peak_rss_kb = child.peak_rss_kb;
  return Status::Ok();
}

template Status RunInChild(
    const std::string&, const Method&, const PoseGraph<Pose2>&, double, MethodRun<Pose2>*);
template Status RunInChild(
    const std::string&, const Method&, const PoseGraph<Pose3>&, double, MethodRun<Pose3>*);

}  // namespace irrr
