// irrr-corrupt: add failures to a clean pose-graph file, for experiments: wrong loop closures,
// noisy odometry and faulty odometry edges.
//
//   irrr-corrupt INPUT OUTPUT --labels LABELS.csv
//                [--mode random|local|random-grouped|local-grouped|inter-session|aliased|
//                        aliased-grouped] [--count N] [--group-size K] [--local-window W]
//                [--aliased-translation M] [--aliased-rotation RAD]
//                [--odometry-noise K] [--odometry-faults N] [--fault-labels FAULTS.csv]
//                [--seed S] [--split ID,ID,...] [--skip-invalid-edges]
//
// Reads INPUT, optionally splits it into sessions at the given vertex ids (as the paper's Intel
// experiment, IV.B), then in this order: makes the odometry K times noisier than its information
// says (core's PerturbOdometry), replaces N odometry measurements by wrong motions (core's
// InjectOdometryFaults), appends the wrong loops of core's MakeOutliers, drawn on the graph as
// changed so far, as extra edges after the file's own. Changed odometry re-chains the vertex
// estimates, so OUTPUT's initial guess is its own dead reckoning. Writes OUTPUT (TORO for *.graph,
// g2o otherwise), a CSV that labels every loop hypothesis of OUTPUT and, on request, a CSV of the
// faulty odometry edges. One --seed drives all three, each from its own stream, so that a seed's
// wrong loops join the same poses with the same claims whether or not noise or faults were added.
// Exit codes follow sysexits.h: 64 usage, 65 bad input data or a request the graph cannot hold, 66
// input missing, 70 internal error, 73 output not written.

#include <sysexits.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <map>
#include <set>
#include <string>
#include <vector>

#include <fmt/core.h>
#include <CLI/CLI.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/loop_csv.h"
#include "core/graph_io.h"
#include "core/outliers.h"
#include "core/pose.h"

