// irrr-plot: draws a pose graph and iRRR's decisions about it (clients/common/plots.h).
//
//   irrr-plot INPUT --out MAP.svg|MAP.png [--decisions DECISIONS.csv] [--optimized OUT.g2o]
//             [--ground-truth GT] [--steps STEPS.csv] [--title TEXT]
//   irrr-plot --chart TABLE.csv --x COLUMN --y COLUMN [--y COLUMN ...] --out CHART.svg|.png
//             [--title TEXT]
//
// INPUT is the graph file that was decided (g2o or TORO); --decisions the CSV of irrr-batch or
// irrr-listen (edge_index = the input's edge index); --optimized the graph irrr-batch --output
// (or irrr-listen --output) wrote, whose vertices give the map (without it: the initial guess);
// --steps a CSV with a "ms" column, one row per step. Writes MAP and, beside it,
// <stem>_before_after, <stem>_steps and <stem>_ate where there is data for them. --chart draws
// columns of any CSV with a header line against one of them instead (tools/soak's latency and
// memory against poses received). Exit codes
// follow sysexits.h: 64 usage, 65 bad input data, 66 input missing, 73 output not written.

#include <sysexits.h>

#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <fmt/core.h>
#include <fmt/ranges.h>
#include <CLI/CLI.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/loop_csv.h"
#include "clients/common/plots.h"

