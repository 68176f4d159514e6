// irrr-bench-accuracy: which loops iRRR / batch RRR accept on public datasets, and how far the
// result is from the ground truth and from the oracle (the graph with exactly the true loops).
//
//   irrr-bench-accuracy [--shared ../shared] [--filter SUBSTRING] [--methods irrr,rrr]
//                       [--graph-dof residual_rows|exact|both]
//                       [--paper-faithful | --variant default|paper|both]
//                       [--order forward|reversed|both]
//                       [--seed N] [--group-size N] [--output FILE] [--list]
//
// Cases: synthetic outliers (core/outliers.h, appended to a clean graph, labels known) on
// Manhattan, Intel, City10000 and Sphere2500; the RRR author's KITTI 00 / 05 place-recognition
// graphs at five alpha levels (per-file labels); Bicocca 25b at five alpha levels (no labels; ATE
// against GPS associated by time); Bovisa 04 and 06 (no labels; ATE against one GPS fix per 10
// poses). Each row goes to stdout as soon as it is done; --output writes a complete Markdown
// document (rewritten after every row, so an interrupted run keeps its rows). --order reversed
// runs iRRR and RRR on every session driven backwards (clients/bench/order_runs.h); --order both
// runs iRRR in both orders and counts the loops accepted in one order only.

#include <sysexits.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <fmt/core.h>
#include <CLI/CLI.hpp>

#include "clients/bench/accuracy_cases.h"
#include "clients/bench/accuracy_report.h"
#include "clients/bench/method_runs.h"
#include "clients/bench/order_runs.h"
#include "clients/bench/reference_files.h"
#include "clients/common/graph_files.h"
#include "core/irrr.h"
#include "core/optimizer.h"
#include "core/outliers.h"
#include "core/trajectory_metrics.h"
#include "daemon/common/allocator.h"