namespace irrr {
namespace {

struct CorruptArguments {
  std::string input;
  std::string output;
  std::string labels;
  std::string fault_labels;  // empty: not written
  std::string mode = OutlierModeName(OutlierMode::kRandom);
  double odometry_noise = 0.0;  // 0: odometry left as given
  int odometry_faults = 0;
  std::vector<int64_t> split;
  bool skip_invalid_edges = false;
  OutlierOptions outliers = [] {
    OutlierOptions options;
    options.count = 0;  // no wrong loops unless asked for: the odometry options stand alone
    return options;
  }();
};

const std::map<std::string, OutlierMode>& ModeNames() {
  static const std::map<std::string, OutlierMode> names = [] {
    std::map<std::string, OutlierMode> by_name;
    for (OutlierMode mode : {OutlierMode::kRandom,
                             OutlierMode::kLocal,
                             OutlierMode::kRandomGrouped,
                             OutlierMode::kLocalGrouped,
                             OutlierMode::kInterSession,
                             OutlierMode::kAliased,
                             OutlierMode::kAliasedGrouped}) {
      by_name[OutlierModeName(mode)] = mode;
    }
    return by_name;
  }();
  return names;
}

// The same constraint as `edge` written from its `to` pose: measurement inverted, information
// carried over to the reversed residual. At poses that satisfy the edge (from = I, to =
// measurement) a perturbation delta of `to` gives r = J_r_to delta and r_reversed =
// J_reversed_from delta, so r = T^-1 r_reversed with T = J_reversed_from J_r_to^-1, and
// r' Omega r = r_reversed' (T^-T Omega T^-1) r_reversed to first order.
template <class Pose>
FileEdge<Pose> Reversed(const FileEdge<Pose>& edge) {
  using Matrix = typename Pose::Matrix;
  Matrix J_r_from;
  Matrix J_r_to;
  RelativePoseResidual<Pose>(edge.measurement, Pose(), edge.measurement, &J_r_from, &J_r_to);
  const Pose inverse = edge.measurement.Inverse();
  Matrix J_reversed_from;
  Matrix J_reversed_to;
  RelativePoseResidual<Pose>(inverse, edge.measurement, Pose(), &J_reversed_from, &J_reversed_to);
  const Matrix T_inverse = (J_reversed_from * J_r_to.inverse()).inverse();
  const Matrix information = T_inverse.transpose() * edge.information * T_inverse;
  FileEdge<Pose> reversed = edge;
  reversed.from = edge.to;
  reversed.to = edge.from;
  reversed.measurement = inverse;
  reversed.information = 0.5 * (information + information.transpose());
  return reversed;
}

constexpr const char* kFaultLabelsCsvHeader = "edge_index,from,to";

// One row per faulty odometry edge of OUTPUT: its index in OUTPUT's edge list and its vertex ids.
template <class Pose>
Status WriteFaultLabelsCsv(std::ostream& out,
                           const GraphFile<Pose>& file,
                           const std::vector<int>& fault_file_edges) {
  out << kFaultLabelsCsvHeader << '\n';
  for (int k : fault_file_edges) {
    out << fmt::format("{},{},{}\n", k, file.edges[k].from, file.edges[k].to);
  }
  if (!out) return Status::Error("write failed");
  return Status::Ok();
}

template <class Pose>
int Run(const CorruptArguments& args, FileFormat input_format) {
  GraphFile<Pose> file;
  {
    std::ifstream in(args.input);
    ReadOptions read_options;
    read_options.skip_invalid_edges = args.skip_invalid_edges;
    if (Status s = ReadGraphFile(in, input_format, read_options, &file); !s.ok()) {
      fmt::print(stderr, "irrr-corrupt: {}: {}\n", args.input, s.message());
      return EX_DATAERR;
    }
    PrintSkippedLines(stderr, "irrr-corrupt", args.input, file.skipped);
  }
  if (!args.split.empty()) {
    if (Status s = SplitIntoSessions(args.split, &file); !s.ok()) {
      fmt::print(stderr, "irrr-corrupt: --split: {}: {}\n", args.input, s.message());
      return EX_DATAERR;
    }
  }
  if (args.odometry_noise > 0.0) {
    if (Status s = PerturbOdometry(args.odometry_noise, args.outliers.seed, &file); !s.ok()) {
      fmt::print(stderr, "irrr-corrupt: --odometry-noise: {}: {}\n", args.input, s.message());
      return EX_DATAERR;
    }
  }
  // Indices in `file.edges`, which are also OUTPUT's: the wrong loops go after the file's edges.
  std::vector<int> fault_file_edges;
  if (args.odometry_faults > 0) {
    if (Status s = InjectOdometryFaults(
            args.odometry_faults, args.outliers.seed, &file, &fault_file_edges);
        !s.ok()) {
      fmt::print(stderr, "irrr-corrupt: --odometry-faults: {}: {}\n", args.input, s.message());
      return EX_DATAERR;
    }
  }
  PoseGraph<Pose> graph;
  std::vector<int> unused;
  if (Status s = BuildPoseGraph(file, &graph, &unused); !s.ok()) {
    fmt::print(stderr, "irrr-corrupt: {}: {}\n", args.input, s.message());
    return EX_DATAERR;
  }
  std::vector<OutlierLink<Pose>> links;
  if (args.outliers.count > 0) {
    if (Status s = MakeOutliers(graph, args.outliers, &links); !s.ok()) {
      fmt::print(stderr, "irrr-corrupt: {}: {}\n", args.input, s.message());
      return EX_DATAERR;
    }
  }

  // Outliers after the file's own edges. A link (i, i+1) that is not odometry (between the last
  // pose of a session and the first of the next) would read back as the odometry joining them,
  // so it is written the other way round: an edge (i+1, i) is always a loop hypothesis.
  std::set<std::pair<int64_t, int64_t>> odometry;
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose>& edge = graph.edge(e);
    if (edge.kind == EdgeKind::kOdometry) {
      odometry.emplace(graph.vertex(edge.from).id, graph.vertex(edge.to).id);
    }
  }
  GraphFile<Pose> corrupted = file;
  const int group_size = IsGrouped(args.outliers.mode) ? std::max(1, args.outliers.group_size) : 1;
  std::vector<int> group_of_edge(file.edges.size(), -1);
  int num_reversed = 0;
  for (size_t k = 0; k < links.size(); ++k) {
    FileEdge<Pose> edge;
    edge.from = graph.vertex(links[k].from).id;
    edge.to = graph.vertex(links[k].to).id;
    edge.measurement = links[k].measurement;
    edge.information = links[k].information;
    if (edge.to == edge.from + 1 && odometry.count({edge.from, edge.to}) == 0) {
      edge = Reversed(edge);
      ++num_reversed;
    }
    corrupted.edges.push_back(edge);
    group_of_edge.push_back(static_cast<int>(k) / group_size);
  }

