// irrr-bench-accuracy: which loops iRRR / batch RRR accept on public datasets, and how far the
// result is from the ground truth and from the oracle (the graph with exactly the true loops).
//
//   irrr-bench-accuracy [--shared ../shared] [--filter SUBSTRING] [--methods irrr,rrr]
//                       [--graph-dof residual_rows|exact|both]
//                       [--paper-faithful | --variant default|paper|both]
//                       [--seed N] [--group-size N] [--output FILE] [--list]
//
// Cases: synthetic outliers (core/outliers.h, appended to a clean graph, labels known) on
// Manhattan, Intel, City10000 and Sphere2500; the RRR author's KITTI 00 / 05 place-recognition
// graphs at five alpha levels (per-file labels); Bicocca 25b at five alpha levels (no labels; ATE
// against GPS associated by time); Bovisa 04 and 06 (no labels; ATE against one GPS fix per 10
// poses). Each row goes to stdout as soon as it is done; --output writes a complete Markdown
// document (rewritten after every row, so an interrupted run keeps its rows).

#include <sched.h>
#include <sysexits.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include <fmt/core.h>
#include <CLI/CLI.hpp>

#include "clients/bench/reference_files.h"
#include "clients/common/graph_files.h"
#include "clients/common/progress_line.h"
#include "core/irrr.h"
#include "core/optimizer.h"
#include "core/outliers.h"
#include "core/trajectory_metrics.h"
#include "daemon/common/allocator.h"

