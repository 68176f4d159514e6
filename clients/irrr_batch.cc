// irrr-batch: decide about the loop closures of a pose-graph file and optimize it.
//
//   irrr-batch INPUT [--method none] [--output OUT.g2o] [--ground-truth GT]
//
// Exit codes follow sysexits.h: 64 usage, 65 bad input data, 66 input missing, 73 output not
// written, 70 optimizer failure.

#include <sysexits.h>

#include <chrono>
#include <string>
#include <vector>

#include <fmt/core.h>
#include <CLI/CLI.hpp>

#include "clients/graph_files.h"
#include "core/graph_io.h"
#include "core/optimizer.h"
#include "core/trajectory_metrics.h"

namespace irrr {
namespace {

struct BatchArguments {
  std::string input;
  std::string method = "none";
  std::string output;
  std::string ground_truth;
  std::string solver = "gn";
  int max_iterations = 100;
  bool skip_unknown_tags = false;
};

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

template <class Pose>
int Run(const BatchArguments& args, FileFormat format) {
  const auto load_start = std::chrono::steady_clock::now();
  GraphFile<Pose> file;
  PoseGraph<Pose> graph;
  std::vector<int> graph_edge_of_file_edge;
  ReadOptions read_options;
  read_options.skip_unknown_tags = args.skip_unknown_tags;
  if (Status s =
          LoadPoseGraph(args.input, format, read_options, &file, &graph, &graph_edge_of_file_edge);
      !s.ok()) {
    fmt::print(stderr, "irrr-batch: {}\n", s.message());
    return EX_DATAERR;
  }
  const double load_s = SecondsSince(load_start);

  std::vector<Pose> ground_truth;
  if (!args.ground_truth.empty()) {
    if (Status s = LoadGroundTruth(args.ground_truth, graph, &ground_truth); !s.ok()) {
      fmt::print(stderr, "irrr-batch: {}\n", s.message());
      return EX_DATAERR;
    }
  }

  int num_loops = 0;
  for (const Edge<Pose>& e : graph.edges()) num_loops += e.kind == EdgeKind::kLoop ? 1 : 0;
  fmt::print(
      "input     {}: {} {} poses in {} session(s), {} odometry edges, {} loop hypotheses "
      "({:.3f} s to read)\n",
      args.input,
      Pose::kName,
      graph.num_vertices(),
      graph.num_sessions(),
      graph.num_edges() - num_loops,
      num_loops,
      load_s);

  // --method none: every loop hypothesis is trusted.
  const std::vector<char> active(graph.num_edges(), 1);
  OptimizerOptions options;
  options.algorithm = args.solver == "lm" ? OptimizerAlgorithm::kLevenbergMarquardt
                                          : OptimizerAlgorithm::kGaussNewton;
  options.max_iterations = args.max_iterations;
  Optimizer<Pose> optimizer(options);
  std::vector<Pose> estimate = graph.initial_estimate();
  const auto solve_start = std::chrono::steady_clock::now();
  const OptimizerSummary summary = optimizer.Solve(graph, active, &estimate);
  const double solve_s = SecondsSince(solve_start);
  fmt::print(
      "optimize  {} ({}): {} iterations, chi2 {:.6g} -> {:.6g}, {} component(s), "
      "{:.3f} s ({:.1f} ms per iteration)\n",
      TerminationTypeName(summary.termination),
      summary.message,
      summary.iterations,
      summary.initial_chi2,
      summary.final_chi2,
      summary.num_components,
      solve_s,
      1e3 * solve_s / std::max(1, summary.iterations));

  if (!ground_truth.empty()) {
    const std::vector<int> component = SessionComponents(graph, active);
    std::vector<std::vector<int>> groups;
    for (int s = 0; s < graph.num_sessions(); ++s) {
      if (component[s] >= static_cast<int>(groups.size())) groups.resize(component[s] + 1);
      for (int v : graph.session(s).vertices) groups[component[s]].push_back(v);
    }
    const TrajectoryError ate = AbsoluteTrajectoryError(estimate, ground_truth, groups);
    fmt::print("accuracy  ATE against {}: rmse {:.4f} m, mean {:.4f} m, max {:.4f} m\n",
               args.ground_truth,
               ate.rmse_m,
               ate.mean_m,
               ate.max_m);
  }

  if (!args.output.empty()) {
    const GraphFile<Pose> result = WithEstimate(file, graph, estimate);
    const FileFormat output_format = FormatForPath(args.output);
    if (Status s = WriteFileAtomically(
            args.output,
            [&](std::ostream& out) { return WriteGraphFile(out, output_format, result); });
        !s.ok()) {
      fmt::print(stderr, "irrr-batch: {}\n", s.message());
      return EX_CANTCREAT;
    }
    fmt::print("output    {}\n", args.output);
  }
  return summary.IsSolutionUsable() ? EX_OK : EX_SOFTWARE;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  irrr::BatchArguments args;
  CLI::App app{"irrr-batch: robust loop closing (iRRR) and optimization of a pose-graph file"};
  app.add_option("input", args.input, "g2o (2D or 3D) or TORO 2D pose-graph file")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--method",
                 args.method,
                 "loop-closure decision method: none (accept every loop hypothesis)")
      ->check(CLI::IsMember({"none"}))
      ->capture_default_str();
  app.add_option(
      "--output", args.output, "write the optimized graph here (TORO for *.graph, g2o otherwise)");
  app.add_option("--ground-truth",
                 args.ground_truth,
                 "ground-truth poses (a graph file, or one 'x y yaw' line per vertex) for ATE");
  app.add_option("--solver", args.solver, "gn (Gauss-Newton) or lm (Levenberg-Marquardt)")
      ->check(CLI::IsMember({"gn", "lm"}))
      ->capture_default_str();
  app.add_option("--max-iterations", args.max_iterations, "optimizer iteration limit")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_flag("--skip-unknown-tags",
               args.skip_unknown_tags,
               "ignore lines with tags other than vertices and edges (e.g. EQUIV)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }

  irrr::FileFormat format;
  int dimension = 0;
  if (irrr::Status s = irrr::InspectGraphFile(args.input, &format, &dimension); !s.ok()) {
    fmt::print(stderr, "irrr-batch: {}\n", s.message());
    return EX_DATAERR;
  }
  return dimension == 2 ? irrr::Run<irrr::Pose2>(args, format)
                        : irrr::Run<irrr::Pose3>(args, format);
}