namespace irrr {
namespace {

// Nearest-rank percentile of sorted values.
double Percentile(const std::vector<double>& sorted, double p) {
  if (sorted.empty()) return 0.0;
  const auto rank = static_cast<size_t>(std::ceil(p * static_cast<double>(sorted.size())));
  return sorted[std::min(sorted.size() - 1, rank == 0 ? 0 : rank - 1)];
}

// ATE with one alignment per connected component of odometry + the loops in `loops`, over the
// vertices that have a reference pose.
template <class Pose>
double ComponentAte(const PoseGraph<Pose>& graph,
                    const std::vector<Pose>& estimate,
                    const Reference<Pose>& reference,
                    const std::vector<char>& loops) {
  std::vector<char> active(graph.num_edges(), 0);
  for (int e = 0; e < graph.num_edges(); ++e) {
    active[e] = graph.edge(e).kind == EdgeKind::kOdometry || loops[e];
  }
  const std::vector<int> component = SessionComponents(graph, active);
  const int count = component.empty() ? 0 : *std::max_element(component.begin(), component.end());
  std::vector<std::vector<int>> groups(count + 1);
  for (int v = 0; v < graph.num_vertices(); ++v) {
    if (reference.valid[v]) groups[component[graph.vertex(v).session]].push_back(v);
  }
  return AbsoluteTrajectoryError(estimate, reference.poses, groups).rmse_m;
}

struct Settings {
  std::string shared;
  std::vector<Method> methods;
  OutlierOptions outliers;      // mode and count come from the case
  double method_seconds = 0.0;  // > 0: a method's run is stopped after this long
  // Which order iRRR and RRR see the sessions in (order_runs.h).
  RunOrder order = RunOrder::kForward;
};

// iRRR's odometry faults against the injected ones: "found/injected", and "+N wrong" for the
// stretches of flagged edges (adjacent edges, Irrr::OdometryFaults) that hold no injected fault;
// "" when there is nothing to say, "-" for a method that flags none.
template <class Pose>
std::string FaultsFound(const Method& method,
                        const PoseGraph<Pose>& graph,
                        const std::vector<char>& is_fault,
                        const std::vector<int>& flagged) {
  const int injected = static_cast<int>(std::count(is_fault.begin(), is_fault.end(), 1));
  if (method.algorithm != Algorithm::kIrrr) return injected > 0 ? "-" : "";
  int found = 0;
  int wrong = 0;
  for (const std::vector<int>& stretch : OdometryStretches(graph, flagged)) {
    const int held = static_cast<int>(
        std::count_if(stretch.begin(), stretch.end(), [&](int e) { return is_fault[e] != 0; }));
    found += held;
    wrong += held == 0 ? 1 : 0;
  }
  if (injected == 0 && wrong == 0) return "";
  const std::string text = fmt::format("{}/{}", found, injected);
  return wrong > 0 ? fmt::format("{} +{} wrong", text, wrong) : text;
}

std::string Fixed(double value, int digits) { return fmt::format("{:.{}f}", value, digits); }

// `graph` without the loop edges marked in `remove` (vertex indices unchanged).
template <class Pose>
Status RemoveLoops(const std::vector<char>& remove, PoseGraph<Pose>* graph) {
  const PoseGraph<Pose>& in = *graph;
  std::vector<int> odometry_to(in.num_vertices(), -1);  // the odometry edge ending at a vertex
  for (int e = 0; e < in.num_edges(); ++e) {
    if (in.edge(e).kind == EdgeKind::kOdometry) odometry_to[in.edge(e).to] = e;
  }
  PoseGraph<Pose> out;
  for (int s = 0; s < in.num_sessions(); ++s) {
    int index = -1;
    if (Status st = out.AddSession(in.session(s).id, &index); !st.ok()) return st;
  }
  for (int v = 0; v < in.num_vertices(); ++v) {
    const Vertex& vertex = in.vertex(v);
    const Edge<Pose>* odometry = odometry_to[v] >= 0 ? &in.edge(odometry_to[v]) : nullptr;
    int index = -1;
    if (Status st = out.AddPose(vertex.session,
                                vertex.id,
                                vertex.stamp,
                                in.initial_estimate()[v],
                                odometry ? &odometry->measurement : nullptr,
                                odometry ? &odometry->information : nullptr,
                                &index);
        !st.ok()) {
      return st;
    }
  }
  for (int e = 0; e < in.num_edges(); ++e) {
    const Edge<Pose>& edge = in.edge(e);
    if (edge.kind != EdgeKind::kLoop || remove[e]) continue;
    int index = -1;
    if (Status st = out.AddLoop(edge.from, edge.to, edge.measurement, edge.information, &index);
        !st.ok()) {
      return st;
    }
  }
  *graph = std::move(out);
  return Status::Ok();
}

template <class Pose>
Status RunCase(const Case& c,
               const Settings& settings,
               const std::function<void(const Row&)>& emit) {
  const std::string path = settings.shared + "/" + c.graph;
  FileFormat format;
  int dimension = 0;
  if (Status s = InspectGraphFile(path, &format, &dimension); !s.ok()) return s;
  GraphFile<Pose> file;
  PoseGraph<Pose> graph;
  std::vector<int> unused;
  if (Status s = LoadPoseGraph(path, format, ReadOptions(), &file, &graph, &unused); !s.ok()) {
    return s;
  }
  // Odometry failures first (they change the file's odometry and its dead reckoning), then the
  // wrong loops on the graph they leave.
  std::string odometry_note;
  std::vector<char> is_fault(graph.num_edges(), 0);
  if (c.odometry_noise > 0.0 || c.odometry_faults > 0) {
    std::vector<int> fault_file_edges;
    if (c.odometry_noise > 0.0) {
      if (Status s = PerturbOdometry(c.odometry_noise, settings.outliers.seed, &file); !s.ok()) {
        return s;
      }
      odometry_note = fmt::format("odometry noise x{:g}, ", c.odometry_noise);
    }
    if (c.odometry_faults > 0) {
      if (Status s = InjectOdometryFaults(
              c.odometry_faults, settings.outliers.seed, &file, &fault_file_edges);
          !s.ok()) {
        return s;
      }
      odometry_note += fmt::format("{} odometry faults, ", c.odometry_faults);
    }
    std::vector<int> graph_edge_of_file_edge;
    graph = PoseGraph<Pose>();
    if (Status s = BuildPoseGraph(file, &graph, &graph_edge_of_file_edge); !s.ok()) return s;
    is_fault.assign(graph.num_edges(), 0);
    for (int k : fault_file_edges) is_fault[graph_edge_of_file_edge[k]] = 1;
  }

  // Labels: which loop edges are true (all 0 and `labelled` false for an unlabelled graph).
  std::vector<char> is_true(graph.num_edges(), 0);
  bool labelled = true;
  std::string outlier_note = "-";
  if (c.kind == CaseKind::kSynthetic) {
    for (int e = 0; e < graph.num_edges(); ++e) is_true[e] = graph.edge(e).kind == EdgeKind::kLoop;
    OutlierOptions options = settings.outliers;
    options.mode = c.mode;
    options.count = c.outliers;
    std::vector<OutlierLink<Pose>> links;
    if (Status s = MakeOutliers(graph, options, &links); !s.ok()) return s;
    for (const OutlierLink<Pose>& link : links) {
      int edge = -1;
      if (Status s = graph.AddLoop(link.from, link.to, link.measurement, link.information, &edge);
          !s.ok()) {
        return s;
      }
      is_true.push_back(0);
      is_fault.push_back(0);
    }
    outlier_note =
        odometry_note + (IsGrouped(c.mode)
                             ? fmt::format("{} {}, groups of {}",
                                           links.size(),
                                           OutlierModeName(c.mode),
                                           std::max(1, options.group_size))
                             : fmt::format("{} {}", links.size(), OutlierModeName(c.mode)));
  } else if (c.kind == CaseKind::kLabelled) {
    if constexpr (Pose::kDim == 3) {
      int unmatched = 0;
      if (Status s = ReadLabels(settings.shared + "/" + c.labels, graph, &is_true, &unmatched);
          !s.ok()) {
        return s;
      }
      if (unmatched > 0) {
        fmt::print(stderr, "{}: {} labelled loop(s) match no loop edge\n", c.name, unmatched);
      }
      outlier_note = "place recognition";
      if (c.wrong_only) {
        if (Status s = RemoveLoops(is_true, &graph); !s.ok()) return s;
        is_fault.assign(graph.num_edges(), 0);
        is_true.assign(graph.num_edges(), 0);
        outlier_note = "place recognition, true loops removed";
      }
    } else {
      return Status::Error(c.name + ": labelled cases are 2D");
    }
  } else {
    labelled = false;
    outlier_note = "place recognition, unlabelled";
  }
  int true_loops = 0;
  int false_loops = 0;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind != EdgeKind::kLoop) continue;
    (is_true[e] ? true_loops : false_loops) += 1;
  }

