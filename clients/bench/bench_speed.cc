// irrr-bench-speed: how fast incremental iRRR is on the public datasets with synthetic wrong
// loops, and what each speed-up buys (issue "Make iRRR fast").
//
// For every case (a dataset plus MakeOutliers' wrong loops) and every variant (all speed-ups on,
// then each switched off in turn), the whole graph is replayed in arrival order with every step
// timed, in a child process of its own: its peak memory is its own, and a run over the time budget
// is stopped. Printed per run: total time, step latency percentiles, optimizations per step, their
// iterations per optimization and the time per iteration (where the time goes), peak memory; and
// whether its decisions equal those of the first variant, loop for loop (exit code 70 if any
// differs, so that the benchmark is also the test of "identical decisions").

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
#include "clients/common/progress_line.h"
#include "core/irrr.h"
#include "core/optimizer.h"
#include "core/outliers.h"
#include "daemon/common/allocator.h"
#include "daemon/common/thread_pool.h"

namespace irrr {
namespace {

struct Dataset {
  std::string name;
  std::string path;  // relative to the shared folder
};

const std::vector<Dataset>& Datasets() {
  static const std::vector<Dataset> datasets = {
      {"manhattan", "datasets/manhattan/vertigo/Olson/manhattanOlson3500.g2o"},
      {"city10000", "datasets/city10000/vertigo/city10000.g2o"},
      {"sphere2500", "datasets/sphere2500/vertigo/sphere2500.g2o"},
      {"intel", "datasets/intel/vertigo/intel.g2o"},
  };
  return datasets;
}

struct Variant {
  std::string name;
  IrrrOptions options;
  int threads = 1;
  bool compared = true;  // its decisions are compared with the reference's
};

// The default (warm) engine, then the cold engine (batch RRR's and the paper preset's checks)
// with all its speed-ups on, the reference of "same decisions", and each off in turn (and its
// warm start, off by default, on). The warm engine decides otherwise by design: not compared.
std::vector<Variant> Variants(int threads) {
  Variant warm{"warm", IrrrOptions(), threads, false};
  Variant all_on{"cold all on", IrrrOptions(), threads};
  all_on.options.engine = IrrrEngine::kCold;
  all_on.options.alpha = 0.95;
  std::vector<Variant> variants = {warm, all_on};
  auto with = [&](const std::string& name, bool IrrrOptions::*option, bool value) {
    Variant v = all_on;
    v.name = name;
    v.options.*option = value;
    variants.push_back(v);
  };
  with("cold reuse_solves off", &IrrrOptions::reuse_solves, false);
  with("cold reuse_analysis off", &IrrrOptions::reuse_analysis, false);
  with("cold local_problems off", &IrrrOptions::local_problems, false);
  with("cold lazy_lookahead off", &IrrrOptions::lazy_lookahead, false);
  Variant serial = all_on;
  serial.name = "cold 1 thread";
  serial.threads = 1;
  variants.push_back(serial);
  with("cold warm_start on", &IrrrOptions::warm_start, true);
  return variants;
}

// The variants named in `names` (comma-separated, in Variants' order): all when empty, none for
// "none" (with --floor, the floor alone). False, with the name, for a name that is not a variant.
bool SelectVariants(const std::vector<std::string>& names,
                    int threads,
                    std::vector<Variant>* selected,
                    std::string* unknown) {
  const std::vector<Variant> all = Variants(threads);
  selected->clear();
  if (names.size() == 1 && names.front() == "none") return true;
  for (const std::string& name : names) {
    if (std::none_of(all.begin(), all.end(), [&](const Variant& v) { return v.name == name; })) {
      *unknown = name;
      return false;
    }
  }
  for (const Variant& v : all) {
    if (names.empty() || std::find(names.begin(), names.end(), v.name) != names.end()) {
      selected->push_back(v);
    }
  }
  return true;
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

// Stops between steps once `budget_s` is spent (the figures then cover the steps that ran).
template <class Pose>
RunResult RunIncremental(const PoseGraph<Pose>& graph, const Variant& variant, double budget_s) {
  RunResult result;
  result.poses = graph.num_vertices();
  result.start_kb = StatusKb("VmRSS");
  ThreadPool pool(variant.threads);
  const auto start = std::chrono::steady_clock::now();
  Irrr<Pose> irrr(variant.options);
  irrr.SetParallelFor(pool.AsParallelFor(), pool.size());
  GraphReplay<Pose> replay(graph, &irrr);
  // On a terminal, a progress line on stderr (nothing otherwise).
  ProgressLine line;
  ReplayProgress<Pose> progress(graph, "  " + variant.name, &line);
  bool over_budget = false;
  auto run_steps = [&]() {
    while (irrr.HasPendingStep() && !over_budget) {
      const auto step_start = std::chrono::steady_clock::now();
      const StepResult step = irrr.RunStep();
      result.step_ms.push_back(1e3 * SecondsSince(step_start));
      result.solves += step.solves;
      result.iterations += step.iterations;
      result.max_solves = std::max(result.max_solves, step.solves);
      over_budget = SecondsSince(start) > budget_s;
      progress.Show(irrr);
    }
  };
  for (const ArrivalEvent& event : ArrivalOrder(graph)) {
    if (over_budget) break;
    result.poses_in += event.kind == ArrivalEvent::Kind::kPose ? 1 : 0;
    replay.Apply(event);
    progress.Fed(event);
    progress.Show(irrr);
    run_steps();
  }
  if (!over_budget) {
    irrr.Flush();
    run_steps();
  }
  line.Clear();
  result.seconds = SecondsSince(start);
  result.steps = irrr.num_steps();
  result.peak_kb = StatusKb("VmHWM");
  result.finished = !over_budget;
  if (result.finished) {
    for (const LoopDecision& d : replay.Decisions())
      result.states.push_back(static_cast<int>(d.state));
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
  std::vector<std::string> datasets = {"manhattan", "city10000", "sphere2500"};
  std::vector<int> counts = {1000};
  OutlierOptions outliers;
  std::vector<Variant> variants;  // the variants to run, in Variants' order
  int threads = 2;
  double budget_s = 600.0;
  bool floor = false;
  bool require_finished = false;  // a run stopped by the budget fails the command (for tests)
};

// What the runs of every case showed, for the exit status.
struct Verdict {
  bool decisions_differ = false;  // a variant decided a loop otherwise than the reference
  bool stopped = false;           // a run did not finish: nothing of it was compared
};

// The floor under any iRRR that decides like this one: every wrong group is judged by Algorithm 2
// in a joint optimization from dead reckoning with the true loops that arrived before it (the
// notes' start; warm starts are slower still, see README), and its edge residuals rank the
// suspects, so it cannot be cut short: one such solve per group is work that no speed-up
// preserving the decisions can skip. Solved one after the other with one
// optimizer (its analysis reused where the pattern allows); returns their time and iterations.
// Stops between solves once `budget_s` is spent (the figures then cover the solves that ran).
template <class Pose>
RunResult WrongLoopFloor(const PoseGraph<Pose>& graph,
                         int first_wrong_edge,
                         int group_size,
                         double budget_s) {
  RunResult result;
  const auto start = std::chrono::steady_clock::now();
  Optimizer<Pose> optimizer;
  const std::vector<Pose> dead_reckoning = graph.OdometryEstimate();
  for (int first = first_wrong_edge; first < graph.num_edges(); first += group_size) {
    const int last = std::min(graph.num_edges(), first + group_size);
    int arrived = 0;  // poses before this index have arrived when the group's last link does
    for (int e = first; e < last; ++e) {
      arrived = std::max({arrived, graph.edge(e).from + 1, graph.edge(e).to + 1});
    }
    std::vector<char> active(graph.num_edges(), 0);
    for (int e = 0; e < graph.num_edges(); ++e) {
      const Edge<Pose>& edge = graph.edge(e);
      const bool wrong = e >= first_wrong_edge;
      const bool in_group = e >= first && e < last;
      active[e] = (in_group || !wrong) && edge.from < arrived && edge.to < arrived ? 1 : 0;
    }
    std::vector<Pose> x = dead_reckoning;
    const auto solve_start = std::chrono::steady_clock::now();
    result.iterations += optimizer.Solve(graph, active, &x).iterations;
    result.step_ms.push_back(1e3 * SecondsSince(solve_start));
    ++result.solves;
    if (SecondsSince(start) > budget_s) break;
  }
  result.seconds = SecondsSince(start);
  result.finished = true;
  return result;
}

template <class Pose>
int RunCase(const Dataset& dataset,
            int count,
            const Settings& settings,
            std::string* table,
            Verdict* verdict) {
  const std::string path = settings.shared + "/" + dataset.path;
  FileFormat format;
  int dimension = 0;
  GraphFile<Pose> file;
  PoseGraph<Pose> graph;
  std::vector<int> unused;
  if (Status s = InspectGraphFile(path, &format, &dimension); !s.ok()) {
    fmt::print(stderr, "irrr-bench-speed: {}\n", s.message());
    return EX_NOINPUT;
  }
  if (Status s = LoadPoseGraph(path, format, ReadOptions(), &file, &graph, &unused); !s.ok()) {
    fmt::print(stderr, "irrr-bench-speed: {}\n", s.message());
    return EX_DATAERR;
  }
  OutlierOptions outliers = settings.outliers;
  outliers.count = count;
  std::vector<OutlierLink<Pose>> links;
  if (Status s = MakeOutliers(graph, outliers, &links); !s.ok()) {
    fmt::print(stderr, "irrr-bench-speed: {}: {}\n", dataset.name, s.message());
    return EX_DATAERR;
  }
  const int first_wrong_edge = graph.num_edges();
  for (const OutlierLink<Pose>& link : links) {
    IRRR_CHECK(graph.AddLoop(link.from, link.to, link.measurement, link.information, nullptr).ok());
  }
  const std::string case_name =
      fmt::format("{} + {} {}", dataset.name, links.size(), OutlierModeName(outliers.mode));

  // The reference point for memory and time: one Gauss-Newton solve of the whole graph (every
  // edge, from the file's initial guess) in a child of its own.
  const RunResult batch = InChild(
      [&graph]() {
        RunResult r;
        r.start_kb = StatusKb("VmRSS");
        std::vector<Pose> x = graph.initial_estimate();
        Optimizer<Pose> optimizer;
        const auto start = std::chrono::steady_clock::now();
        optimizer.Solve(graph, std::vector<char>(graph.num_edges(), 1), &x);
        r.seconds = SecondsSince(start);
        r.peak_kb = StatusKb("VmHWM");
        r.finished = true;
        return r;
      },
      10 * settings.budget_s);
  const double graph_mb = GraphMegabytes(graph);
  const double batch_mb = static_cast<double>(batch.peak_kb - batch.start_kb) / 1024.0;
  fmt::print(stderr,
             "{}: {} poses, {} edges; graph {:.1f} MB; one batch solve (all edges) {:.2f} s, "
             "+{:.1f} MB\n",
             case_name,
             graph.num_vertices(),
             graph.num_edges(),
             graph_mb,
             batch.seconds,
             batch_mb);
  if (settings.floor) {
    const int group_size = IsGrouped(outliers.mode) ? std::max(1, outliers.group_size) : 1;
    const int groups = (graph.num_edges() - first_wrong_edge + group_size - 1) / group_size;
    const RunResult floor = InChild(
        [&]() { return WrongLoopFloor(graph, first_wrong_edge, group_size, settings.budget_s); },
        10 * settings.budget_s);
    std::vector<double> sorted = floor.step_ms;
    std::sort(sorted.begin(), sorted.end());
    fmt::print(stderr,
               "{}: floor: {} of {} joint solves from dead reckoning, one per wrong group against "
               "the true loops before it: {:.2f} s, {:.1f} iterations per solve, solve p50 / p99 "
               "/ max {:.1f} / {:.1f} / {:.1f} ms\n",
               case_name,
               floor.solves,
               groups,
               floor.seconds,
               floor.solves > 0 ? static_cast<double>(floor.iterations) / floor.solves : 0.0,
               Percentile(sorted, 0.50),
               Percentile(sorted, 0.99),
               sorted.empty() ? 0.0 : sorted.back());
  }

  std::vector<int> reference_states;
  std::string reference_name;
  for (const Variant& variant : settings.variants) {
    fmt::print(stderr, "  {} ...\n", variant.name);
    const double budget_s = settings.budget_s;
    // A step can outlast the budget by far (the budget is checked between steps).
    RunResult r =
        InChild([&]() { return RunIncremental(graph, variant, budget_s); }, 10 * budget_s);
    std::string same = "-";
    if (!variant.compared) {
      same = "(not compared)";
    } else if (r.finished && reference_states.empty() && reference_name.empty()) {
      reference_states = r.states;
      reference_name = variant.name;
      same = "(reference)";
    } else if (r.finished && !reference_states.empty()) {
      int differ = 0;
      for (size_t e = 0; e < r.states.size() && e < reference_states.size(); ++e) {
        differ += r.states[e] != reference_states[e] ? 1 : 0;
      }
      same = differ == 0 && r.states.size() == reference_states.size()
                 ? "yes"
                 : fmt::format("NO ({} loops differ)", differ);
    }
    std::vector<double> sorted = r.step_ms;
    std::sort(sorted.begin(), sorted.end());
    const bool ran = r.poses > 0;  // finished, or stopped by the budget with figures
    if (ran && same.rfind("NO", 0) == 0) verdict->decisions_differ = true;
    if (!r.finished) verdict->stopped = true;
    const std::string total =
        !ran ? "failed"
        : r.finished
            ? fmt::format("{:.2f}", r.seconds)
            : fmt::format("> {:.0f} (stopped at pose {} of {})", r.seconds, r.poses_in, r.poses);
    const std::string row =
        ran ? fmt::format(
                  "| {} | {} | {} | {} | {} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {} | "
                  "{:.1f} | {:.2f} | {:.1f} | {:.1f} | {:.1f} | {:.1f} | {:.2f} | {} |\n",
                  case_name,
                  variant.name,
                  variant.threads,
                  total,
                  r.steps,
                  Percentile(sorted, 0.50),
                  Percentile(sorted, 0.90),
                  Percentile(sorted, 0.99),
                  sorted.empty() ? 0.0 : sorted.back(),
                  r.steps > 0 ? static_cast<double>(r.solves) / r.steps : 0.0,
                  r.max_solves,
                  r.solves > 0 ? static_cast<double>(r.iterations) / r.solves : 0.0,
                  r.iterations > 0 ? 1e3 * r.seconds / r.iterations : 0.0,
                  static_cast<double>(r.peak_kb) / 1024.0,
                  static_cast<double>(r.peak_kb - r.start_kb) / 1024.0,
                  graph_mb,
                  batch_mb,
                  batch.seconds,
                  same)
            : fmt::format(
                  "| {} | {} | {} | failed | - | - | - | - | - | - | - | - | - | - | - | {:.1f} | "
                  "{:.1f} | {:.2f} | - |\n",
                  case_name,
                  variant.name,
                  variant.threads,
                  graph_mb,
                  batch_mb,
                  batch.seconds);
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
  CLI::App app("irrr-bench-speed: incremental iRRR's speed, and what each speed-up buys");
  Settings settings;
  std::string datasets = "manhattan,city10000,sphere2500";
  std::string counts = "1000";
  std::string variants;
  std::string mode = "random";
  std::string output;
  app.add_option("--shared", settings.shared, "the shared/ folder holding datasets/")
      ->capture_default_str();
  app.add_option("--datasets", datasets, "comma-separated: manhattan, city10000, sphere2500, intel")
      ->capture_default_str();
  app.add_option("--outliers", counts, "comma-separated wrong-loop counts")->capture_default_str();
  app.add_option("--mode", mode, "outlier mode")
      ->check(CLI::IsMember({"random", "local", "random-grouped", "local-grouped"}))
      ->capture_default_str();
  app.add_option("--group-size", settings.outliers.group_size, "links per group (grouped modes)")
      ->capture_default_str();
  app.add_option("--seed", settings.outliers.seed, "seed of the wrong loops")
      ->capture_default_str();
  app.add_option(
      "--variants",
      variants,
      "comma-separated subset of: warm, cold all on, cold reuse_solves off, cold "
      "reuse_analysis off, cold local_problems off, cold lazy_lookahead off, cold 1 thread, cold "
      "warm_start on; or none (default: all)");
  app.add_flag("--floor",
               settings.floor,
               "also time one joint solve from dead reckoning per wrong group (the work no "
               "decision-preserving speed-up can skip); stops at the budget");
  app.add_option("--threads", settings.threads, "threads of the parallel variants")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--budget",
                 settings.budget_s,
                 "seconds after which a run stops (between steps; its figures cover the steps run)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--output", output, "also write the table (Markdown) here");
  app.add_flag("--require-finished",
               settings.require_finished,
               "fail (exit 70) when a run does not finish, as well as when decisions differ");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }
  settings.datasets = SplitCommas(datasets);
  if (std::string unknown;
      !SelectVariants(SplitCommas(variants), settings.threads, &settings.variants, &unknown)) {
    fmt::print(stderr, "irrr-bench-speed: unknown variant \"{}\"\n", unknown);
    return EX_USAGE;
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
      "| case | variant | threads | total s | steps | step p50 ms | p90 ms | p99 ms | max ms | "
      "solves/step | max solves | iterations/solve | ms/iteration | peak MB | growth MB | graph MB "
      "| batch solve MB | batch solve s | same decisions |\n"
      "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  fmt::print("{}", table);
  Verdict verdict;
  for (const std::string& name : settings.datasets) {
    const auto it = std::find_if(
        Datasets().begin(), Datasets().end(), [&](const Dataset& d) { return d.name == name; });
    if (it == Datasets().end()) {
      fmt::print(stderr, "irrr-bench-speed: unknown dataset {}\n", name);
      return EX_USAGE;
    }
    FileFormat format;
    int dimension = 0;
    if (Status s = InspectGraphFile(settings.shared + "/" + it->path, &format, &dimension);
        !s.ok()) {
      fmt::print(stderr, "irrr-bench-speed: {}\n", s.message());
      return EX_NOINPUT;
    }
    for (int count : settings.counts) {
      const int code = dimension == 2 ? RunCase<Pose2>(*it, count, settings, &table, &verdict)
                                      : RunCase<Pose3>(*it, count, settings, &table, &verdict);
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
  if (verdict.decisions_differ) {
    fmt::print(stderr, "irrr-bench-speed: a speed-up changed decisions (rows marked NO)\n");
    return EX_SOFTWARE;
  }
  if (verdict.stopped && settings.require_finished) {
    fmt::print(stderr,
               "irrr-bench-speed: a run did not finish (budget or failure), so its decisions were "
               "not compared\n");
    return EX_SOFTWARE;
  }
  return EX_OK;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) { return irrr::Main(argc, argv); }
