// irrr-bench-speed: how fast incremental iRRR is on the public datasets with synthetic wrong
// loops, beside one batch solve of the same graph with every loop trusted (`irrr-batch --method
// none`: what a back-end without outlier rejection pays once).
//
// For every case (a dataset plus MakeOutliers' wrong loops, or the paper's Intel experiment as
// shipped in data/) and every engine asked for, the whole graph is replayed in arrival order with
// every step timed, in a child process of its own: its peak memory is its own, and a run over the
// time budget is stopped. Printed per run: total time, step latency percentiles, optimizations
// per step, peak memory, the wrong loops accepted and the true ones missed; beside them the batch
// solve's time and memory.

#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <sysexits.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <fmt/core.h>
#include <CLI/CLI.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/loop_csv.h"
#include "clients/common/progress_line.h"
#include "core/irrr.h"
#include "core/optimizer.h"
#include "core/outliers.h"
#include "daemon/common/allocator.h"

namespace irrr {
namespace {

struct Dataset {
  std::string name;
  std::string path;  // relative to the shared folder, or (in_project) to the project
  bool in_project = false;
  // The paper's experiment: the file holds its wrong loops (labelled by line in `labels`), and
  // its cluster gap is the paper's.
  std::string labels;
  double cluster_gap = 0.0;  // 0: the options' own
};

const std::vector<Dataset>& Datasets() {
  static const std::vector<Dataset> datasets = {
      {"manhattan", "datasets/manhattan/vertigo/Olson/manhattanOlson3500.g2o", false, "", 0.0},
      {"city10000", "datasets/city10000/vertigo/city10000.g2o", false, "", 0.0},
      {"sphere2500", "datasets/sphere2500/vertigo/sphere2500.g2o", false, "", 0.0},
      {"intel", "datasets/intel/vertigo/intel.g2o", false, "", 0.0},
      {"intel-4sessions",
       "data/intel_4sessions_grouped.g2o",
       true,
       "data/intel_4sessions_grouped_labels.csv",
       10.0},
  };
  return datasets;
}

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Nearest-rank percentile of sorted values.
double Percentile(const std::vector<double>& sorted, double p) {
  if (sorted.empty()) return 0.0;
  const auto rank = static_cast<size_t>(std::ceil(p * static_cast<double>(sorted.size())));
  return sorted[std::min(sorted.size() - 1, rank == 0 ? 0 : rank - 1)];
}

// A field of /proc/self/status in kB (VmRSS, VmHWM), or -1.
long StatusKb(const std::string& field) {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(field + ":", 0) == 0) return std::stol(line.substr(field.size() + 1));
  }
  return -1;
}

struct RunResult {
  bool finished = false;  // every step ran (else the budget stopped it, or it failed)
  int poses_in = 0;       // poses fed when it ended
  int poses = 0;
  double seconds = 0.0;
  int steps = 0;
  long solves = 0;
  int max_solves = 0;   // in one step
  long iterations = 0;  // of the optimizations run
  std::vector<double> step_ms;
  long start_kb = 0;  // RSS when the run started (the graph, loaded by the parent, included)
  long peak_kb = 0;   // VmHWM at the end
  std::vector<int> states;
};

struct Variant {
  std::string name;
  IrrrOptions options;
};

// "warm-budget": the warm engine with a step budget (--step-budget).
std::vector<Variant> Variants(int step_budget) {
  IrrrOptions budgeted;
  budgeted.step_budget = step_budget;
  return {
      {"warm", IrrrOptions()}, {"warm-budget", budgeted}, {"paper", IrrrOptions::PaperFaithful()}};
}

