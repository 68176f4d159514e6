// irrr-batch: decide about the loop closures of a pose-graph file and optimize it.
//
//   irrr-batch INPUT [--method none|rrr|irrr|dcs|gnc] [--config FILE] [--decisions OUT.csv]
//              [--output OUT.g2o] [--ground-truth GT] [--alpha A] [--cluster-gap G]
//              [--graph-dof residual_rows|exact] [--solver gn|lm] [--max-iterations N]
//              [--plot MAP.svg|MAP.png]
//
// dcs and gnc are the field's robust-kernel baselines (core/robust_solve.h): their decisions are
// "accepted" for a loop whose final weight is above 0.5 and "rejected_link_test" otherwise, with
// the loop's d^2 at the final estimate and the kernel's threshold (DCS: 3 Phi, where the scale is
// 0.5; GNC: the truncated least squares bound c^2) in the CSV.
// --plot draws the map with every decision, the initial guess beside it, the time of every iRRR
// step and, with --ground-truth, the ATE histogram (clients/common/plots.h).
// Options come from the "irrr" object of the configuration file (if any), then from the command
// line, which overrides it. Exit codes follow sysexits.h: 64 usage, 65 bad input data, 66 input
// missing, 70 optimizer failure, 73 output not written, 78 bad configuration.

#include <sysexits.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include <fmt/core.h>
#include <fmt/ranges.h>
#include <CLI/CLI.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/loop_csv.h"
#include "clients/common/plots.h"
#include "clients/common/progress_line.h"
#include "core/graph_io.h"
#include "core/irrr.h"
#include "core/optimizer.h"
#include "core/robust_solve.h"
#include "core/test_statistics.h"
#include "core/trajectory_metrics.h"
#include "daemon/common/allocator.h"
#include "daemon/common/irrr_config.h"

