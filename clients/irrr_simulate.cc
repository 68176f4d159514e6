// irrr-simulate: a simulated day of a fleet as one SE(2) pose-graph file: robots driving a
// Manhattan-world city, each run cut into sessions in frames of their own, with the true and
// wrong loop hypotheses of a simulated place recognizer in arrival order (clients/common/
// fleet_simulation.h says what is simulated and how).
//
//   irrr-simulate OUTPUT [--poses N] [--robots R] [--sessions-per-robot S] [--grid-blocks WxH]
//                 [--block-length M] [--pose-spacing M] [--keep-straight P]
//                 [--odometry-sigma-xy M] [--odometry-sigma-yaw RAD] [--loop-sigma-xy M]
//                 [--loop-sigma-yaw RAD] [--information-scale K] [--match-radius M]
//                 [--match-heading RAD] [--recognition-rate P] [--min-loop-gap N]
//                 [--wrong-rate P] [--wrong-grouped P] [--wrong-aliased P] [--group-size K]
//                 [--aliased-translation M] [--aliased-rotation RAD] [--wrong-min-distance M]
//                 [--seed S] [--labels LABELS.csv] [--ground-truth GT.txt]
//                 [--robots-file ROBOTS.txt]
//
// Writes OUTPUT (TORO for *.graph, g2o otherwise), and on request irrr-corrupt's labels of every
// loop hypothesis, the ground truth (one "x y yaw" line per vertex, all robots in one world frame)
// and the robot of each session as irrr-inject --robots takes it. Prints one summary line.
// Exit codes follow sysexits.h: 64 usage (an option out of range, or wrong loops the simulated
// city cannot hold), 70 internal error, 73 output not written.

#include <sysexits.h>

#include <regex>
#include <string>
#include <vector>

#include <fmt/core.h>
#include <CLI/CLI.hpp>

#include "clients/common/fleet_simulation.h"
#include "clients/common/graph_files.h"
#include "clients/common/loop_csv.h"
#include "core/graph_io.h"
#include "core/pose_graph.h"