  // Label the hypotheses as a reader of OUTPUT will see them.
  PoseGraph<Pose> check;
  std::vector<int> graph_edge_of_file_edge;
  if (Status s = BuildPoseGraph(corrupted, &check, &graph_edge_of_file_edge); !s.ok()) {
    fmt::print(
        stderr, "irrr-corrupt: internal error: the output does not read back: {}\n", s.message());
    return EX_SOFTWARE;
  }
  if (check.num_sessions() != graph.num_sessions()) {
    fmt::print(stderr,
               "irrr-corrupt: internal error: {} sessions read back, {} written\n",
               check.num_sessions(),
               graph.num_sessions());
    return EX_SOFTWARE;
  }
  std::vector<LabelRow> labels;
  int num_loops = 0;
  for (size_t k = 0; k < corrupted.edges.size(); ++k) {
    const bool outlier = k >= file.edges.size();
    if (check.edge(graph_edge_of_file_edge[k]).kind != EdgeKind::kLoop) {
      if (outlier) {
        fmt::print(
            stderr, "irrr-corrupt: internal error: outlier edge {} reads back as odometry\n", k);
        return EX_SOFTWARE;
      }
      continue;
    }
    LabelRow row;
    row.edge_index = static_cast<int>(k);
    row.from = corrupted.edges[k].from;
    row.to = corrupted.edges[k].to;
    row.outlier = outlier;
    row.group = group_of_edge[k];
    labels.push_back(row);
    num_loops += outlier ? 0 : 1;
  }

  const FileFormat output_format = FormatForPath(args.output);
  if (Status s = WriteFileAtomically(
          args.output,
          [&](std::ostream& out) { return WriteGraphFile(out, output_format, corrupted); });
      !s.ok()) {
    fmt::print(stderr, "irrr-corrupt: {}\n", s.message());
    return EX_CANTCREAT;
  }
  if (Status s = WriteFileAtomically(
          args.labels, [&](std::ostream& out) { return WriteLabelsCsv(out, labels); });
      !s.ok()) {
    fmt::print(stderr, "irrr-corrupt: {}\n", s.message());
    return EX_CANTCREAT;
  }
  if (!args.fault_labels.empty()) {
    if (Status s = WriteFileAtomically(args.fault_labels,
                                       [&](std::ostream& out) {
                                         return WriteFaultLabelsCsv(
                                             out, corrupted, fault_file_edges);
                                       });
        !s.ok()) {
      fmt::print(stderr, "irrr-corrupt: {}\n", s.message());
      return EX_CANTCREAT;
    }
  }

