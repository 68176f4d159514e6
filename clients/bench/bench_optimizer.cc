// irrr-bench-optimizer: how fast and how far the optimizer gets on public datasets, from their
// raw initial guess with every edge trusted.
//
//   irrr-bench-optimizer [--shared ../shared] [--solver gn|lm] [--repeat N] [DATASET...]
//
// Each dataset runs in a child process so that its peak memory (max RSS) is its own.

#include <sys/resource.h>
#include <sys/wait.h>
#include <sysexits.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <map>
#include <string>
#include <vector>

#include <fmt/core.h>
#include <CLI/CLI.hpp>

#include "clients/common/graph_files.h"
#include "core/optimizer.h"
#include "core/trajectory_metrics.h"

namespace irrr {
namespace {

struct Dataset {
  std::string name;
  std::string path;          // under the shared folder
  std::string ground_truth;  // under the shared folder, or empty
};

const std::vector<Dataset>& KnownDatasets() {
  static const std::vector<Dataset> kDatasets = {
      {"manhattan",
       "datasets/manhattan/vertigo/Olson/manhattanOlson3500.g2o",
       "datasets/manhattan/vertigo/groundTruth/manhattanOlson3500_nodes_groundTruth.dat"},
      {"intel", "datasets/intel/vertigo/intel.g2o", ""},
      {"city10000", "datasets/city10000/vertigo/city10000.g2o", ""},
      {"sphere2500", "datasets/sphere2500/vertigo/sphere2500.g2o", ""},
      {"garage", "datasets/garage/parking-garage.g2o", ""},
  };
  return kDatasets;
}

// What a child reports to the parent through a pipe (plain data).
struct Result {
  int ok = 0;
  int vertices = 0;
  int edges = 0;
  int iterations = 0;
  int termination = 0;
  double load_s = 0.0;
  double solve_s = 0.0;
  double first_iteration_s = 0.0;
  double initial_chi2 = 0.0;
  double final_chi2 = 0.0;
  double ate_rmse_m = -1.0;
  char message[160] = {};
};

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

template <class Pose>
Result RunDataset(const std::string& path,
                  FileFormat format,
                  const std::string& ground_truth_path,
                  OptimizerAlgorithm algorithm,
                  int repeat) {
  Result result;
  const auto load_start = std::chrono::steady_clock::now();
  GraphFile<Pose> file;
  PoseGraph<Pose> graph;
  std::vector<int> unused;
  if (Status s = LoadPoseGraph(path, format, ReadOptions(), &file, &graph, &unused); !s.ok()) {
    std::snprintf(result.message, sizeof(result.message), "%s", s.message().c_str());
    return result;
  }
  result.load_s = SecondsSince(load_start);
  result.vertices = graph.num_vertices();
  result.edges = graph.num_edges();
  const std::vector<char> active(graph.num_edges(), 1);
  OptimizerOptions options;
  options.algorithm = algorithm;

  // One iteration alone shows the cost of the first solve (symbolic analysis included).
  {
    OptimizerOptions one = options;
    one.max_iterations = 1;
    Optimizer<Pose> optimizer(one);
    std::vector<Pose> estimate = graph.initial_estimate();
    const auto start = std::chrono::steady_clock::now();
    optimizer.Solve(graph, active, &estimate);
    result.first_iteration_s = SecondsSince(start);
  }
  std::vector<Pose> estimate;
  OptimizerSummary summary;
  double best_s = 1e300;
  for (int r = 0; r < repeat; ++r) {
    Optimizer<Pose> optimizer(options);
    estimate = graph.initial_estimate();
    const auto start = std::chrono::steady_clock::now();
    summary = optimizer.Solve(graph, active, &estimate);
    best_s = std::min(best_s, SecondsSince(start));
  }
  result.solve_s = best_s;
  result.iterations = summary.iterations;
  result.termination = static_cast<int>(summary.termination);
  result.initial_chi2 = summary.initial_chi2;
  result.final_chi2 = summary.final_chi2;
  std::snprintf(result.message, sizeof(result.message), "%s", summary.message.c_str());
  if (!ground_truth_path.empty()) {
    std::vector<Pose> ground_truth;
    if (Status s = LoadGroundTruth(ground_truth_path, graph, &ground_truth); s.ok()) {
      result.ate_rmse_m = AbsoluteTrajectoryError(estimate, ground_truth).rmse_m;
    }
  }
  result.ok = 1;
  return result;
}

Result RunInChild(const Dataset& dataset,
                  const std::string& shared,
                  OptimizerAlgorithm algorithm,
                  int repeat,
                  long* peak_kb) {
  int pipe_fds[2];
  Result result;
  if (pipe(pipe_fds) != 0) return result;
  const pid_t pid = fork();
  if (pid == 0) {
    close(pipe_fds[0]);
    const std::string path = shared + "/" + dataset.path;
    const std::string ground_truth =
        dataset.ground_truth.empty() ? "" : shared + "/" + dataset.ground_truth;
    FileFormat format;
    int dimension = 0;
    Result child;
    if (Status s = InspectGraphFile(path, &format, &dimension); !s.ok()) {
      std::snprintf(child.message, sizeof(child.message), "%s", s.message().c_str());
    } else if (dimension == 2) {
      child = RunDataset<Pose2>(path, format, ground_truth, algorithm, repeat);
    } else {
      child = RunDataset<Pose3>(path, format, ground_truth, algorithm, repeat);
    }
    const ssize_t written = write(pipe_fds[1], &child, sizeof(child));
    _exit(written == static_cast<ssize_t>(sizeof(child)) ? 0 : 1);
  }
  close(pipe_fds[1]);
  const ssize_t got = read(pipe_fds[0], &result, sizeof(result));
  close(pipe_fds[0]);
  int status = 0;
  struct rusage usage {};
  wait4(pid, &status, 0, &usage);
  *peak_kb = usage.ru_maxrss;
  if (got != static_cast<ssize_t>(sizeof(result))) result = Result();
  return result;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  std::string shared = "../shared";
  std::string solver = "gn";
  int repeat = 3;
  std::vector<std::string> names;
  CLI::App app{"irrr-bench-optimizer: optimizer speed and final chi2 on public datasets"};
  app.add_option("--shared", shared, "the shared/ folder holding datasets/")->capture_default_str();
  app.add_option("--solver", solver, "gn or lm")
      ->check(CLI::IsMember({"gn", "lm"}))
      ->capture_default_str();
  app.add_option("--repeat", repeat, "solves per dataset; the fastest is reported")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("datasets", names, "dataset names (default: all)");
  CLI11_PARSE(app, argc, argv);

  const auto algorithm = solver == "lm" ? irrr::OptimizerAlgorithm::kLevenbergMarquardt
                                        : irrr::OptimizerAlgorithm::kGaussNewton;
  std::vector<irrr::Dataset> selected;
  for (const irrr::Dataset& d : irrr::KnownDatasets()) {
    if (names.empty() || std::find(names.begin(), names.end(), d.name) != names.end()) {
      selected.push_back(d);
    }
  }
  if (selected.empty()) {
    fmt::print(stderr, "no known dataset selected\n");
    return EX_USAGE;
  }
  fmt::print(
      "solver {}, from the raw initial guess, all edges; time = fastest of {}\n", solver, repeat);
  fmt::print(
      "| dataset | poses | edges | load s | 1st iter ms | iters | ms/iter | solve s | "
      "chi2 initial | chi2 final | termination | ATE m | peak MB |\n");
  fmt::print("|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  int failures = 0;
  for (const irrr::Dataset& d : selected) {
    long peak_kb = 0;
    const irrr::Result r = irrr::RunInChild(d, shared, algorithm, repeat, &peak_kb);
    if (!r.ok) {
      fmt::print("| {} | failed: {} |\n", d.name, r.message);
      ++failures;
      continue;
    }
    const std::string ate = r.ate_rmse_m < 0 ? "-" : fmt::format("{:.3f}", r.ate_rmse_m);
    fmt::print(
        "| {} | {} | {} | {:.3f} | {:.1f} | {} | {:.1f} | {:.3f} | {:.6g} | {:.6g} | {} | "
        "{} | {:.1f} |\n",
        d.name,
        r.vertices,
        r.edges,
        r.load_s,
        1e3 * r.first_iteration_s,
        r.iterations,
        1e3 * r.solve_s / std::max(1, r.iterations),
        r.solve_s,
        r.initial_chi2,
        r.final_chi2,
        irrr::TerminationTypeName(static_cast<irrr::TerminationType>(r.termination)),
        ate,
        peak_kb / 1024.0);
  }
  return failures == 0 ? EX_OK : EX_SOFTWARE;
}