  // The oracle: odometry + exactly the true loops, from dead reckoning.
  std::vector<Pose> oracle = graph.OdometryEstimate();
  if (labelled) {
    std::vector<char> active(graph.num_edges(), 0);
    for (int e = 0; e < graph.num_edges(); ++e) {
      active[e] = graph.edge(e).kind == EdgeKind::kOdometry || is_true[e];
    }
    Optimizer<Pose> optimizer;
    const OptimizerSummary summary = optimizer.Solve(graph, active, &oracle);
    if (!summary.IsSolutionUsable()) {
      return Status::Error(c.name + ": the oracle's optimization failed: " + summary.message);
    }
  }

  Reference<Pose> reference;
  reference.valid.assign(graph.num_vertices(), 1);
  const std::string reference_path = settings.shared + "/" + c.reference_path;
  switch (c.reference) {
    case ReferenceKind::kPoseLines:
    case ReferenceKind::kGraphFile:
      if (Status s = LoadGroundTruth(reference_path, graph, &reference.poses); !s.ok()) return s;
      reference.label = "GT";
      break;
    case ReferenceKind::kIsamEdges:
      if (Status s = ChainIsamEdges(reference_path, graph, &reference.poses); !s.ok()) return s;
      reference.label = "GT (iSAM chain)";
      break;
    case ReferenceKind::kOracle:
      reference.poses = oracle;
      reference.label = "oracle";
      break;
    case ReferenceKind::kTimestampGps:
      if constexpr (Pose::kDim == 3) {
        if (Status s = TimeAssociatedGps(
                settings.shared + "/" + c.timestamps, reference_path, graph, &reference);
            !s.ok()) {
          return s;
        }
      } else {
        return Status::Error(c.name + ": GPS references are 2D");
      }
      break;
    case ReferenceKind::kStridedGps:
      if constexpr (Pose::kDim == 3) {
        if (Status s = StridedGps(reference_path, kGpsStride, graph, &reference); !s.ok()) {
          return s;
        }
      } else {
        return Status::Error(c.name + ": GPS references are 2D");
      }
      break;
  }
  const double oracle_value = labelled ? ComponentAte(graph, oracle, reference, is_true) : 0.0;
  const std::string oracle_ate = labelled ? Fixed(oracle_value, 3) : "-";
  fmt::print(
      stderr,
      "{}: {} poses, {} loops ({} true), {}; against {}: oracle ATE {} m, odometry-only "
      "ATE {:.3f} m\n",
      c.name,
      graph.num_vertices(),
      true_loops + false_loops,
      labelled ? std::to_string(true_loops) : "?",
      outlier_note,
      reference.label,
      oracle_ate,
      ComponentAte(
          graph, graph.OdometryEstimate(), reference, std::vector<char>(graph.num_edges(), 0)));