namespace irrr {
namespace {

enum class CaseKind {
  kSynthetic,  // a clean graph (every loop true) plus generated outliers
  kLabelled,   // a place-recognition graph with a file of its true loops ("i j" per line)
  kUnlabelled  // a place-recognition graph without labels, ATE against GPS
};

enum class ReferenceKind {
  kPoseLines,     // one "x y yaw" line per vertex (Vertigo *_nodes_groundTruth.dat)
  kGraphFile,     // a pose-graph file (edges-only files chained along their odometry)
  kIsamEdges,     // iSAM EDGE2/EDGE3 noise-free edges: chain the sequential ones
  kOracle,        // no ground truth: the oracle's optimum is the reference
  kTimestampGps,  // Bicocca: vertex k <-> timestamps line k, nearest GPS row in time
  kStridedGps,    // Bovisa: the GPS graph's vertex k <-> graph vertex id kGpsStride * k
};

struct Case {
  std::string name;
  CaseKind kind = CaseKind::kSynthetic;
  std::string graph;  // paths relative to the shared folder
  ReferenceKind reference = ReferenceKind::kOracle;
  std::string reference_path;
  std::string labels;      // kLabelled: true loops
  std::string timestamps;  // kTimestampGps: one time per graph vertex
  OutlierMode mode = OutlierMode::kRandom;
  int outliers = 0;
  bool wrong_only = false;  // kLabelled: the true loops removed (a correct answer accepts none)
};

std::vector<Case> AllCases() {
  struct Clean {
    std::string name;
    std::string graph;
    ReferenceKind reference;
    std::string reference_path;
  };
  const std::vector<Clean> clean = {
      {"manhattan",
       "datasets/manhattan/vertigo/Olson/manhattanOlson3500.g2o",
       ReferenceKind::kPoseLines,
       "datasets/manhattan/vertigo/groundTruth/manhattanOlson3500_nodes_groundTruth.dat"},
      {"intel", "datasets/intel/vertigo/intel.g2o", ReferenceKind::kOracle, ""},
      {"city10000",
       "datasets/city10000/vertigo/city10000.g2o",
       ReferenceKind::kIsamEdges,
       "datasets/city10000/isam/groundtruth/city10000_groundtruth.txt"},
      {"sphere2500",
       "datasets/sphere2500/vertigo/sphere2500.g2o",
       ReferenceKind::kIsamEdges,
       "datasets/sphere2500/isam/groundtruth/sphere2500_groundtruth.txt"},
  };
  const OutlierMode modes[] = {OutlierMode::kRandom,
                               OutlierMode::kLocal,
                               OutlierMode::kRandomGrouped,
                               OutlierMode::kLocalGrouped};
  std::vector<Case> cases;
  for (const Clean& c : clean) {
    for (int count : {100, 1000}) {
      for (OutlierMode mode : modes) {
        Case k;
        k.name = fmt::format("{}-{}-{}", c.name, OutlierModeName(mode), count);
        k.kind = CaseKind::kSynthetic;
        k.graph = c.graph;
        k.reference = c.reference;
        k.reference_path = c.reference_path;
        k.mode = mode;
        k.outliers = count;
        cases.push_back(k);
      }
    }
  }
  const char* alphas[] = {"0.00", "0.25", "0.50", "0.75", "1.00"};
  // KITTI 00 and 05; and from 00 a real sequence whose hypotheses are all wrong (its labelled
  // true loops removed).
  std::vector<Case> wrong_only;
  for (const char* sequence : {"00", "05"}) {
    for (const char* alpha : alphas) {
      const std::string folder = fmt::format("datasets/kitti_rrr/{}/kitti_{}", sequence, sequence);
      Case k;
      k.name = fmt::format("kitti{}-alpha-{}", sequence, alpha);
      k.kind = CaseKind::kLabelled;
      k.graph = fmt::format("{}_alpha_{}.g2o", folder, alpha);
      k.labels = fmt::format("{}_alpha_{}_GT_LC.txt", folder, alpha);
      k.reference = ReferenceKind::kGraphFile;
      k.reference_path = folder + "_GT.g2o";
      cases.push_back(k);
      if (std::string(sequence) == "00") {
        k.name = fmt::format("kitti00-wrong-only-alpha-{}", alpha);
        k.wrong_only = true;
        wrong_only.push_back(k);
      }
    }
  }
  cases.insert(cases.end(), wrong_only.begin(), wrong_only.end());
  for (const char* alpha : {"0.000", "0.250", "0.500", "0.750", "1.000"}) {
    Case k;
    k.name = fmt::format("bicocca25b-alpha-{}", alpha);
    k.kind = CaseKind::kUnlabelled;
    k.graph = fmt::format("datasets/rrr_bicocca25b/B25b_{}.g2o", alpha);
    k.reference = ReferenceKind::kTimestampGps;
    k.reference_path = "datasets/rrr_bicocca25b/timestamps/Bicocca_2009-02-25b-GT-extended.csv";
    k.timestamps = "datasets/rrr_bicocca25b/timestamps/B25b_timestamps.txt";
    cases.push_back(k);
  }
  // Bovisa (RAWSEEDS, the RRR author's bag-of-words loops): never tuned on. Its GPS files hold
  // one fix per 10 odometry poses: their step lengths match the odometry's 10-pose steps (1718 m
  // against 1714 m over Bovisa 04, 1893 against 1882 over 06).
  for (const char* session : {"04", "06"}) {
    Case k;
    k.name = fmt::format("bovisa{}", session);
    k.kind = CaseKind::kUnlabelled;
    k.graph = fmt::format("datasets/rrr_bovisa/Bovisa{}_odometry_bow_tr.g2o", session);
    k.reference = ReferenceKind::kStridedGps;
    k.reference_path = fmt::format("datasets/rrr_bovisa/Bovisa{}_GT_GPS.g2o", session);
    cases.push_back(k);
  }
  return cases;
}

// One algorithm configuration of the matrix.
struct Method {
  bool incremental = true;  // iRRR (Irrr driven step by step) or batch RRR (RunBatchRrr)
  GraphDegreesOfFreedom dof = GraphDegreesOfFreedom::kResidualRows;
  bool paper_faithful = false;
  double alpha = 0.0;             // > 0: overrides the preset's
  double variance_factor = -1.0;  // >= 0: overrides the default (0: estimated)
};

std::string MethodName(const Method& m) { return m.incremental ? "irrr" : "rrr"; }
std::string DofName(GraphDegreesOfFreedom dof) {
  return dof == GraphDegreesOfFreedom::kResidualRows ? "residual_rows" : "exact";
}
std::string VariantName(const Method& m) { return m.paper_faithful ? "paper" : "default"; }

IrrrOptions OptionsFor(const Method& m) {
  IrrrOptions options = m.paper_faithful ? IrrrOptions::PaperFaithful() : IrrrOptions();
  options.graph_dof = m.dof;
  if (m.alpha > 0.0) options.alpha = m.alpha;
  if (m.variance_factor >= 0.0) options.variance_factor = m.variance_factor;
  return options;
}

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

double ProcessCpuSeconds() {
  timespec now{};
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &now);
  return static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec);
}

// Nearest-rank percentile of sorted values.
double Percentile(const std::vector<double>& sorted, double p) {
  if (sorted.empty()) return 0.0;
  const auto rank = static_cast<size_t>(std::ceil(p * static_cast<double>(sorted.size())));
  return sorted[std::min(sorted.size() - 1, rank == 0 ? 0 : rank - 1)];
}