namespace irrr {
namespace {

struct Arguments {
  std::string input;
  std::string out;
  std::string decisions;
  std::string optimized;
  std::string ground_truth;
  std::string steps;
  std::string title;
  bool skip_invalid_edges = false;
  std::string chart;
  std::string x;
  std::vector<std::string> y;
};

// The column `name` of a CSV with a header line.
Status ReadColumn(const std::string& path, const std::string& name, std::vector<double>* values) {
  std::ifstream in(path);
  if (!in) return Status::Error(path + ": cannot open");
  std::string line;
  std::getline(in, line);
  std::vector<std::string> header;
  std::stringstream names(line);
  for (std::string cell; std::getline(names, cell, ',');) header.push_back(cell);
  const auto column = std::find(header.begin(), header.end(), name) - header.begin();
  if (column == static_cast<long>(header.size())) {
    return Status::Error(path + ": no \"" + name + "\" column");
  }
  for (int row = 2; std::getline(in, line); ++row) {
    std::stringstream cells(line);
    std::string cell;
    for (long k = 0; k <= column && std::getline(cells, cell, ','); ++k) {
    }
    try {
      values->push_back(std::stod(cell));
    } catch (const std::exception&) {
      return Status::Error(path + ":" + std::to_string(row) + ": \"" + cell + "\" is not a number");
    }
  }
  return Status::Ok();
}

// --chart: the --y columns against the --x column.
int Chart(const Arguments& args) {
  std::vector<double> x;
  if (Status s = ReadColumn(args.chart, args.x, &x); !s.ok()) {
    fmt::print(stderr, "irrr-plot: {}\n", s.message());
    return EX_DATAERR;
  }
  std::vector<ChartSeries> series;
  for (const std::string& name : args.y) {
    std::vector<double> y;
    if (Status s = ReadColumn(args.chart, name, &y); !s.ok()) {
      fmt::print(stderr, "irrr-plot: {}\n", s.message());
      return EX_DATAERR;
    }
    ChartSeries& one = series.emplace_back();
    one.name = name;
    for (size_t k = 0; k < x.size() && k < y.size(); ++k) one.points.emplace_back(x[k], y[k]);
  }
  const std::string title =
      args.title.empty() ? args.chart.substr(args.chart.rfind('/') + 1) : args.title;
  const std::string y_label = args.y.size() == 1 ? args.y.front() : "";
  if (Status s = WritePlot(args.out, ChartSvg(title, args.x, y_label, series)); !s.ok()) {
    fmt::print(stderr, "irrr-plot: {}\n", s.message());
    return EX_CANTCREAT;
  }
  fmt::print("plots     {}\n", args.out);
  return EX_OK;
}

template <class Pose>
int Plot(const Arguments& args, FileFormat format) {
  GraphFile<Pose> file;
  PoseGraph<Pose> graph;
  std::vector<int> graph_edge_of_file_edge;
  ReadOptions read_options;
  read_options.skip_invalid_edges = args.skip_invalid_edges;
  if (Status s =
          LoadPoseGraph(args.input, format, read_options, &file, &graph, &graph_edge_of_file_edge);
      !s.ok()) {
    fmt::print(stderr, "irrr-plot: {}\n", s.message());
    return EX_DATAERR;
  }
  PrintSkippedLines(stderr, "irrr-plot", args.input, file.skipped);
  std::vector<LoopDecision> decisions(graph.num_edges());
  if (!args.decisions.empty()) {
    std::ifstream in(args.decisions);
    std::vector<DecisionRow> rows;
    Status s = in ? ReadDecisionsCsv(in, &rows) : Status::Error("cannot open");
    for (const DecisionRow& row : rows) {
      if (!s.ok()) break;
      if (row.edge_index < 0 || row.edge_index >= static_cast<int>(file.edges.size())) {
        s = Status::Error("edge_index " + std::to_string(row.edge_index) + " is not an edge of " +
                          args.input);
        break;
      }
      decisions[graph_edge_of_file_edge[row.edge_index]] = row.decision;
    }
    if (!s.ok()) {
      fmt::print(stderr, "irrr-plot: {}: {}\n", args.decisions, s.message());
      return EX_DATAERR;
    }
  }
  std::vector<Pose> estimate = graph.initial_estimate();
  if (!args.optimized.empty()) {
    std::ifstream in(args.optimized);
    GraphFile<Pose> optimized;
    Status s = in ? ReadGraphFile(in, FormatForPath(args.optimized), ReadOptions(), &optimized)
                  : Status::Error("cannot open");
    for (const FileVertex<Pose>& v : optimized.vertices) {
      if (!s.ok()) break;
      const int index = graph.FindVertex(v.id);
      if (index < 0) {
        s = Status::Error("vertex " + std::to_string(v.id) + " is not in " + args.input);
        break;
      }
      estimate[index] = v.estimate;
    }
    if (!s.ok()) {
      fmt::print(stderr, "irrr-plot: {}: {}\n", args.optimized, s.message());
      return EX_DATAERR;
    }
  }
  std::vector<Pose> ground_truth;
  if (!args.ground_truth.empty()) {
    if (Status s = LoadGroundTruth(args.ground_truth, graph, &ground_truth); !s.ok()) {
      fmt::print(stderr, "irrr-plot: {}\n", s.message());
      return EX_DATAERR;
    }
  }
  std::vector<double> step_ms;
  if (!args.steps.empty()) {
    if (Status s = ReadColumn(args.steps, "ms", &step_ms); !s.ok()) {
      fmt::print(stderr, "irrr-plot: {}\n", s.message());
      return EX_DATAERR;
    }
  }
  std::vector<std::string> written;
  const std::string title =
      args.title.empty() ? args.input.substr(args.input.rfind('/') + 1) : args.title;
  if (Status s = WriteGraphPlots(
          args.out, title, graph, estimate, decisions, ground_truth, step_ms, &written);
      !s.ok()) {
    fmt::print(stderr, "irrr-plot: {}\n", s.message());
    return EX_CANTCREAT;
  }
  fmt::print("plots     {}\n", fmt::join(written, ", "));
  return EX_OK;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  irrr::Arguments args;
  CLI::App app{"irrr-plot: draw a pose graph and the decisions about its loop closures"};
  auto* input =
      app.add_option("input", args.input, "the graph file that was decided (g2o or TORO)");
  app.add_option("--out", args.out, "the map plot (SVG, or PNG with rsvg-convert)")->required();
  app.add_option("--decisions", args.decisions, "decisions CSV (irrr-batch or irrr-listen)");
  app.add_option("--optimized", args.optimized, "the optimized graph (irrr-batch --output)");
  app.add_option("--ground-truth", args.ground_truth, "ground-truth poses, as irrr-batch takes");
  app.add_option("--steps", args.steps, "CSV with a \"ms\" column: the time of each iRRR step");
  app.add_option("--title", args.title, "title of the plots (default: the input's name)");
  app.add_flag("--skip-invalid-edges",
               args.skip_invalid_edges,
               "leave out invalid edge lines as irrr-batch --skip-invalid-edges does (so that its "
               "decisions line up)");
  auto* chart = app.add_option(
      "--chart", args.chart, "instead of a graph: a CSV with a header line, to chart its columns");
  app.add_option("--x", args.x, "--chart: the column along the x axis")->needs(chart);
  app.add_option("--y", args.y, "--chart: a column to chart against --x (repeatable)")
      ->needs(chart);
  chart->excludes(input);
  app.footer(
      "Exit codes: 0 ok, 64 usage, 65 bad input data, 66 input missing, 73 output not written.");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }
  if (!args.chart.empty()) {
    if (args.x.empty() || args.y.empty()) {
      fmt::print(stderr, "irrr-plot: --chart needs --x and at least one --y\n");
      return EX_USAGE;
    }
    return irrr::Chart(args);
  }
  if (args.input.empty()) {
    fmt::print(stderr, "irrr-plot: an input graph file (or --chart) is required\n");
    return EX_USAGE;
  }
  if (!std::ifstream(args.input)) {
    fmt::print(stderr, "irrr-plot: {}: cannot open\n", args.input);
    return EX_NOINPUT;
  }
  irrr::FileFormat format;
  int dimension = 0;
  if (irrr::Status s = irrr::InspectGraphFile(args.input, &format, &dimension); !s.ok()) {
    fmt::print(stderr, "irrr-plot: {}\n", s.message());
    return EX_DATAERR;
  }
  return dimension == 2 ? irrr::Plot<irrr::Pose2>(args, format)
                        : irrr::Plot<irrr::Pose3>(args, format);
}