  // The clean edges: odometry that is not a fault, and the true loops. Every method's map is
  // scored by its chi2 over them, beside the lowest any method of the run reached.
  std::vector<char> clean(graph.num_edges(), 0);
  for (int e = 0; e < graph.num_edges(); ++e) {
    clean[e] = graph.edge(e).kind == EdgeKind::kOdometry ? !is_fault[e] : is_true[e];
  }
  auto clean_chi2 = [&](const std::vector<Pose>& estimate) {
    double chi2 = 0.0;
    for (int e = 0; e < graph.num_edges(); ++e) {
      if (clean[e]) chi2 += EdgeChi2(graph.edge(e), estimate);
    }
    return chi2;
  };
  if (labelled)
    fmt::print(
        stderr, "{}: chi2 of the oracle over the clean edges {:.6g}\n", c.name, clean_chi2(oracle));

  // --order: iRRR and RRR on every session driven backwards, their result brought back to
  // `graph`'s edges and vertices (the robust kernels weigh every edge at once: no order).
  ReversedGraph<Pose> reversed;
  if (settings.order != RunOrder::kForward) reversed = TimeReversed(graph);
  const std::string backwards = c.name + " reversed";
  auto run_reversed = [&](const Method& method, MethodRun<Pose>* run) {
    Status s = RunInChild(backwards, method, reversed.graph, settings.method_seconds, run);
    if (s.ok() && !run->stopped) {
      FromReversed(graph, reversed, &run->accepted, &run->estimate);
      std::vector<int> original(reversed.graph.num_edges(), -1);
      for (int e = 0; e < graph.num_edges(); ++e) original[reversed.edge_of[e]] = e;
      for (int& e : run->odometry_faults) e = original[e];
      std::sort(run->odometry_faults.begin(), run->odometry_faults.end());
    }
    return s;
  };
  std::vector<MethodRun<Pose>> runs;
  std::vector<int> order_diffs;  // per run, -1: not compared
  for (const Method& method : settings.methods) {
    const bool reverse = settings.order == RunOrder::kReversed && !method.IsRobustKernel();
    fmt::print(stderr,
               "running {} {} {} {}{} ...\n",
               c.name,
               MethodName(method),
               DofName(method),
               VariantName(method),
               reverse ? " reversed" : "");
    MethodRun<Pose> run;
    if (Status s = reverse ? run_reversed(method, &run)
                           : RunInChild(c.name, method, graph, settings.method_seconds, &run);
        !s.ok()) {
      return Status::Error(MethodName(method) + ": " + s.message());
    }
    int diffs = -1;
    if (settings.order == RunOrder::kBoth && method.algorithm == Algorithm::kIrrr) {
      fmt::print(stderr, "running {} {} reversed ...\n", c.name, MethodName(method));
      MethodRun<Pose> other;
      if (Status s = run_reversed(method, &other); !s.ok()) {
        return Status::Error(MethodName(method) + " reversed: " + s.message());
      }
      std::string outcome = "stopped";
      if (!run.stopped && !other.stopped) {
        diffs = OrderDiffs(graph, run.accepted, other.accepted);
        int accepted = 0;
        int wrong = 0;
        for (int e = 0; e < graph.num_edges(); ++e) {
          if (graph.edge(e).kind != EdgeKind::kLoop || !other.accepted[e]) continue;
          ++accepted;
          wrong += is_true[e] ? 0 : 1;
        }
        outcome = fmt::format("{} loop(s) accepted in one order only; reversed: {} accepted ({})",
                              diffs,
                              accepted,
                              labelled ? fmt::format("{} wrong", wrong) : "unlabelled");
      }
      fmt::print(stderr,
                 "{}: {} reversed: {}; {:.2f} s ({:.2f} s CPU)\n",
                 c.name,
                 MethodName(method),
                 outcome,
                 other.seconds,
                 other.cpu_seconds);
    }
    order_diffs.push_back(diffs);
    runs.push_back(std::move(run));
  }
  std::vector<double> chi2(runs.size(), 0.0);
  double lowest_chi2 = std::numeric_limits<double>::infinity();
  for (size_t m = 0; m < runs.size(); ++m) {
    if (runs[m].stopped) continue;
    chi2[m] = clean_chi2(runs[m].estimate);
    lowest_chi2 = std::min(lowest_chi2, chi2[m]);
  }
  for (size_t m = 0; m < runs.size(); ++m) {
    const Method& method = settings.methods[m];
    const MethodRun<Pose>& run = runs[m];
    Row row;
    row.case_name = c.name;
    row.method = MethodName(method);
    row.configuration = DofName(method) + ", " + VariantName(method);
    row.seed = settings.outliers.seed;
    row.seconds = run.seconds;
    if (run.stopped) {
      row.stopped = true;
      row.markdown = fmt::format("| {} | {} | {} | {} | {} | {} | stopped after {:.0f} s |",
                                 c.name,
                                 outlier_note,
                                 MethodName(method),
                                 DofName(method),
                                 VariantName(method),
                                 graph.num_vertices(),
                                 run.seconds);
      emit(row);
      continue;
    }
    int accepted_true = 0;
    int accepted_false = 0;
    for (int e = 0; e < graph.num_edges(); ++e) {
      if (graph.edge(e).kind != EdgeKind::kLoop || !run.accepted[e]) continue;
      (is_true[e] ? accepted_true : accepted_false) += 1;
    }
    const int accepted_all = accepted_true + accepted_false;
    const double ate = ComponentAte(graph, run.estimate, reference, run.accepted);
    std::string precision = "-";
    std::string recall = "-";
    std::string ratio = "-";
    std::string chi2_text = "-";
    std::string lowest_text = "-";
    std::string chi2_ratio = "-";
    if (labelled) {
      // Four digits where three would round a wrong acceptance away (2099 of 2100: 0.9995).
      precision =
          accepted_all == 0     ? "-"
          : accepted_false == 0 ? Fixed(1.0, 3)
          : accepted_true == 0
              ? Fixed(0.0, 3)
              : Fixed(std::min(0.9999, static_cast<double>(accepted_true) / accepted_all), 4);
      recall = true_loops > 0 ? Fixed(static_cast<double>(accepted_true) / true_loops, 3) : "-";
      if (c.reference != ReferenceKind::kOracle && oracle_value > 0.0) {
        ratio = Fixed(ate / oracle_value, 2);
      }
      chi2_text = fmt::format("{:.6g}", chi2[m]);
      lowest_text = fmt::format("{:.6g}", lowest_chi2);
      chi2_ratio = Fixed(chi2[m] / lowest_chi2, 3);
    }
    std::string latency = "- | - | - | -";
    std::string steps = "-";
    if (run.steps >= 0) {
      std::vector<double> sorted = run.step_ms;
      std::sort(sorted.begin(), sorted.end());
      steps = fmt::format(
          "{} ({} solves{})",
          run.steps,
          run.solves,
          run.capped_steps > 0 ? fmt::format(", {} capped", run.capped_steps) : std::string());
      if (!sorted.empty()) {
        latency = fmt::format("{:.1f} | {:.1f} | {:.1f} | {:.1f}",
                              Percentile(sorted, 0.50),
                              Percentile(sorted, 0.90),
                              Percentile(sorted, 0.99),
                              sorted.back());
      }
    } else if (method.IsRobustKernel()) {
      steps = fmt::format("- ({} solves)", run.solves);
    }
    row.cpu_seconds = run.cpu_seconds;
    row.labelled = labelled;
    row.accepted_wrong = accepted_false;
    row.recall = true_loops > 0 ? static_cast<double>(accepted_true) / true_loops : 1.0;
    row.chi2_ratio = labelled ? chi2[m] / lowest_chi2 : 1.0;
    row.order_diffs = order_diffs[m];
    const std::string faults = FaultsFound(method, graph, is_fault, run.odometry_faults);
    row.markdown = fmt::format(
        "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} "
        "| {} | {} | {:.2f} | {:.2f} | {:.0f} | {} | {} |",
        c.name,
        outlier_note,
        MethodName(method),
        DofName(method),
        VariantName(method),
        graph.num_vertices(),
        labelled ? fmt::format("{}/{}", true_loops, false_loops)
                 : fmt::format("{} (?)", true_loops + false_loops),
        accepted_all,
        labelled ? std::to_string(accepted_true) : "-",
        labelled ? std::to_string(accepted_false) : "-",
        precision,
        recall,
        faults,
        chi2_text,
        lowest_text,
        chi2_ratio,
        Fixed(ate, 3),
        oracle_ate,
        ratio,
        reference.label,
        run.seconds,
        run.cpu_seconds,
        run.peak_rss_kb / 1024.0,
        steps,
        latency);
    if (settings.order == RunOrder::kBoth) {
      row.markdown += order_diffs[m] >= 0 ? fmt::format(" {} |", order_diffs[m]) : " - |";
    }
    emit(row);
  }
  return Status::Ok();
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  irrr::TuneAllocatorForSolves();
  std::string shared = "../shared";
  std::string filter;
  std::string methods_option = "irrr";
  std::string graph_dof = "residual_rows";
  std::string variant = "default";
  bool paper_faithful = false;
  std::string output;
  bool list = false;
  irrr::OutlierOptions outliers;
  CLI::App app{
      "irrr-bench-accuracy: precision, recall, ATE and step latency of iRRR / RRR over the "
      "benchmark matrix"};
  app.add_option("--shared", shared, "the shared/ folder holding datasets/")->capture_default_str();
  app.add_option("--filter",
                 filter,
                 "run only the cases whose name contains this (only that case if it is a whole "
                 "case name: intel-random-100 does not select intel-random-1000)");
  app.add_option("--methods", methods_option, "comma-separated: irrr (incremental), rrr (batch)")
      ->capture_default_str();
  app.add_option("--graph-dof", graph_dof, "degrees of freedom of the graph test")
      ->check(CLI::IsMember({"residual_rows", "exact", "both"}))
      ->capture_default_str();
  auto* paper = app.add_flag(
      "--paper-faithful", paper_faithful, "the paper's tests as written (same as --variant paper)");
  app.add_option("--variant", variant, "default (strengthened tests), paper, or both")
      ->check(CLI::IsMember({"default", "paper", "both"}))
      ->excludes(paper)
      ->capture_default_str();
  double alpha = 0.0;
  double variance_factor = -1.0;
  app.add_option("--alpha", alpha, "confidence of every test (default: the variant's)");
  app.add_option("--variance-factor",
                 variance_factor,
                 "fixed variance factor of the information (0: estimated; default: the variant's)");
  int step_budget = -1;
  app.add_option("--step-budget",
                 step_budget,
                 "iRRR: solves one step may use before leaving the rest to later steps (0: "
                 "unbounded; default: the variant's)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--seed", outliers.seed, "seed of the synthetic outliers")->capture_default_str();
  std::string seed_range;
  auto* seeds_option = app.add_option(
      "--seeds",
      seed_range,
      "A-B: run every synthetic case with each seed from A to B, and end with a summary line per "
      "case and method (runs with no wrong loop, the worst run, the median recall, runs whose "
      "chi2 over the clean edges is within 1% of the lowest)");
  app.get_option("--seed")->excludes(seeds_option);
  double method_seconds = 0.0;
  app.add_option("--method-seconds",
                 method_seconds,
                 "stop a method's run after this long and say so in its row (0: never)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--group-size", outliers.group_size, "links per group of grouped outliers")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  const std::map<std::string, irrr::RunOrder> orders = {{"forward", irrr::RunOrder::kForward},
                                                        {"reversed", irrr::RunOrder::kReversed},
                                                        {"both", irrr::RunOrder::kBoth}};
  std::string order = "forward";
  app.add_option("--order",
                 order,
                 "reversed: iRRR and RRR decide on every session driven backwards, scored on the "
                 "original; both: iRRR in both orders, with the loops accepted in one order only")
      ->check(CLI::IsMember({"forward", "reversed", "both"}))
      ->capture_default_str();
  app.add_option("--output", output, "also write a complete Markdown document here");
  app.add_flag("--list", list, "print the case names (after --filter) and exit");
  CLI11_PARSE(app, argc, argv);
  if (paper_faithful) variant = "paper";
  std::vector<uint32_t> seeds = {outliers.seed};
  if (!seed_range.empty()) {
    unsigned first = 0;
    unsigned last = 0;
    char dash = 0;
    std::istringstream range(seed_range);
    if (!(range >> first >> dash >> last) || dash != '-' || last < first || !range.eof()) {
      fmt::print(stderr, "--seeds: expected A-B with A <= B, got '{}'\n", seed_range);
      return EX_USAGE;
    }
    seeds.clear();
    for (unsigned seed = first; seed <= last; ++seed) seeds.push_back(seed);
  }