struct RunResult {
  std::vector<LoopDecision> decisions;
  double seconds = 0.0;
  double cpu_seconds = 0.0;  // of this process: tells a loaded machine from a slow algorithm
  int steps = -1;            // -1: batch
  int solves = 0;
  std::vector<double> step_ms;
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
  int poses_in = 0;
  Irrr<Pose> irrr(options);
  ProgressLine line;
  ReplayProgress<Pose> progress(graph, "  " + label, &line);
  auto run_steps = [&]() {
    while (irrr.HasPendingStep()) {
      const auto step_start = std::chrono::steady_clock::now();
      const StepResult step = irrr.RunStep();
      result.step_ms.push_back(1e3 * SecondsSince(step_start));
      result.solves += step.solves;
      if (line.enabled()) {
        progress.Show(irrr);
      } else if (const double elapsed_s = SecondsSince(start); elapsed_s >= next_progress_s) {
        fmt::print(stderr,
                   "  {}: {:.0f} s, {} steps, pose {}/{}\n",
                   label,
                   elapsed_s,
                   irrr.num_steps(),
                   poses_in,
                   graph.num_vertices());
        next_progress_s = elapsed_s + kProgressSeconds;
      }
    }
  };
  GraphReplay<Pose> replay(graph, &irrr);
  for (const ArrivalEvent& event : ArrivalOrder(graph)) {
    poses_in += event.kind == ArrivalEvent::Kind::kPose ? 1 : 0;
    replay.Apply(event);
    progress.Fed(event);
    progress.Show(irrr);
    run_steps();
  }
  irrr.Flush();
  run_steps();
  line.Clear();
  result.seconds = SecondsSince(start);
  result.steps = irrr.num_steps();
  result.decisions = replay.Decisions();
  *estimate = replay.Estimate();
  return result;
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
  OutlierOptions outliers;  // mode and count come from the case
};

// One finished row of the table, and what the closing summary line needs.
struct Row {
  std::string markdown;
  std::string case_name;
  std::string method;
  std::string configuration;  // graph dof and variant
  double seconds = 0.0;
  double cpu_seconds = 0.0;
};

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
    }
    outlier_note = IsGrouped(c.mode) ? fmt::format("{} {}, groups of {}",
                                                   links.size(),
                                                   OutlierModeName(c.mode),
                                                   std::max(1, options.group_size))
                                     : fmt::format("{} {}", links.size(), OutlierModeName(c.mode));
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

  for (const Method& method : settings.methods) {
    fmt::print(stderr,
               "running {} {} {} {} ...\n",
               c.name,
               MethodName(method),
               DofName(method.dof),
               VariantName(method));
    const IrrrOptions options = OptionsFor(method);
    std::vector<Pose> estimate;
    RunResult run;
    const double cpu_start_s = ProcessCpuSeconds();
    if (method.incremental) {
      run = RunIncrementalTimed(c.name, graph, options, &estimate);
    } else {
      const auto start = std::chrono::steady_clock::now();
      run.decisions = RunBatchRrr(graph, options, &estimate);
      run.seconds = SecondsSince(start);
    }
    run.cpu_seconds = ProcessCpuSeconds() - cpu_start_s;
    std::vector<char> accepted(graph.num_edges(), 0);
    int accepted_true = 0;
    int accepted_false = 0;
    for (int e = 0; e < graph.num_edges(); ++e) {
      if (graph.edge(e).kind != EdgeKind::kLoop) continue;
      if (run.decisions[e].state != LoopState::kAccepted) continue;
      accepted[e] = 1;
      (is_true[e] ? accepted_true : accepted_false) += 1;
    }
    const int accepted_all = accepted_true + accepted_false;
    const double ate = ComponentAte(graph, estimate, reference, accepted);
    std::string precision = "-";
    std::string recall = "-";
    std::string ratio = "-";
    if (labelled) {
      precision =
          accepted_all > 0 ? Fixed(static_cast<double>(accepted_true) / accepted_all, 3) : "-";
      recall = true_loops > 0 ? Fixed(static_cast<double>(accepted_true) / true_loops, 3) : "-";
      if (c.reference != ReferenceKind::kOracle && oracle_value > 0.0) {
        ratio = Fixed(ate / oracle_value, 2);
      }
    }
    std::string latency = "- | - | - | -";
    std::string steps = "-";
    if (run.steps >= 0) {
      std::vector<double> sorted = run.step_ms;
      std::sort(sorted.begin(), sorted.end());
      steps = fmt::format("{} ({} solves)", run.steps, run.solves);
      if (!sorted.empty()) {
        latency = fmt::format("{:.1f} | {:.1f} | {:.1f} | {:.1f}",
                              Percentile(sorted, 0.50),
                              Percentile(sorted, 0.90),
                              Percentile(sorted, 0.99),
                              sorted.back());
      }
    }
    Row row;
    row.case_name = c.name;
    row.method = MethodName(method);
    row.configuration = DofName(method.dof) + ", " + VariantName(method);
    row.seconds = run.seconds;
    row.cpu_seconds = run.cpu_seconds;
    row.markdown = fmt::format(
        "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2f} "
        "| {:.2f} | {} | {} |",
        c.name,
        outlier_note,
        MethodName(method),
        DofName(method.dof),
        VariantName(method),
        graph.num_vertices(),
        labelled ? fmt::format("{}/{}", true_loops, false_loops)
                 : fmt::format("{} (?)", true_loops + false_loops),
        accepted_all,
        labelled ? std::to_string(accepted_true) : "-",
        labelled ? std::to_string(accepted_false) : "-",
        precision,
        recall,
        Fixed(ate, 3),
        oracle_ate,
        ratio,
        reference.label,
        run.seconds,
        run.cpu_seconds,
        steps,
        latency);
    emit(row);
  }
  return Status::Ok();
}