namespace irrr {
namespace {

struct BatchArguments {
  std::string input;
  std::string method = "none";
  std::string config;
  std::string decisions;
  std::string output;
  std::string ground_truth;
  std::string plot;
  std::string labels;
  bool skip_unknown_tags = false;
  bool skip_invalid_edges = false;
  RobustOptions robust;  // --method dcs or gnc
};

// Precision and recall of the decisions against an irrr-corrupt labels file (rows by file edge
// index). Returns EX_OK or EX_DATAERR with a message.
int PrintScores(const std::string& path, const std::vector<DecisionRow>& decisions) {
  std::ifstream in(path);
  std::vector<LabelRow> labels;
  Scores scores;
  Status s = in ? ReadLabelsCsv(in, &labels) : Status::Error("cannot open");
  if (s.ok()) s = ScoreDecisions(labels, decisions, &scores);
  if (!s.ok()) {
    fmt::print(stderr, "irrr-batch: {}: {}\n", path, s.message());
    return EX_DATAERR;
  }
  fmt::print("scores    against {}: {}\n", path, FormatScores(scores));
  return EX_OK;
}

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

int WriteOrFail(const std::string& path, const std::function<Status(std::ostream&)>& write) {
  if (Status s = WriteFileAtomically(path, write); !s.ok()) {
    fmt::print(stderr, "irrr-batch: {}\n", s.message());
    return EX_CANTCREAT;
  }
  return EX_OK;
}

// ATE with each component aligned on its own; one line per component when there are several.
template <class Pose>
void PrintAccuracy(const PoseGraph<Pose>& graph,
                   const std::vector<char>& active,
                   const std::vector<Pose>& estimate,
                   const std::vector<Pose>& ground_truth,
                   const std::string& ground_truth_path) {
  const std::vector<int> component = SessionComponents(graph, active);
  std::vector<std::vector<int>> groups;
  std::vector<std::vector<int>> sessions_of_group;
  for (int s = 0; s < graph.num_sessions(); ++s) {
    if (component[s] >= static_cast<int>(groups.size())) {
      groups.resize(component[s] + 1);
      sessions_of_group.resize(component[s] + 1);
    }
    for (int v : graph.session(s).vertices) groups[component[s]].push_back(v);
    sessions_of_group[component[s]].push_back(s);
  }
  const TrajectoryError ate = AbsoluteTrajectoryError(estimate, ground_truth, groups);
  fmt::print("accuracy  ATE against {}: rmse {:.4f} m, mean {:.4f} m, max {:.4f} m\n",
             ground_truth_path,
             ate.rmse_m,
             ate.mean_m,
             ate.max_m);
  if (groups.size() < 2) return;
  // errors_m follows the groups' order.
  size_t next = 0;
  for (size_t c = 0; c < groups.size(); ++c) {
    double sum_squared = 0.0;
    double max_m = 0.0;
    for (size_t k = 0; k < groups[c].size(); ++k, ++next) {
      sum_squared += ate.errors_m[next] * ate.errors_m[next];
      max_m = std::max(max_m, ate.errors_m[next]);
    }
    std::string sessions;
    for (int s : sessions_of_group[c]) {
      sessions += (sessions.empty() ? "" : ",") + std::to_string(graph.session(s).id);
    }
    fmt::print("          component {} (session {}): {} poses, rmse {:.4f} m, max {:.4f} m\n",
               c,
               sessions,
               groups[c].size(),
               std::sqrt(sum_squared / std::max<size_t>(1, groups[c].size())),
               max_m);
  }
}

// " (the data's estimate 3.41)" when the tests used another factor, else "".
std::string VarianceEstimateNote(const StepResult& step) {
  if (!step.VarianceEstimateDiffers()) return "";
  return fmt::format(" (the data's estimate {:.4g})", step.variance_estimate);
}

int Arbitrations(const std::vector<StepResult>& steps) {
  int n = 0;
  for (const StepResult& step : steps) n += step.arbitrations;
  return n;
}

// The largest step's solves and, with a step budget, how many steps stopped at it.
std::string StepWorkNote(const std::vector<StepResult>& steps, int step_budget) {
  int largest = 0;
  int capped = 0;
  for (const StepResult& step : steps) {
    largest = std::max(largest, step.solves);
    capped += step.capped ? 1 : 0;
  }
  if (step_budget == 0) return fmt::format("largest {} solves", largest);
  return fmt::format(
      "largest {} solves, {} stopped at the step budget of {}", largest, capped, step_budget);
}

// The odometry edges the accepted loops refute (Irrr::OdometryFaults), as stretches of adjacent
// edges, each from its first pose's id to its last's.
template <class Pose>
void PrintOdometryFaults(const PoseGraph<Pose>& graph, const std::vector<int>& faults) {
  if (faults.empty()) return;
  std::vector<std::string> stretches;
  for (const std::vector<int>& stretch : OdometryStretches(graph, faults)) {
    stretches.push_back(fmt::format("{}-{}",
                                    graph.vertex(graph.edge(stretch.front()).from).id,
                                    graph.vertex(graph.edge(stretch.back()).to).id));
  }
  fmt::print("faults    {} odometry edge(s) the accepted loops refute, in {} stretch(es): {}\n",
             faults.size(),
             stretches.size(),
             fmt::join(stretches, ", "));
}

template <class Pose>
int Run(const BatchArguments& args, const IrrrOptions& options, FileFormat format) {
  const auto load_start = std::chrono::steady_clock::now();
  GraphFile<Pose> file;
  PoseGraph<Pose> graph;
  std::vector<int> graph_edge_of_file_edge;
  ReadOptions read_options;
  read_options.skip_unknown_tags = args.skip_unknown_tags;
  read_options.skip_invalid_edges = args.skip_invalid_edges;
  if (Status s =
          LoadPoseGraph(args.input, format, read_options, &file, &graph, &graph_edge_of_file_edge);
      !s.ok()) {
    fmt::print(stderr, "irrr-batch: {}\n", s.message());
    return EX_DATAERR;
  }
  if (!file.skipped.empty()) {
    PrintSkippedLines(stderr, "irrr-batch", args.input, file.skipped);
    // Labels index the file's edges; with lines left out they would not line up.
    if (!args.labels.empty()) {
      fmt::print(stderr,
                 "irrr-batch: --labels cannot be scored against a file with skipped edge lines "
                 "(labels count every edge line of the file)\n");
      return EX_USAGE;
    }
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
      "input     {}: {} {} poses in {} session(s), {} odometry edges, {} loop hypotheses{} "
      "({:.3f} s to read)\n",
      args.input,
      Pose::kName,
      graph.num_vertices(),
      graph.num_sessions(),
      graph.num_edges() - num_loops,
      num_loops,
      file.skipped.empty() ? std::string()
                           : fmt::format(", {} invalid edge lines skipped", file.skipped.size()),
      load_s);

  std::vector<LoopDecision> decisions(graph.num_edges());
  std::vector<Pose> estimate = graph.initial_estimate();
  std::vector<StepResult> steps;     // --method irrr
  std::vector<int> odometry_faults;  // --method irrr
  std::vector<double> step_ms;       // the time of each
  double decide_s = 0.0;
  std::string robust_note;  // --method dcs or gnc
  int exit_code = EX_OK;
  if (args.method == "none") {
    // Every loop hypothesis is trusted.
    for (int e = 0; e < graph.num_edges(); ++e) {
      if (graph.edge(e).kind == EdgeKind::kLoop) decisions[e].state = LoopState::kAccepted;
    }
    Optimizer<Pose> optimizer(options.optimizer);
    const auto solve_start = std::chrono::steady_clock::now();
    OptimizerSummary summary;
    {
      ProgressLine line;
      ElapsedTicker ticker(
          fmt::format("optimizing {} poses, every loop trusted", graph.num_vertices()), &line);
      summary = optimizer.Solve(graph, std::vector<char>(graph.num_edges(), 1), &estimate);
    }
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
    if (!summary.IsSolutionUsable()) exit_code = EX_SOFTWARE;
    // Each loop's d^2 at the trusting optimum against the link test at the optimum's own variance
    // factor (chi2 over degrees of freedom): the loops the rest of the graph disagrees with.
    const double dof = summary.residual_dimension - summary.free_parameters;
    if (dof > 0.0) {
      const TestThresholds at_optimum{options.alpha, summary.final_chi2 / dof, dof};
      for (int e = 0; e < graph.num_edges(); ++e) {
        if (graph.edge(e).kind != EdgeKind::kLoop) continue;
        decisions[e].chi2 = summary.edge_chi2[e];
        decisions[e].threshold = at_optimum.Of(Pose::kDim);
      }
    }
  } else if (args.method == "dcs" || args.method == "gnc") {
    const auto decide_start = std::chrono::steady_clock::now();
    RobustOptions robust = args.robust;
    robust.kernel = args.method == "dcs" ? RobustKernel::kDcs : RobustKernel::kGncTls;
    RobustResult<Pose> result;
    Status s = Status::Ok();
    {
      ProgressLine line;
      ElapsedTicker ticker(fmt::format("{}: weighting {} loop hypotheses", args.method, num_loops),
                           &line);
      s = RobustSolve(graph, robust, graph.initial_estimate(), &result);
    }
    decide_s = SecondsSince(decide_start);
    if (!s.ok()) {
      fmt::print(stderr, "irrr-batch: {}\n", s.message());
      return EX_SOFTWARE;
    }
    estimate = result.estimate;
    for (int e = 0; e < graph.num_edges(); ++e) {
      if (graph.edge(e).kind != EdgeKind::kLoop) continue;
      decisions[e].state = result.Accepted(e) ? LoopState::kAccepted : LoopState::kRejectedLinkTest;
      decisions[e].chi2 = result.edge_chi2[e];
      decisions[e].threshold = result.threshold[e];
    }
    robust_note = fmt::format("{} reweightings, {} solver iterations, {}, ",
                              result.outer_iterations,
                              result.solver_iterations,
                              result.message);
  } else {
    const auto decide_start = std::chrono::steady_clock::now();
    // On a terminal, a progress line on stderr while deciding (ProgressLine); nothing otherwise.
    ProgressLine line;
    if (args.method == "rrr") {
      ElapsedTicker ticker(fmt::format("batch RRR: deciding {} loop hypotheses", num_loops), &line);
      decisions = RunBatchRrr(graph, options, &estimate);
    } else {
      // RunIncrementalIrrr's replay, with each step timed (for --plot).
      Irrr<Pose> irrr(options);
      GraphReplay<Pose> replay(graph, &irrr);
      ReplayProgress<Pose> progress(graph, "iRRR", &line);
      ReplayTimed(graph, &irrr, &replay, &progress, [&](const StepResult& step, double ms) {
        steps.push_back(step);
        step_ms.push_back(ms);
        return true;
      });
      line.Clear();
      decisions = replay.Decisions();
      estimate = replay.Estimate();
      odometry_faults = replay.OdometryFaults();
    }
    decide_s = SecondsSince(decide_start);
  }
  // The result's edges: odometry and the accepted loops.
  std::vector<char> active(graph.num_edges(), 0);
  for (int e = 0; e < graph.num_edges(); ++e) {
    active[e] =
        graph.edge(e).kind == EdgeKind::kOdometry || decisions[e].state == LoopState::kAccepted;
  }

  if (args.method != "none") {
    std::map<LoopState, int> count;
    std::vector<int> clusters;
    double chi2 = 0.0;
    for (int e = 0; e < graph.num_edges(); ++e) {
      if (active[e]) chi2 += EdgeChi2(graph.edge(e), estimate);
      if (graph.edge(e).kind != EdgeKind::kLoop) continue;
      ++count[decisions[e].state];
      if (decisions[e].cluster >= 0) clusters.push_back(decisions[e].cluster);
    }
    std::sort(clusters.begin(), clusters.end());
    const int num_clusters =
        static_cast<int>(std::unique(clusters.begin(), clusters.end()) - clusters.begin());
    const std::vector<int> component = SessionComponents(graph, active);
    const int num_components =
        component.empty() ? 0 : *std::max_element(component.begin(), component.end()) + 1;
    const int link = count[LoopState::kRejectedLinkTest];
    const int cluster = count[LoopState::kRejectedClusterTest];
    const int joint = count[LoopState::kRejectedJointTest];
    fmt::print(
        "decide    {}: {} loops in, {} accepted, {} rejected ({} link test, {} cluster test, {} "
        "joint test), {} reversed, {} pending, {} clusters, {}{} component(s), chi2 {:.6g}, "
        "{:.3f} s\n",
        args.method,
        num_loops,
        count[LoopState::kAccepted],
        link + cluster + joint,
        link,
        cluster,
        joint,
        count[LoopState::kReversed],
        count[LoopState::kPending],
        num_clusters,
        args.method == "irrr" && !steps.empty()
            ? fmt::format("{} steps ({}), {} arbitrations, variance factor {:.4g}{}, ",
                          steps.size(),
                          StepWorkNote(steps, options.step_budget),
                          Arbitrations(steps),
                          steps.back().variance_factor,
                          VarianceEstimateNote(steps.back()))
        : args.method == "irrr" ? std::string("0 steps, ")
                                : robust_note,
        num_components,
        chi2,
        decide_s);
  }

  if (args.method == "irrr") PrintOdometryFaults(graph, odometry_faults);

  const std::vector<DecisionRow> rows =
      DecisionRowsInFileOrder(file, graph, graph_edge_of_file_edge, decisions);
  if (!args.labels.empty()) {
    if (int code = PrintScores(args.labels, rows); code != EX_OK) return code;
  }

  if (!ground_truth.empty()) {
    PrintAccuracy(graph, active, estimate, ground_truth, args.ground_truth);
  }

  if (!args.decisions.empty()) {
    if (int code = WriteOrFail(args.decisions,
                               [&](std::ostream& out) { return WriteDecisionsCsv(out, rows); });
        code != EX_OK) {
      return code;
    }
    fmt::print("decisions {}\n", args.decisions);
  }

  if (!args.output.empty()) {
    // Vertices at the estimate; edges: odometry and the accepted loops, in file order.
    GraphFile<Pose> result = WithEstimate(file, graph, estimate);
    result.edges.clear();
    for (size_t k = 0; k < file.edges.size(); ++k) {
      if (active[graph_edge_of_file_edge[k]]) result.edges.push_back(file.edges[k]);
    }
    const FileFormat output_format = FormatForPath(args.output);
    if (int code = WriteOrFail(
            args.output,
            [&](std::ostream& out) { return WriteGraphFile(out, output_format, result); });
        code != EX_OK) {
      return code;
    }
    fmt::print("output    {}\n", args.output);
  }

  if (!args.plot.empty()) {
    std::vector<std::string> written;
    const std::string title =
        args.input.substr(args.input.rfind('/') + 1) + " (" + args.method + ")";
    if (Status s = WriteGraphPlots(
            args.plot, title, graph, estimate, decisions, ground_truth, step_ms, &written);
        !s.ok()) {
      fmt::print(stderr, "irrr-batch: {}\n", s.message());
      return EX_CANTCREAT;
    }
    fmt::print("plots     {}\n", fmt::join(written, ", "));
  }
  return exit_code;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  irrr::TuneAllocatorForSolves();
  irrr::BatchArguments args;
  double alpha = 0.0;
  double cluster_gap = 0.0;
  std::string graph_dof;
  std::string solver;
  int max_iterations = 0;
  int step_budget = 0;
  // Help shows IrrrOptions' own defaults, under their configuration names.
  const nlohmann::json defaults = irrr::IrrrOptionsToJson(irrr::IrrrOptions());
  CLI::App app{"irrr-batch: robust loop closing (iRRR) and optimization of a pose-graph file"};
  app.add_option("input", args.input, "g2o (2D or 3D) or TORO 2D pose-graph file")->required();
  app.add_option("--method",
                 args.method,
                 "none (accept every loop hypothesis), rrr (batch RRR), irrr (incremental "
                 "iRRR, hypotheses replayed in arrival order), or a robust-kernel baseline over "
                 "the whole file: dcs (dynamic covariance scaling; a loop is accepted when its "
                 "final scale is above 0.5) or gnc (graduated non-convexity with truncated least "
                 "squares, from the dead reckoning; accepted when its final weight is above 0.5)")
      ->check(CLI::IsMember({"none", "rrr", "irrr", "dcs", "gnc"}))
      ->capture_default_str();
  app.add_option("--dcs-phi", args.robust.dcs_phi, "dcs: the kernel's Phi")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--dcs-iterations",
                 args.robust.dcs_iterations,
                 "dcs: reweighted Gauss-Newton steps at most")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--gnc-inlier-probability",
                 args.robust.inlier_probability,
                 "gnc: an inlier's d^2 is below the chi-square quantile of this probability")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  app.add_option("--config", args.config, "JSON configuration; only its \"irrr\" object is read");
  app.add_option(
      "--plot",
      args.plot,
      "draw the map with every decision here (SVG, or PNG with rsvg-convert), and beside "
      "it the initial guess, the time per step and the ATE histogram");
  app.add_option("--decisions",
                 args.decisions,
                 "write one CSV row per loop hypothesis, in input file order, here");
  app.add_option("--labels",
                 args.labels,
                 "irrr-corrupt's labels of the input's loops: print precision and recall");
  app.add_option("--output",
                 args.output,
                 "write the optimized graph (odometry and accepted loops) here (TORO for "
                 "*.graph, g2o otherwise)");
  app.add_option("--ground-truth",
                 args.ground_truth,
                 "ground-truth poses (a graph file, or one 'x y yaw' line per vertex) for ATE");
  app.add_option(
      "--alpha",
      alpha,
      fmt::format("confidence of the chi-square tests, in (0, 1) [{}]", defaults["alpha"].dump()));
  app.add_option("--cluster-gap",
                 cluster_gap,
                 fmt::format("cluster gap t_g of eq. (6), in poses for files [{}]",
                             defaults["cluster_gap"].dump()));
  app.add_option("--graph-dof",
                 graph_dof,
                 fmt::format("degrees of freedom of the graph test: residual_rows (reference) or "
                             "exact [{}]",
                             defaults["graph_dof"].get<std::string>()))
      ->check(CLI::IsMember({"residual_rows", "exact"}));
  app.add_option("--solver",
                 solver,
                 fmt::format("gn (Gauss-Newton) or lm (Levenberg-Marquardt) [{}]",
                             irrr::IrrrOptions().optimizer.algorithm ==
                                     irrr::OptimizerAlgorithm::kGaussNewton
                                 ? "gn"
                                 : "lm"))
      ->check(CLI::IsMember({"gn", "lm"}));
  app.add_option("--max-iterations",
                 max_iterations,
                 fmt::format("optimizer iteration limit [{}]",
                             defaults["optimizer"]["max_iterations"].dump()))
      ->check(CLI::PositiveNumber);
  app.add_option("--step-budget",
                 step_budget,
                 fmt::format("solves one step may use before leaving the rest of its work to later "
                             "steps; 0: unbounded [{}]",
                             defaults["step_budget"].dump()))
      ->check(CLI::NonNegativeNumber);
  app.add_flag("--skip-unknown-tags",
               args.skip_unknown_tags,
               "ignore lines with tags other than vertices and edges (e.g. EQUIV)");
  app.add_flag("--skip-invalid-edges",
               args.skip_invalid_edges,
               "leave out edge lines that are well formed but invalid (self-loop, non-finite "
               "number, information not positive definite, undeclared vertex), each named on "
               "stderr, instead of failing");
  app.footer(
      "Defaults in brackets are IrrrOptions' own; a --config file replaces them and the options "
      "above replace the file's.\n\nExit codes: 0 ok, 64 usage, 65 bad input data, 66 input "
      "missing, 70 optimizer failure, 73 output not written, 78 bad configuration.");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }

  irrr::IrrrOptions options;
  if (!args.config.empty()) {
    if (!std::ifstream(args.config)) {
      fmt::print(stderr, "irrr-batch: {}: cannot open\n", args.config);
      return EX_NOINPUT;
    }
    nlohmann::json config;
    if (irrr::Status s = irrr::LoadConfigFile(args.config, &config); !s.ok()) {
      fmt::print(stderr, "irrr-batch: {}\n", s.message());
      return EX_CONFIG;
    }
    if (irrr::Status s = irrr::ParseIrrrConfig(config, &options); !s.ok()) {
      fmt::print(stderr, "irrr-batch: {}: {}\n", args.config, s.message());
      return EX_CONFIG;
    }
  }
  if (app.count("--alpha") > 0) options.alpha = alpha;
  if (app.count("--cluster-gap") > 0) options.cluster_gap = cluster_gap;
  if (app.count("--graph-dof") > 0) {
    options.graph_dof = graph_dof == "exact" ? irrr::GraphDegreesOfFreedom::kExact
                                             : irrr::GraphDegreesOfFreedom::kResidualRows;
  }
  if (app.count("--solver") > 0) {
    options.optimizer.algorithm = solver == "lm" ? irrr::OptimizerAlgorithm::kLevenbergMarquardt
                                                 : irrr::OptimizerAlgorithm::kGaussNewton;
  }
  if (app.count("--max-iterations") > 0) options.optimizer.max_iterations = max_iterations;
  if (app.count("--step-budget") > 0) options.step_budget = step_budget;
  // The file's values were valid: what fails now came from the command line.
  if (irrr::Status s = options.Validate(); !s.ok()) {
    fmt::print(stderr, "irrr-batch: command line: {}\n", s.message());
    return EX_USAGE;
  }
  if (irrr::Status s = args.robust.Validate(); !s.ok()) {
    fmt::print(stderr, "irrr-batch: command line: {}\n", s.message());
    return EX_USAGE;
  }

  if (!std::ifstream(args.input)) {
    fmt::print(stderr, "irrr-batch: {}: cannot open\n", args.input);
    return EX_NOINPUT;
  }
  irrr::FileFormat format;
  int dimension = 0;
  if (irrr::Status s = irrr::InspectGraphFile(args.input, &format, &dimension); !s.ok()) {
    fmt::print(stderr, "irrr-batch: {}\n", s.message());
    return EX_DATAERR;
  }
  return dimension == 2 ? irrr::Run<irrr::Pose2>(args, options, format)
                        : irrr::Run<irrr::Pose3>(args, options, format);
}