  const int num_groups = static_cast<int>(links.size()) / group_size;
  std::string odometry_summary;
  if (args.odometry_noise > 0.0) {
    odometry_summary += fmt::format("odometry noise x{}", args.odometry_noise);
  }
  if (args.odometry_faults > 0) {
    odometry_summary += fmt::format(
        "{}{} odometry faults", odometry_summary.empty() ? "" : ", ", args.odometry_faults);
  }
  fmt::print(
      "irrr-corrupt: {}: {} {} poses in {} session(s), {} loop hypotheses; {}+ {} {} outliers{} "
      "(seed {}){} -> {}, labels {}{}\n",
      args.input,
      Pose::kName,
      graph.num_vertices(),
      graph.num_sessions(),
      num_loops,
      odometry_summary.empty() ? std::string() : odometry_summary + "; ",
      links.size(),
      args.mode,
      IsGrouped(args.outliers.mode) ? fmt::format(" in {} groups of {}", num_groups, group_size)
                                    : std::string(),
      args.outliers.seed,
      num_reversed > 0 ? fmt::format(", {} written reversed", num_reversed) : std::string(),
      args.output,
      args.labels,
      args.fault_labels.empty() ? std::string() : ", fault labels " + args.fault_labels);
  return EX_OK;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  irrr::CorruptArguments args;
  CLI::App app{
      "irrr-corrupt: add wrong loop closures, noisy odometry or odometry faults to a pose-graph "
      "file and label them"};
  app.add_option("input", args.input, "clean g2o (2D or 3D) or TORO 2D pose-graph file")
      ->required();
  app.add_option("output", args.output, "corrupted graph (TORO for *.graph, g2o otherwise)")
      ->required();
  std::vector<std::string> mode_names;
  for (const auto& [name, mode] : irrr::ModeNames()) mode_names.push_back(name);
  app.add_option("--mode",
                 args.mode,
                 "wrong loops: random, local (within --local-window poses), random-grouped, "
                 "local-grouped, inter-session (grouped, between two sessions), aliased (lone "
                 "links claiming two distant poses are nearly the same place) or aliased-grouped "
                 "(groups as random-grouped with such a claim)")
      ->check(CLI::IsMember(mode_names))
      ->capture_default_str();
  app.add_option("--count",
                 args.outliers.count,
                 "wrong loop links in all (grouped: rounded up to groups); 0 adds none")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--labels",
                 args.labels,
                 "write edge_index,from,to,outlier,group for every loop hypothesis of OUTPUT here")
      ->required();
  app.add_option("--group-size", args.outliers.group_size, "links per group (grouped modes)")
      ->check(CLI::PositiveNumber)
      ->capture_default_str();
  app.add_option("--local-window",
                 args.outliers.local_window,
                 "local modes: at most this many poses between the two ends")
      ->check(CLI::Range(2, 1 << 30))
      ->capture_default_str();
  app.add_option("--aliased-translation",
                 args.outliers.aliased_translation_m,
                 "aliased modes: the claim's translation is uniform in the disc (ball in 3D) of "
                 "this radius (m)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--aliased-rotation",
                 args.outliers.aliased_rotation_rad,
                 "aliased modes: the claim's rotation is uniform within this angle (rad; 3D: "
                 "about a random axis)")
      ->check(CLI::Range(0.0, M_PI))
      ->capture_default_str();
  app.add_option("--odometry-noise",
                 args.odometry_noise,
                 "noisy odometry: perturb every odometry measurement by a draw from N(0, K^2 "
                 "Sigma), Sigma the inverse of its information (kept), and chain the vertex "
                 "estimates along it")
      ->check(CLI::PositiveNumber);
  app.add_option("--odometry-faults",
                 args.odometry_faults,
                 "odometry faults: replace N odometry measurements (distinct, spread over the "
                 "sessions) by wrong motions (1-3 m, 0.3-1.0 rad more), information kept, and "
                 "chain the vertex estimates along them; applied after --odometry-noise")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--fault-labels",
                 args.fault_labels,
                 "write edge_index,from,to for every faulty odometry edge of OUTPUT here");
  app.add_option("--seed", args.outliers.seed, "random seed (wrong loops, noise and faults)")
      ->capture_default_str();
  app.add_option("--split",
                 args.split,
                 "start a new session at each of these vertex ids (comma separated); their "
                 "odometry edges are removed")
      ->delimiter(',');
  app.add_flag("--skip-invalid-edges",
               args.skip_invalid_edges,
               "leave out edge lines of INPUT that are well formed but invalid (self-loop, "
               "non-finite number, information not positive definite, undeclared vertex), each "
               "named on stderr; OUTPUT and its labels hold the rest");
  app.footer(
      "Exit codes: 0 ok, 64 usage, 65 bad input data or a request the graph cannot hold, 66 "
      "input missing, 70 internal error, 73 output not written.");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }
  args.outliers.mode = irrr::ModeNames().at(args.mode);

  if (!std::ifstream(args.input)) {
    fmt::print(stderr, "irrr-corrupt: {}: cannot open\n", args.input);
    return EX_NOINPUT;
  }
  irrr::FileFormat format;
  int dimension = 0;
  if (irrr::Status s = irrr::InspectGraphFile(args.input, &format, &dimension); !s.ok()) {
    fmt::print(stderr, "irrr-corrupt: {}\n", s.message());
    return EX_DATAERR;
  }
  if (dimension == 3 && irrr::FormatForPath(args.output) == irrr::FileFormat::kToro) {
    fmt::print(stderr, "irrr-corrupt: {}: TORO files hold 2D graphs only\n", args.output);
    return EX_USAGE;
  }
  return dimension == 2 ? irrr::Run<irrr::Pose2>(args, format)
                        : irrr::Run<irrr::Pose3>(args, format);
}