namespace irrr {
namespace {

struct SimulateArguments {
  std::string output;
  std::string labels;        // empty: not written
  std::string ground_truth;  // empty: not written
  std::string robots_file;   // empty: not written
  std::string grid_blocks = "6x6";
  FleetSimulationOptions options;
};

// "WxH" or "N" (N x N) into the options' grid size.
bool ParseGridBlocks(const std::string& text, FleetSimulationOptions* options) {
  std::smatch match;
  if (std::regex_match(text, match, std::regex("([0-9]{1,6})x([0-9]{1,6})"))) {
    options->grid_blocks_x = std::stoi(match[1]);
    options->grid_blocks_y = std::stoi(match[2]);
    return true;
  }
  if (std::regex_match(text, match, std::regex("[0-9]{1,6}"))) {
    options->grid_blocks_x = options->grid_blocks_y = std::stoi(text);
    return true;
  }
  return false;
}

// Reads the file as a reader of OUTPUT will: every session and loop where the simulation put it.
Status CheckReadsBack(const FleetSimulation& simulation) {
  PoseGraph<Pose2> graph;
  std::vector<int> graph_edge_of_file_edge;
  if (Status s = BuildPoseGraph(simulation.file, &graph, &graph_edge_of_file_edge); !s.ok()) {
    return s;
  }
  if (graph.num_sessions() != simulation.counts.sessions) {
    return Status::Error(fmt::format(
        "{} sessions read back, {} written", graph.num_sessions(), simulation.counts.sessions));
  }
  for (const SimulatedLoop& loop : simulation.loops) {
    if (graph.edge(graph_edge_of_file_edge[loop.edge_index]).kind != EdgeKind::kLoop) {
      return Status::Error(fmt::format("loop edge {} reads back as odometry", loop.edge_index));
    }
  }
  return Status::Ok();
}

int Run(const SimulateArguments& args) {
  FleetSimulation simulation;
  if (Status s = SimulateFleet(args.options, &simulation); !s.ok()) {
    fmt::print(stderr, "irrr-simulate: {}\n", s.message());
    return EX_USAGE;
  }
  if (Status s = CheckReadsBack(simulation); !s.ok()) {
    fmt::print(stderr, "irrr-simulate: internal error: {}\n", s.message());
    return EX_SOFTWARE;
  }
  const FileFormat format = FormatForPath(args.output);
  if (Status s = WriteFileAtomically(
          args.output,
          [&](std::ostream& out) { return WriteGraphFile(out, format, simulation.file); });
      !s.ok()) {
    fmt::print(stderr, "irrr-simulate: {}\n", s.message());
    return EX_CANTCREAT;
  }
  std::string written;
  auto write = [&](const std::string& path,
                   const char* what,
                   const std::function<Status(std::ostream&)>& body) {
    if (path.empty()) return true;
    if (Status s = WriteFileAtomically(path, body); !s.ok()) {
      fmt::print(stderr, "irrr-simulate: {}\n", s.message());
      return false;
    }
    written += fmt::format(", {} {}", what, path);
    return true;
  };
  const bool ok =
      write(args.labels,
            "labels",
            [&](std::ostream& out) { return WriteLabelsCsv(out, simulation.labels); }) &&
      write(args.ground_truth,
            "ground truth",
            [&](std::ostream& out) { return WriteGroundTruth(out, simulation.ground_truth); }) &&
      write(args.robots_file, "robots", [&](std::ostream& out) {
        out << RobotsList(simulation.robot_of_session) << '\n';
        return out ? Status::Ok() : Status::Error("write failed");
      });
  if (!ok) return EX_CANTCREAT;
  fmt::print("irrr-simulate: {} (seed {}) -> {}{}\n",
             FormatFleetSummary(simulation.counts),
             args.options.seed,
             args.output,
             written);
  return EX_OK;
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  irrr::SimulateArguments args;
  irrr::FleetSimulationOptions& o = args.options;
  CLI::App app{
      "irrr-simulate: a simulated day of a fleet (robots driving a city grid, each run cut into "
      "sessions, true and wrong loop hypotheses of a place recognizer) as one SE(2) pose-graph "
      "file"};
  app.add_option("output", args.output, "the fleet's pose graph (TORO for *.graph, g2o otherwise)")
      ->required();
  app.add_option("--poses", o.poses, "poses in all, split evenly over the robots")
      ->capture_default_str();
  app.add_option("--robots", o.robots, "robots, all driving at once in one city")
      ->capture_default_str();
  app.add_option("--sessions-per-robot",
                 o.sessions_per_robot,
                 "each robot's run cut into this many sessions, each starting in its own frame")
      ->capture_default_str();
  app.add_option("--grid-blocks", args.grid_blocks, "the city: WxH blocks (or N: N x N)")
      ->capture_default_str();
  app.add_option("--block-length", o.block_length_m, "a block's side (m)")->capture_default_str();
  app.add_option("--pose-spacing", o.pose_spacing_m, "path length between two poses (m)")
      ->capture_default_str();
  app.add_option("--keep-straight",
                 o.keep_straight_probability,
                 "probability of driving straight on at an intersection (left and right share "
                 "the rest; never back)")
      ->capture_default_str();
  app.add_option("--odometry-sigma-xy",
                 o.odometry_sigma_xy_m,
                 "odometry noise per pose step, sd of x and y (m)")
      ->capture_default_str();
  app.add_option("--odometry-sigma-yaw",
                 o.odometry_sigma_yaw_rad,
                 "odometry noise per pose step, sd of the yaw (rad)")
      ->capture_default_str();
  app.add_option("--loop-sigma-xy", o.loop_sigma_xy_m, "a true loop's noise, sd of x and y (m)")
      ->capture_default_str();
  app.add_option(
         "--loop-sigma-yaw", o.loop_sigma_yaw_rad, "a true loop's noise, sd of the yaw (rad)")
      ->capture_default_str();
  app.add_option("--information-scale",
                 o.information_scale,
                 "information = this x covariance^-1 (below 1: the file claims more noise than "
                 "there is, as public datasets often do)")
      ->capture_default_str();
  app.add_option("--match-radius",
                 o.match_radius_m,
                 "the recognizer's candidates: earlier poses within this distance (m)")
      ->capture_default_str();
  app.add_option(
         "--match-heading", o.match_heading_rad, "... and within this heading difference (rad)")
      ->capture_default_str();
  app.add_option("--recognition-rate",
                 o.recognition_rate,
                 "probability that a pose with candidates claims one of them (a true loop)")
      ->capture_default_str();
  app.add_option("--min-loop-gap",
                 o.min_loop_gap,
                 "poses at least between the two ends of a loop within one session")
      ->capture_default_str();
  app.add_option(
         "--wrong-rate", o.wrong_rate, "wrong loops' share of all loop hypotheses, in [0, 1)")
      ->capture_default_str();
  app.add_option("--wrong-grouped",
                 o.wrong_grouped_fraction,
                 "share of the wrong loops in groups (consecutive poses, consistent claims)")
      ->capture_default_str();
  app.add_option("--wrong-aliased",
                 o.wrong_aliased_fraction,
                 "share of the wrong loops (lone, and groups) that are aliased: two distant "
                 "places claimed nearly the same; the others are random claims")
      ->capture_default_str();
  app.add_option("--group-size", o.group_size, "links per wrong group")->capture_default_str();
  app.add_option("--aliased-translation",
                 o.aliased_translation_m,
                 "aliased claims: translation uniform in the disc of this radius (m)")
      ->capture_default_str();
  app.add_option("--aliased-rotation",
                 o.aliased_rotation_rad,
                 "aliased claims: yaw uniform within this angle (rad)")
      ->capture_default_str();
  app.add_option("--wrong-min-distance",
                 o.wrong_min_distance_m,
                 "a wrong loop joins poses farther apart than this in the world (m)")
      ->capture_default_str();
  app.add_option("--seed", o.seed, "random seed (paths, noise, recognizer, wrong loops)")
      ->capture_default_str();
  app.add_option("--labels",
                 args.labels,
                 "write edge_index,from,to,outlier,group for every loop hypothesis here");
  app.add_option("--ground-truth",
                 args.ground_truth,
                 "write one \"x y yaw\" line per vertex here (one world frame)");
  app.add_option("--robots-file",
                 args.robots_file,
                 "write the robot of each session here, as irrr-inject --robots takes it");
  app.footer(
      "Exit codes: 0 ok, 64 usage (an option out of range, or wrong loops the city cannot hold), "
      "70 internal error, 73 output not written.");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }
  if (!irrr::ParseGridBlocks(args.grid_blocks, &o)) {
    fmt::print(
        stderr, "irrr-simulate: --grid-blocks: expected WxH or N, got \"{}\"\n", args.grid_blocks);
    return EX_USAGE;
  }
  if (irrr::Status s = o.Validate(); !s.ok()) {
    fmt::print(stderr, "irrr-simulate: {}\n", s.message());
    return EX_USAGE;
  }
  return irrr::Run(args);
}