// Stops between steps once `budget_s` is spent (the figures then cover the steps that ran).
template <class Pose>
RunResult RunIncremental(const PoseGraph<Pose>& graph,
                         const IrrrOptions& options,
                         double budget_s) {
  RunResult result;
  result.poses = graph.num_vertices();
  result.start_kb = StatusKb("VmRSS");
  const auto start = std::chrono::steady_clock::now();
  Irrr<Pose> irrr(options);
  GraphReplay<Pose> replay(graph, &irrr);
  // On a terminal, a progress line on stderr (nothing otherwise).
  ProgressLine line;
  ReplayProgress<Pose> progress(graph, "  iRRR", &line);
  result.finished =
      ReplayTimed(graph, &irrr, &replay, &progress, [&](const StepResult& step, double ms) {
        result.step_ms.push_back(ms);
        result.solves += step.solves;
        result.iterations += step.iterations;
        result.max_solves = std::max(result.max_solves, step.solves);
        return SecondsSince(start) <= budget_s;
      });
  result.poses_in = progress.poses_in();
  line.Clear();
  result.seconds = SecondsSince(start);
  result.steps = irrr.num_steps();
  result.peak_kb = StatusKb("VmHWM");
  if (result.finished) {
    for (const LoopDecision& d : replay.Decisions()) {
      result.states.push_back(static_cast<int>(d.state));
    }
  }
  return result;
}

