// A fleet across simulated hosts (tools/netns-fleet): three robots and a base station, each in its
// own network namespace, on one bridge; LCM over UDP multicast with ttl=1. Each robot injects its
// own part of one multi-session file (irrr-inject --only-robot) and listens for its own poses and
// transforms (irrr-listen --robot); two daemons, one on the base station and one on robot 1's
// host, hear the same inputs and publish on channels of their own. Hidden ([.][fleet]): CTest runs
// it through tools/netns-fleet.

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <catch2/catch.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/loop_csv.h"
#include "core/pose.h"
#include "tests/processes.h"
#include "tests/test_files.h"

namespace irrr {
namespace {

using Catch::Matchers::Contains;

const char* const kFleetUrl = "udpm://239.255.76.67:7667?ttl=1&recv_buf_size=2097152";
const char* const kRobotsOfSessions = "1,2,3,1";  // session s belongs to robot kRobots[s]
constexpr int kRobots[4] = {1, 2, 3, 1};
constexpr int kSessionStarts[4] = {0, 150, 300, 450};
constexpr int kPoses = 600;

// `command` on fleet host `host` (base, r1, r2, r3).
std::string On(const std::string& host, const std::string& command) {
  const char* fleet = std::getenv("IRRR_FLEET");
  REQUIRE(fleet != nullptr);
  return "ip netns exec " + std::string(fleet) + "-" + host + " " + command;
}

void SetPort(const std::string& host, bool up) {
  const std::string command = "ip -n " + std::string(std::getenv("IRRR_FLEET")) +
                              "-br link set port-" + host + (up ? " up" : " down");
  REQUIRE(std::system(command.c_str()) == 0);
}

struct Fleet {
  std::string dir;
  std::string input;           // Intel's first 600 poses in four sessions, with wrong loops
  std::string labels;          // which loops are wrong
  std::string reference;       // the optimum of the clean, unsplit graph: the ground truth
  std::string config_a;        // daemon base-a (the standard channels)
  std::string config_standby;  // daemon standby (its own output channels)
};

Fleet MakeFleet(const std::string& dir) {
  Fleet f;
  f.dir = dir;
  const std::string clean = dir + "/intel600.g2o";
  WriteIntelPrefix(kPoses, clean);
  f.input = dir + "/fleet.g2o";
  f.labels = dir + "/labels.csv";
  f.reference = dir + "/reference.g2o";
  // Re-based sessions with 45 wrong inter-session loops in groups of 3: two robots that see
  // look-alike places (the grouped kind a single consistency test cannot reject).
  const std::string corrupt = std::string(IRRR_CORRUPT) + " " + Quoted(clean) + " " +
                              Quoted(f.input) +
                              " --split 150,300,450 --mode inter-session --count 45 "
                              "--group-size 3 --seed 2 --labels " +
                              Quoted(f.labels);
  REQUIRE(RunTool(corrupt, dir + "/corrupt.log") == 0);
  REQUIRE(
      RunTool(std::string(IRRR_BATCH) + " " + Quoted(clean) + " --output " + Quoted(f.reference),
              dir + "/reference.log") == 0);
  // Stamp order across robots (daemon.merge), waiting for each robot up to 30 s.
  const std::string common =
      std::string("\"lcm_url\": \"") + kFleetUrl +
      "\", \"status_hz\": 5, \"merge\": {\"window_ms\": 30000, \"senders\": [\"robot1\", "
      "\"robot2\", \"robot3\"]}";
  f.config_a = dir + "/base-a.json";
  WriteText(f.config_a,
            "{\"daemon\": {\"daemon_id\": \"base-a\", " + common +
                "}, \"irrr\": {\"cluster_gap\": 10}}\n");
  f.config_standby = dir + "/standby.json";
  WriteText(f.config_standby,
            "{\"daemon\": {\"daemon_id\": \"standby\", " + common +
                ", \"channels\": {\"correction\": \"IRRR_CORRECTION/standby\", \"verdicts\": "
                "\"IRRR_VERDICTS/standby\", \"solution\": \"IRRR_SOLUTION/standby\", \"status\": "
                "\"IRRR_STATUS/standby\", \"error\": \"IRRR_ERROR/standby\"}}, \"irrr\": "
                "{\"cluster_gap\": 10}}\n");
  RunBatch(dir, f.input, f.config_a);  // batch.csv, batch.g2o: the file's own arrival order
  return f;
}

// One run of the fleet: daemon base-a and its listener on the base station, standby and its
// listener on robot 1's host, each robot's injector and listener on its host; `partition` cuts
// robot 2 off for a while mid-stream.
void RunFleet(const Fleet& f, const std::string& run, bool partition) {
  const std::string dir = f.dir + "/" + run;
  std::filesystem::create_directories(dir);
  const std::string irrrd = std::string(IRRRD) + " --config ";
  auto daemon_a = StartDaemon(On("base", irrrd + Quoted(f.config_a)), dir + "/base-a.log");
  // The second daemon runs on robot 1's host: it hears the fleet in another order.
  auto daemon_standby =
      StartDaemon(On("r1", irrrd + Quoted(f.config_standby)), dir + "/standby.log");
  const std::string listen = std::string(IRRR_LISTEN) + " --config ";
  Background listen_a(
      On("base",
         listen + Quoted(f.config_a) + " --decisions " + Quoted(dir + "/listen.csv") +
             " --output " + Quoted(dir + "/listen.g2o")),
      dir + "/listen.log");
  Background listen_standby(
      On("r1",
         listen + Quoted(f.config_standby) + " --decisions " + Quoted(dir + "/listen_standby.csv")),
      dir + "/listen_standby.log");
  std::vector<std::unique_ptr<Background>> robot_listeners;
  for (int r = 1; r <= 3; ++r) {
    const std::string name = dir + "/robot" + std::to_string(r);
    robot_listeners.push_back(std::make_unique<Background>(
        On("r" + std::to_string(r),
           listen + Quoted(f.config_a) + " --robot " + std::to_string(r) + " --decisions " +
               Quoted(name + ".csv") + " --transforms " + Quoted(name + "_transforms.csv") +
               " --output " + Quoted(name + ".g2o")),
        name + "_listen.log"));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  std::vector<std::unique_ptr<Background>> injectors;
  for (int r = 1; r <= 3; ++r) {
    injectors.push_back(std::make_unique<Background>(
        On("r" + std::to_string(r),
           std::string(IRRR_INJECT) + " " + Quoted(f.input) + " --config " + Quoted(f.config_a) +
               " --robots " + kRobotsOfSessions + " --only-robot " + std::to_string(r) +
               " --sender robot" + std::to_string(r) + " --rate 50 --wait --timeout 300"),
        dir + "/inject" + std::to_string(r) + ".log"));
  }
  const auto start = std::chrono::steady_clock::now();
  auto seconds_since = [](std::chrono::steady_clock::time_point t) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
  };
  if (partition) {
    std::this_thread::sleep_for(std::chrono::seconds(2));
    SetPort("r2", false);
    std::this_thread::sleep_for(std::chrono::seconds(4));
    SetPort("r2", true);
  }
  for (int r = 1; r <= 3; ++r) {
    const int code = injectors[r - 1]->Wait();
    const std::string log = ReadText(dir + "/inject" + std::to_string(r) + ".log");
    INFO("robot " << r << ":\n" << log << ReadText(dir + "/base-a.log"));
    REQUIRE(code == 0);
    CHECK_THAT(log, Contains("the daemon is missing 0"));
  }
  std::printf("fleet %s: every robot's input taken by base-a %.1f s after the start\n",
              run.c_str(),
              seconds_since(start));
  // Listeners first: before writing, each asks its daemon for the whole solution.
  for (auto& l : robot_listeners) CHECK(l->Stop(SIGINT) == 0);
  CHECK(listen_a.Stop(SIGINT) == 0);
  CHECK(listen_standby.Stop(SIGINT) == 0);
  CHECK(daemon_a->Stop() == 0);
  CHECK(daemon_standby->Stop() == 0);
  for (const char* daemon : {"base-a", "standby"}) {
    const std::string log = ReadText(dir + "/" + daemon + ".log");
    CHECK_THAT(log, Contains("0 input(s) rejected"));
    CHECK_THAT(log, !Contains("also publishes"));  // nobody else on its correction channel
  }
}

std::vector<DecisionRow> ReadDecisions(const std::string& path) {
  std::ifstream in(path);
  std::vector<DecisionRow> rows;
  INFO(path);
  REQUIRE(ReadDecisionsCsv(in, &rows).ok());
  return rows;
}

std::map<int64_t, Pose2> ReadPoses(const std::string& path) {
  std::ifstream in(path);
  GraphFile<Pose2> file;
  INFO(path);
  REQUIRE(ReadGraphFile(in, FileFormat::kG2o, ReadOptions(), &file).ok());
  std::map<int64_t, Pose2> poses;
  for (const FileVertex<Pose2>& v : file.vertices) poses[v.id] = v.estimate;
  return poses;
}

int SessionOf(int64_t key) {
  int s = 0;
  while (s + 1 < 4 && key >= kSessionStarts[s + 1]) ++s;
  return s;
}

// Each robot got its own sessions' poses and transforms, in one map frame, and they match the
// ground truth (the clean graph's optimum, in the frame of session 0's first pose).
void CheckRobots(const Fleet& f, const std::string& dir) {
  const std::map<int64_t, Pose2> truth_world = ReadPoses(f.reference);
  const std::map<int64_t, Pose2> odometry = ReadPoses(f.input);  // each session from the origin
  const Pose2 world_T_map = truth_world.at(0);
  auto truth = [&](int64_t key) { return world_T_map.Inverse() * truth_world.at(key); };
  double worst_transform_m = 0.0;
  double worst_transform_rad = 0.0;
  double worst_pose_m = 0.0;
  for (int r = 1; r <= 3; ++r) {
    const std::string name = dir + "/robot" + std::to_string(r);
    INFO("robot " << r);
    // Its poses: exactly its sessions' keys.
    const std::map<int64_t, Pose2> poses = ReadPoses(name + ".g2o");
    int expected_poses = 0;
    for (int s = 0; s < 4; ++s) {
      if (kRobots[s] == r) {
        expected_poses += (s + 1 < 4 ? kSessionStarts[s + 1] : kPoses) - kSessionStarts[s];
      }
    }
    CHECK(static_cast<int>(poses.size()) == expected_poses);
    for (const auto& [key, pose] : poses) {
      CHECK(kRobots[SessionOf(key)] == r);
      worst_pose_m = std::max(worst_pose_m, (pose.translation() - truth(key).translation()).norm());
    }
    // Its transforms: one per session, all in component 0 (the map of session 0, robot 1).
    std::istringstream rows(ReadText(name + "_transforms.csv"));
    std::string line;
    std::getline(rows, line);
    CHECK(line == "robot_id,session_id,component,latest_key,x,y,z,qw,qx,qy,qz");
    int sessions = 0;
    while (std::getline(rows, line)) {
      int robot = 0, session = 0, component = 0;
      long long key = 0;
      double x = 0, y = 0, z = 0, qw = 0, qx = 0, qy = 0, qz = 0;
      REQUIRE(std::sscanf(line.c_str(),
                          "%d,%d,%d,%lld,%lf,%lf,%lf,%lf,%lf,%lf,%lf",
                          &robot,
                          &session,
                          &component,
                          &key,
                          &x,
                          &y,
                          &z,
                          &qw,
                          &qx,
                          &qy,
                          &qz) == 11);
      CHECK(robot == r);
      CHECK(kRobots[session] == r);
      CHECK(component == 0);
      const Pose2 map_T_odom(x, y, 2.0 * std::atan2(qz, qw));
      const Pose2 true_map_T_odom = truth(key) * odometry.at(key).Inverse();
      worst_transform_m = std::max(
          worst_transform_m, (map_T_odom.translation() - true_map_T_odom.translation()).norm());
      worst_transform_rad =
          std::max(worst_transform_rad, YawDifference(map_T_odom, true_map_T_odom));
      ++sessions;
    }
    CHECK(sessions == (r == 1 ? 2 : 1));
  }
  std::printf(
      "fleet %s: session-to-map transforms within %.3f m and %.4f rad of the ground "
      "truth, robots' poses within %.3f m\n",
      dir.c_str(),
      worst_transform_m,
      worst_transform_rad,
      worst_pose_m);
  CHECK(worst_transform_m < 0.25);
  CHECK(worst_transform_rad < 0.02);
  CHECK(worst_pose_m < 0.5);
}

TEST_CASE(
    "fleet: three robots and a base station merge into one map; two daemons agree; a "
    "partitioned robot catches up to the same result",
    "[.][fleet]") {
  const Fleet f = MakeFleet(TestDirectory("fleet"));
  // irrr-batch, which every daemon below must equal, accepts none of the 45 wrong loops.
  std::map<int, LoopState> batch_state;  // by the file's edge index
  for (const DecisionRow& row : ReadDecisions(f.dir + "/batch.csv")) {
    batch_state[row.edge_index] = row.decision.state;
  }
  int wrong = 0;
  {
    std::ifstream in(f.labels);
    std::vector<LabelRow> labels;
    REQUIRE(ReadLabelsCsv(in, &labels).ok());
    for (const LabelRow& l : labels) {
      REQUIRE(batch_state.count(l.edge_index) == 1);
      wrong += l.outlier ? 1 : 0;
      CHECK(!(l.outlier && batch_state[l.edge_index] == LoopState::kAccepted));
    }
  }
  REQUIRE(wrong == 45);

  for (const bool partition : {false, true}) {
    const std::string run = partition ? "partition" : "connected";
    INFO(run);
    RunFleet(f, run, partition);
    const std::string dir = f.dir + "/" + run;
    // Both daemons apply the file's own order (stamps), so irrr-batch's decisions and map; and
    // the second daemon's decisions are the first's, row for row, though it heard another order.
    std::filesystem::copy_file(f.dir + "/batch.csv", dir + "/batch.csv");
    std::filesystem::copy_file(f.dir + "/batch.g2o", dir + "/batch.g2o");
    CheckSameAsBatch(dir, /*all_edges_heard=*/!partition);
    CHECK(ReadText(dir + "/listen_standby.csv") == ReadText(dir + "/listen.csv"));
    CheckRobots(f, dir);
    if (partition) {
      // Robot 2's messages sent while its port was down came back through resync.
      const std::string log = ReadText(dir + "/inject2.log");
      INFO(log);
      CHECK_THAT(log, !Contains("resent 0 "));
    }
  }
}

}  // namespace
}  // namespace irrr