  std::vector<irrr::Case> cases;
  const std::vector<irrr::Case> all = irrr::AllCases();
  const bool exact = std::any_of(
      all.begin(), all.end(), [&filter](const irrr::Case& c) { return c.name == filter; });
  for (const irrr::Case& c : all) {
    if (exact ? c.name == filter : c.name.find(filter) != std::string::npos) cases.push_back(c);
  }
  if (list) {
    for (const irrr::Case& c : cases) fmt::print("{}\n", c.name);
    return EX_OK;
  }
  if (cases.empty()) {
    fmt::print(stderr, "no case name contains '{}' (see --list)\n", filter);
    return EX_USAGE;
  }

  irrr::Settings settings;
  settings.shared = shared;
  settings.outliers = outliers;
  settings.method_seconds = method_seconds;
  settings.order = orders.at(order);
  std::vector<irrr::GraphDegreesOfFreedom> dofs;
  if (graph_dof != "exact") dofs.push_back(irrr::GraphDegreesOfFreedom::kResidualRows);
  if (graph_dof != "residual_rows") dofs.push_back(irrr::GraphDegreesOfFreedom::kExact);
  std::vector<bool> variants;
  if (variant != "paper") variants.push_back(false);
  if (variant == "paper" || variant == "both") variants.push_back(true);
  std::stringstream method_names(methods_option);
  std::string name;
  const std::map<std::string, irrr::Algorithm> algorithms = {{"irrr", irrr::Algorithm::kIrrr},
                                                             {"rrr", irrr::Algorithm::kRrr},
                                                             {"dcs", irrr::Algorithm::kDcs},
                                                             {"gnc", irrr::Algorithm::kGnc}};
  while (std::getline(method_names, name, ',')) {
    const auto found = algorithms.find(name);
    if (found == algorithms.end()) {
      fmt::print(stderr, "--methods: unknown method '{}' (irrr, rrr, dcs, gnc)\n", name);
      return EX_USAGE;
    }
    irrr::Method method;
    method.algorithm = found->second;
    method.alpha = alpha;
    method.variance_factor = variance_factor;
    method.step_budget = step_budget;
    if (method.IsRobustKernel()) {
      settings.methods.push_back(method);  // neither graph dof nor variant applies
      continue;
    }
    for (irrr::GraphDegreesOfFreedom dof : dofs) {
      for (bool p : variants) {
        method.dof = dof;
        method.paper_faithful = p;
        settings.methods.push_back(method);
      }
    }
  }
  if (settings.methods.empty()) {
    fmt::print(stderr, "--methods: no method given\n");
    return EX_USAGE;
  }