// Runs `run` in a child process; a child still running after `kill_after_s` is killed (an empty
// result).
template <class Run>
RunResult InChild(const Run& run, double kill_after_s) {
  int fds[2];
  if (pipe(fds) != 0) return RunResult();
  const pid_t pid = fork();
  if (pid == 0) {
    close(fds[0]);
    const RunResult r = run();
    std::ostringstream out;
    out.precision(17);
    out << r.finished << ' ' << r.poses_in << ' ' << r.poses << ' ' << r.seconds << ' ' << r.steps
        << ' ' << r.solves << ' ' << r.max_solves << ' ' << r.iterations << ' ' << r.start_kb << ' '
        << r.peak_kb << ' ' << r.step_ms.size();
    for (double ms : r.step_ms) out << ' ' << ms;
    out << ' ' << r.states.size();
    for (int s : r.states) out << ' ' << s;
    const std::string text = out.str();
    size_t written = 0;
    while (written < text.size()) {
      const ssize_t n = write(fds[1], text.data() + written, text.size() - written);
      if (n <= 0) break;
      written += static_cast<size_t>(n);
    }
    close(fds[1]);
    _exit(0);
  }
  close(fds[1]);
  RunResult result;
  if (pid < 0) {
    close(fds[0]);
    return result;
  }
  // Read while waiting, so that a large result cannot block the child on a full pipe.
  std::string text;
  const auto start = std::chrono::steady_clock::now();
  bool killed = false;
  fcntl(fds[0], F_SETFL, O_NONBLOCK);
  while (true) {
    char buffer[65536];
    const ssize_t n = read(fds[0], buffer, sizeof buffer);
    if (n > 0) {
      text.append(buffer, static_cast<size_t>(n));
      continue;
    }
    if (n == 0) break;  // the child closed its end
    if (!killed && SecondsSince(start) > kill_after_s) {
      kill(pid, SIGKILL);
      killed = true;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  if (killed || !WIFEXITED(status) || WEXITSTATUS(status) != 0 || text.empty()) return result;
  std::istringstream in(text);
  size_t count = 0;
  in >> result.finished >> result.poses_in >> result.poses >> result.seconds >> result.steps >>
      result.solves >> result.max_solves >> result.iterations >> result.start_kb >>
      result.peak_kb >> count;
  result.step_ms.resize(count);
  for (double& ms : result.step_ms) in >> ms;
  in >> count;
  result.states.resize(count);
  for (int& s : result.states) in >> s;
  if (!in) return RunResult();
  return result;
}

// Bytes the graph itself takes: vertices, edges (with their information) and one estimate.
template <class Pose>
double GraphMegabytes(const PoseGraph<Pose>& graph) {
  const double bytes =
      static_cast<double>(graph.num_vertices()) *
          static_cast<double>(sizeof(Vertex) + sizeof(Pose)) +
      static_cast<double>(graph.num_edges()) * static_cast<double>(sizeof(Edge<Pose>));
  return bytes / (1024.0 * 1024.0);
}

struct Settings {
  std::string shared = "../shared";
  std::string project = IRRR_SOURCE_DIR;
  std::vector<std::string> datasets = {"manhattan", "city10000", "sphere2500"};
  std::vector<int> counts = {1000};
  OutlierOptions outliers;
  std::vector<Variant> variants;
  double budget_s = 600.0;
};

template <class Pose>
int RunCase(const Dataset& dataset, int count, const Settings& settings, std::string* table) {
  const std::string path =
      (dataset.in_project ? settings.project : settings.shared) + "/" + dataset.path;
  FileFormat format;
  int dimension = 0;
  GraphFile<Pose> file;
  PoseGraph<Pose> graph;
  std::vector<int> graph_edge_of_file_edge;
  if (Status s = InspectGraphFile(path, &format, &dimension); !s.ok()) {
    fmt::print(stderr, "irrr-bench-speed: {}\n", s.message());
    return EX_NOINPUT;
  }
  if (Status s =
          LoadPoseGraph(path, format, ReadOptions(), &file, &graph, &graph_edge_of_file_edge);
      !s.ok()) {
    fmt::print(stderr, "irrr-bench-speed: {}\n", s.message());
    return EX_DATAERR;
  }
  // Which loops are wrong: the synthetic ones appended here, or the labelled ones of the file.
  std::vector<char> wrong(graph.num_edges(), 0);
  std::string case_name = dataset.name;
  if (!dataset.labels.empty()) {
    std::ifstream in(settings.project + "/" + dataset.labels);
    std::vector<LabelRow> labels;
    if (Status s = ReadLabelsCsv(in, &labels); !s.ok()) {
      fmt::print(stderr, "irrr-bench-speed: {}: {}\n", dataset.labels, s.message());
      return EX_DATAERR;
    }
    int wrong_count = 0;
    for (const LabelRow& row : labels) {
      if (!row.outlier) continue;
      wrong[graph_edge_of_file_edge[row.edge_index]] = 1;
      ++wrong_count;
    }
    case_name = fmt::format("{} (+ {} wrong, in the file)", dataset.name, wrong_count);
  } else {
    OutlierOptions outliers = settings.outliers;
    outliers.count = count;
    std::vector<OutlierLink<Pose>> links;
    if (Status s = MakeOutliers(graph, outliers, &links); !s.ok()) {
      fmt::print(stderr, "irrr-bench-speed: {}: {}\n", dataset.name, s.message());
      return EX_DATAERR;
    }
    for (const OutlierLink<Pose>& link : links) {
      IRRR_CHECK(
          graph.AddLoop(link.from, link.to, link.measurement, link.information, nullptr).ok());
    }
    wrong.resize(graph.num_edges(), 1);
    case_name =
        fmt::format("{} + {} {}", dataset.name, links.size(), OutlierModeName(outliers.mode));
  }
  int true_loops = 0;
  for (int e = 0; e < graph.num_edges(); ++e) {
    true_loops += graph.edge(e).kind == EdgeKind::kLoop && !wrong[e] ? 1 : 0;
  }

  // The reference point for memory and time: one Gauss-Newton solve of the whole graph (every
  // edge, from the file's initial guess) in a child of its own.
  const RunResult batch = InChild(
      [&graph]() {
        RunResult r;
        r.start_kb = StatusKb("VmRSS");
        std::vector<Pose> x = graph.initial_estimate();
        Optimizer<Pose> optimizer;
        const auto start = std::chrono::steady_clock::now();
        const OptimizerSummary summary =
            optimizer.Solve(graph, std::vector<char>(graph.num_edges(), 1), &x);
        r.seconds = SecondsSince(start);
        r.iterations = summary.iterations;
        r.peak_kb = StatusKb("VmHWM");
        r.finished = true;
        return r;
      },
      10 * settings.budget_s);
  const double graph_mb = GraphMegabytes(graph);
  const double batch_mb = static_cast<double>(batch.peak_kb - batch.start_kb) / 1024.0;
  fmt::print(stderr,
             "{}: {} poses, {} edges; graph {:.1f} MB; one batch solve (every loop trusted) "
             "{:.2f} s in {} iterations, +{:.1f} MB\n",
             case_name,
             graph.num_vertices(),
             graph.num_edges(),
             graph_mb,
             batch.seconds,
             batch.iterations,
             batch_mb);

  for (const Variant& variant : settings.variants) {
    IrrrOptions options = variant.options;
    if (dataset.cluster_gap > 0.0) options.cluster_gap = dataset.cluster_gap;
    const double budget_s = settings.budget_s;
    // A step can outlast the budget by far (the budget is checked between steps).
    RunResult r =
        InChild([&]() { return RunIncremental(graph, options, budget_s); }, 10 * budget_s);
    std::vector<double> sorted = r.step_ms;
    std::sort(sorted.begin(), sorted.end());
    const bool ran = r.poses > 0;  // finished, or stopped by the budget with figures
    std::string accuracy = "-";
    if (r.finished) {
      int accepted_wrong = 0;
      int missed_true = 0;
      for (int e = 0; e < graph.num_edges(); ++e) {
        if (graph.edge(e).kind != EdgeKind::kLoop) continue;
        const bool accepted = r.states[e] == static_cast<int>(LoopState::kAccepted);
        accepted_wrong += accepted && wrong[e] ? 1 : 0;
        missed_true += !accepted && !wrong[e] ? 1 : 0;
      }
      accuracy = fmt::format("{} / {} of {}", accepted_wrong, missed_true, true_loops);
    }
    const std::string total =
        !ran ? "failed"
        : r.finished
            ? fmt::format("{:.2f}", r.seconds)
            : fmt::format("> {:.0f} (stopped at pose {} of {})", r.seconds, r.poses_in, r.poses);
    const std::string row =
        ran ? fmt::format(
                  "| {} | {} | {} | {:.2f} | {:.2f} | {} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | "
                  "{:.1f} | {} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {} |\n",
                  case_name,
                  variant.name,
                  total,
                  batch.seconds,
                  r.finished && batch.seconds > 0.0 ? r.seconds / batch.seconds : 0.0,
                  r.steps,
                  Percentile(sorted, 0.50),
                  Percentile(sorted, 0.90),
                  Percentile(sorted, 0.99),
                  sorted.empty() ? 0.0 : sorted.back(),
                  r.steps > 0 ? static_cast<double>(r.solves) / r.steps : 0.0,
                  r.max_solves,
                  static_cast<double>(r.peak_kb) / 1024.0,
                  static_cast<double>(r.peak_kb - r.start_kb) / 1024.0,
                  graph_mb,
                  batch_mb,
                  accuracy)
            : fmt::format(
                  "| {} | {} | failed | {:.2f} | - | - | - | - | - | - | - | - | - | - | "
                  "{:.1f} | {:.1f} | - |\n",
                  case_name,
                  variant.name,
                  batch.seconds,
                  graph_mb,
                  batch_mb);
    fmt::print("{}", row);
    std::fflush(stdout);
    *table += row;
  }
  return EX_OK;
}

std::vector<std::string> SplitCommas(const std::string& text) {
  std::vector<std::string> parts;
  std::stringstream in(text);
  std::string part;
  while (std::getline(in, part, ',')) {
    if (!part.empty()) parts.push_back(part);
  }
  return parts;
}

int Main(int argc, char** argv) {
  TuneAllocatorForSolves();
  CLI::App app(
      "irrr-bench-speed: incremental iRRR's speed and memory beside one trusting batch solve");
  Settings settings;
  std::string datasets = "manhattan,city10000,sphere2500";
  std::string counts = "1000";
  std::string variants = "warm";
  std::string mode = "random";
  std::string output;
  int step_budget = 25;
  app.add_option("--shared", settings.shared, "the shared/ folder holding datasets/")
      ->capture_default_str();
  app.add_option("--datasets",
                 datasets,
                 "comma-separated: manhattan, city10000, sphere2500, intel, intel-4sessions (the "
                 "paper's experiment, shipped in data/)")
      ->capture_default_str();
  app.add_option("--outliers", counts, "comma-separated wrong-loop counts")->capture_default_str();
  app.add_option("--mode", mode, "outlier mode")
      ->check(CLI::IsMember({"random", "local", "random-grouped", "local-grouped"}))
      ->capture_default_str();
  app.add_option("--group-size", settings.outliers.group_size, "links per group (grouped modes)")
      ->capture_default_str();
  app.add_option("--seed", settings.outliers.seed, "seed of the wrong loops")
      ->capture_default_str();
  app.add_option("--variants", variants, "comma-separated engines: warm, warm-budget, paper")
      ->capture_default_str();
  app.add_option("--step-budget", step_budget, "warm-budget: solves per step (irrr.step_budget)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--budget",
                 settings.budget_s,
                 "seconds after which a run stops (between steps; its figures cover the steps run)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--output", output, "also write the table (Markdown) here");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }
  settings.datasets = SplitCommas(datasets);
  for (const std::string& name : SplitCommas(variants)) {
    bool known = false;
    for (const Variant& v : Variants(step_budget)) {
      if (v.name == name) {
        settings.variants.push_back(v);
        known = true;
      }
    }
    if (!known) {
      fmt::print(stderr, "irrr-bench-speed: unknown variant \"{}\"\n", name);
      return EX_USAGE;
    }
  }
  settings.counts.clear();
  for (const std::string& c : SplitCommas(counts)) settings.counts.push_back(std::stoi(c));
  for (OutlierMode m : {OutlierMode::kRandom,
                        OutlierMode::kLocal,
                        OutlierMode::kRandomGrouped,
                        OutlierMode::kLocalGrouped}) {
    if (mode == OutlierModeName(m)) settings.outliers.mode = m;
  }

  std::string table =
      "| case | engine | total s | batch solve s | total / batch | steps | step p50 ms | p90 ms | "
      "p99 ms | max ms | solves/step | max solves | peak MB | growth MB | graph MB | batch solve "
      "MB | wrong accepted / true missed |\n"
      "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  fmt::print("{}", table);
  for (const std::string& name : settings.datasets) {
    const auto it = std::find_if(
        Datasets().begin(), Datasets().end(), [&](const Dataset& d) { return d.name == name; });
    if (it == Datasets().end()) {
      fmt::print(stderr, "irrr-bench-speed: unknown dataset {}\n", name);
      return EX_USAGE;
    }
    const std::string path = (it->in_project ? settings.project : settings.shared) + "/" + it->path;
    FileFormat format;
    int dimension = 0;
    if (Status s = InspectGraphFile(path, &format, &dimension); !s.ok()) {
      fmt::print(stderr, "irrr-bench-speed: {}\n", s.message());
      return EX_NOINPUT;
    }
    // The paper's experiment carries its own wrong loops: one run, whatever the counts.
    const std::vector<int> counts_here = it->labels.empty() ? settings.counts : std::vector<int>{0};
    for (int count : counts_here) {
      const int code = dimension == 2 ? RunCase<Pose2>(*it, count, settings, &table)
                                      : RunCase<Pose3>(*it, count, settings, &table);
      if (code != EX_OK) return code;
    }
  }
  if (!output.empty()) {
    std::ofstream out(output);
    out << table;
    if (!out) {
      fmt::print(stderr, "irrr-bench-speed: {}: cannot write\n", output);
      return EX_CANTCREAT;
    }
  }
  return EX_OK;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) { return irrr::Main(argc, argv); }