const char* kTableHeader =
    "| case | outliers | method | graph dof | variant | poses | loops true/false | accepted | "
    "acc. true | acc. false | precision | recall | ATE m | oracle ATE m | ATE/oracle | "
    "reference | time s | cpu s | steps | step p50 ms | p90 ms | p99 ms | max ms |\n"
    "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"
    "\n";

std::string CpuModel() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("model name", 0) == 0) {
      const size_t colon = line.find(':');
      if (colon != std::string::npos) {
        size_t start = line.find_first_not_of(' ', colon + 1);
        return start == std::string::npos ? "" : line.substr(start);
      }
    }
  }
  return "unknown";
}

// What nproc prints: the CPUs this process may run on.
int UsableCpus() {
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) == 0) return CPU_COUNT(&set);
  return static_cast<int>(sysconf(_SC_NPROCESSORS_ONLN));
}

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char text[64];
  std::strftime(text, sizeof(text), "%Y-%m-%d %H:%M UTC", &utc);
  return text;
}

// A command line as a shell would accept it back (arguments with odd characters single-quoted).
std::string QuotedCommand(int argc, char** argv) {
  std::string out;
  for (int k = 0; k < argc; ++k) {
    std::string arg = argv[k];
    const bool plain = !arg.empty() && arg.find_first_not_of(
                                           "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
                                           "0123456789-_./=,:+@%") == std::string::npos;
    if (!plain) {
      std::string quoted = "'";
      for (char ch : arg) quoted += ch == '\'' ? std::string("'\\''") : std::string(1, ch);
      arg = quoted + "'";
    }
    out += (k == 0 ? "" : " ") + arg;
  }
  return out;
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
  app.add_option("--seed", outliers.seed, "seed of the synthetic outliers")->capture_default_str();
  app.add_option("--group-size", outliers.group_size, "links per group of grouped outliers")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--output", output, "also write a complete Markdown document here");
  app.add_flag("--list", list, "print the case names (after --filter) and exit");
  CLI11_PARSE(app, argc, argv);
  if (paper_faithful) variant = "paper";

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
  std::vector<irrr::GraphDegreesOfFreedom> dofs;
  if (graph_dof != "exact") dofs.push_back(irrr::GraphDegreesOfFreedom::kResidualRows);
  if (graph_dof != "residual_rows") dofs.push_back(irrr::GraphDegreesOfFreedom::kExact);
  std::vector<bool> variants;
  if (variant != "paper") variants.push_back(false);
  if (variant == "paper" || variant == "both") variants.push_back(true);
  std::stringstream method_names(methods_option);
  std::string name;
  while (std::getline(method_names, name, ',')) {
    if (name != "irrr" && name != "rrr") {
      fmt::print(stderr, "--methods: unknown method '{}' (irrr, rrr)\n", name);
      return EX_USAGE;
    }
    for (irrr::GraphDegreesOfFreedom dof : dofs) {
      for (bool p : variants) {
        settings.methods.push_back({name == "irrr", dof, p, alpha, variance_factor});
      }
    }
  }
  if (settings.methods.empty()) {
    fmt::print(stderr, "--methods: no method given\n");
    return EX_USAGE;
  }

  const std::string command = irrr::QuotedCommand(argc, argv);
  const std::string machine =
      fmt::format("{} CPU(s) (nproc), {}", irrr::UsableCpus(), irrr::CpuModel());
  const std::string date = irrr::UtcNow();
  const int planned = static_cast<int>(cases.size() * settings.methods.size());
  std::vector<irrr::Row> rows;
  std::vector<std::string> failures;
  auto summary_lines = [&]() {
    std::string out;
    for (const irrr::Row& r : rows) {
      if (r.case_name == "manhattan-random-1000" && r.method == "irrr") {
        out += fmt::format(
            "iRRR incremental over Manhattan + 1000 random outliers ({}): {:.2f} s ({:.2f} s "
            "CPU)\n",
            r.configuration,
            r.seconds,
            r.cpu_seconds);
      }
    }
    return out;
  };
  auto write_document = [&]() {
    if (output.empty()) return irrr::Status::Ok();
    return irrr::WriteFileAtomically(output, [&](std::ostream& out) {
      out << "# iRRR accuracy benchmark\n\n";
      out << "Regenerated by `" << command << "` on " << machine << ", " << date << ".\n";
      if (static_cast<int>(rows.size()) < planned || !failures.empty()) {
        out << "\n**Partial:** " << rows.size() << " of " << planned << " rows";
        out << (failures.empty() ? "." : ", failed cases below.") << "\n";
      }
      out << "\nSynthetic outliers: core/outliers.h MakeOutliers appended to the clean graph, seed "
          << settings.outliers.seed << ", grouped modes in groups of "
          << settings.outliers.group_size << ", local window " << settings.outliers.local_window
          << " poses; every original loop is true. iRRR options: alpha "
          << irrr::IrrrOptions().alpha << ", cluster gap " << irrr::IrrrOptions().cluster_gap
          << " poses; variant \"paper\" = the paper's Algorithms 1-2 as written, \"default\" = "
             "the strengthened tests (algorithm-notes, \"Beyond the paper\").\n\n";
      out << "Columns: precision = accepted true / accepted; recall = accepted true / true "
             "loops; ATE = translation RMSE after rigid alignment of each connected component "
             "(odometry + accepted loops) to the reference; oracle = odometry + exactly the true "
             "loops, optimized from dead reckoning; time = wall time of the whole run (iRRR: input "
             "fed in arrival order and every step; RRR: batch), cpu = this process's CPU time over "
             "the same span (lower than time when the machine is shared); steps = iRRR steps "
             "(closed clusters) and their "
             "optimizations; step latency = wall time of each RunStep. Reference \"GT (iSAM "
             "chain)\": the noise-free sequential edges of the iSAM ground-truth file chained from "
             "the origin; \"oracle\": no ground truth exists, the oracle is the reference; \"GPS "
             "n/N\": Bicocca vertices with a GPS fix within "
          << irrr::kGpsMatchSeconds
          << " s (vertex k has time line k of B25b_timestamps.txt), Bovisa vertices 0, "
          << irrr::kGpsStride << ", " << 2 * irrr::kGpsStride
          << ", ... (fix k of the GT_GPS file); Bicocca and Bovisa ship no loop labels, so their "
             "precision, recall and oracle are \"-\".\n\n";
      out << irrr::kTableHeader;
      for (const irrr::Row& r : rows) out << r.markdown << "\n";
      const std::string summary = summary_lines();
      if (!summary.empty()) out << "\n" << summary;
      if (!failures.empty()) {
        out << "\nFailed cases:\n\n";
        for (const std::string& f : failures) out << "* " << f << "\n";
      }
      return irrr::Status::Ok();
    });
  };

  fmt::print("{} case(s) x {} method configuration(s); {}\n\n",
             cases.size(),
             settings.methods.size(),
             machine);
  fmt::print("{}", irrr::kTableHeader);
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
    const std::string path = shared + "/" + c.graph;
    irrr::FileFormat format;
    int dimension = 0;
    irrr::Status status = irrr::InspectGraphFile(path, &format, &dimension);
    if (status.ok()) {
      status = dimension == 2 ? irrr::RunCase<irrr::Pose2>(c, settings, emit)
                              : irrr::RunCase<irrr::Pose3>(c, settings, emit);
    }
    if (!status.ok()) {
      failures.push_back(c.name + ": " + status.message());
      fmt::print(stderr, "{}: failed: {}\n", c.name, status.message());
      if (irrr::Status s = write_document(); !s.ok() && !write_failed) {
        fmt::print(stderr, "{}\n", s.message());
        write_failed = true;
      }
    }
  }
  const std::string summary = summary_lines();
  if (!summary.empty()) fmt::print("\n{}", summary);
  if (write_failed) return EX_CANTCREAT;
  return failures.empty() ? EX_OK : EX_DATAERR;
}