  irrr::ReportContext context;
  context.command = irrr::QuotedCommand(argc, argv);
  context.machine = irrr::MachineDescription();
  context.date = irrr::UtcNow();
  context.outliers = settings.outliers;
  context.order = settings.order;
  context.sweep = seeds.size() > 1;
  context.planned_rows = static_cast<int>(cases.size() * settings.methods.size());
  std::vector<irrr::Row> rows;
  std::vector<std::string> failures;
  auto write_document = [&]() {
    if (output.empty()) return irrr::Status::Ok();
    context.outliers = settings.outliers;  // the seed being run
    return irrr::WriteReport(output, context, rows, failures);
  };

  fmt::print("{} case(s) x {} method configuration(s); {}\n\n",
             cases.size(),
             settings.methods.size(),
             context.machine);
  fmt::print("{}", irrr::TableHeader(settings.order));
  std::fflush(stdout);
  bool write_failed = false;
  auto emit = [&](const irrr::Row& row) {
    rows.push_back(row);
    fmt::print("{}\n", row.markdown);
    std::fflush(stdout);
    if (irrr::Status s = write_document(); !s.ok() && !write_failed) {
      fmt::print(stderr, "{}\n", s.message());
      write_failed = true;
    }
  };
  for (const irrr::Case& c : cases) {
    // Only the synthetic failures depend on the seed.
    const size_t case_seeds = c.kind == irrr::CaseKind::kSynthetic ? seeds.size() : 1;
    for (size_t k = 0; k < case_seeds; ++k) {
      settings.outliers.seed = seeds[k];
      const std::string path = shared + "/" + c.graph;
      irrr::FileFormat format;
      int dimension = 0;
      irrr::Status status = irrr::InspectGraphFile(path, &format, &dimension);
      if (status.ok()) {
        status = dimension == 2 ? irrr::RunCase<irrr::Pose2>(c, settings, emit)
                                : irrr::RunCase<irrr::Pose3>(c, settings, emit);
      }
      if (!status.ok()) {
        failures.push_back(fmt::format("{} (seed {}): {}", c.name, seeds[k], status.message()));
        fmt::print(stderr, "{}: failed: {}\n", c.name, status.message());
        if (irrr::Status s = write_document(); !s.ok() && !write_failed) {
          fmt::print(stderr, "{}\n", s.message());
          write_failed = true;
        }
      }
    }
  }
  const std::string summary = irrr::SummaryLines(rows, context.sweep);
  if (!summary.empty()) fmt::print("\n{}", summary);
  if (write_failed) return EX_CANTCREAT;
  return failures.empty() ? EX_OK : EX_DATAERR;
}
