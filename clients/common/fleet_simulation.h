#ifndef IRRR_CLIENTS_COMMON_FLEET_SIMULATION_H_
#define IRRR_CLIENTS_COMMON_FLEET_SIMULATION_H_

// A simulated day of a fleet in one SE(2) pose-graph file (irrr-simulate, tests): robots driving
// the streets of a Manhattan-world city, each run cut into sessions that start in frames of their
// own, with the loop hypotheses of a simulated place recognizer, true and wrong, in arrival order.
//
// The world: a grid of square blocks; streets run along the block edges. Each robot starts at a
// random intersection and drives the streets, turning only at intersections (keeping straight
// with `keep_straight_probability`, else left or right, never back; quarter circles of
// `corner_radius_m` round the corners), wandering slowly about the centre line. It takes a pose
// every `pose_spacing_m` of its path. Robots drive at the same time: the k-th pose of every robot
// is taken at step k. A robot's run is cut into `sessions_per_robot` sessions of (nearly) equal
// length; it drives on from where the session before ended, but its odometry restarts at the
// identity.
//
// The file (what core/graph_io.h's BuildPoseGraph reads as robots x sessions sessions):
//  - vertex ids 0..N-1: robot 0's sessions, then robot 1's, ...; each vertex's estimate is its
//    session's dead reckoning from the identity;
//  - odometry (i-1, i) inside each session: the true motion with noise e ~ N(0, Sigma_odometry)
//    in g2o's error chart (the residual at the true poses is e), information = information_scale
//    x Sigma_odometry^-1;
//  - loop hypotheses of a place recognizer. At each pose, with probability `recognition_rate`,
//    it claims one place it saw before (drawn uniformly among the candidates, if any): a pose
//    within `match_radius_m` and `match_heading_rad` of the current one that the current pose's
//    robot may claim (below). The claim is the true relative pose with noise e ~ N(0,
//    Sigma_loop), information = information_scale x Sigma_loop^-1. Wrong claims make up
//    `wrong_rate` of all hypotheses: random (translation uniform within `random_translation_m`
//    per axis, any rotation) or aliased (two places claimed to be nearly the same: translation
//    uniform in the disc of `aliased_translation_m`, rotation within `aliased_rotation_rad`, as
//    core/outliers.h draws them), lone or in groups of `group_size` links between runs of
//    consecutive poses that agree with each other and with the dead reckoning (link m joins the
//    m-th poses of the two runs). Every wrong link joins poses more than `wrong_min_distance_m`
//    apart in the world, so that no wrong claim is accidentally right. (Core's MakeOutliers
//    draws over a finished graph; these are drawn between poses the claiming robot may claim,
//    and away from the truth, so the generator draws its own);
//  - the edges in arrival order (core/irrr.h, ArrivalOrder): each pose's odometry, then the loops
//    whose later pose it is. A loop is written from its earlier pose to its later one, except
//    (i, i+1) across a session boundary, which would read back as odometry and is written (i+1,
//    i), its claim drawn in that direction.
//
// Who may claim what: a pose claims a place of its own robot taken before it (in its own
// session at least `min_loop_gap` poses before), or a place of a robot with a lower id taken at
// the same step or before. irrr-inject --robots --only-robot sends a loop from the robot of its
// later vertex id (replay_messages.h, AssignRobots), which is then also the robot whose pose is
// later in time, so each loop is sent once, by the robot that recognised the place, after the
// other robot has sent the place. (A robot recognising a higher-id robot's earlier place would
// be sent by that other robot, before the recognising pose exists: the simulation leaves such
// claims out.)
//
// Reproducible: one `seed` drives the trajectories, the noise, the recognizer and the wrong
// claims, each from a stream of its own (so that, e.g., a different wrong_rate keeps the true
// loops).

#include <cstdint>
#include <ostream>
#include <string>
#include <vector>

#include "clients/common/loop_csv.h"
#include "core/graph_io.h"
#include "core/pose.h"
#include "core/status.h"

namespace irrr {

struct FleetSimulationOptions {
  int poses = 5000;  // in all, split evenly over the robots (the first ones take the remainder)
  int robots = 3;
  int sessions_per_robot = 4;  // each robot's run cut into this many sessions of equal length
  // The city: grid_blocks_x x grid_blocks_y square blocks, block_length_m on a side.
  int grid_blocks_x = 6;
  int grid_blocks_y = 6;
  double block_length_m = 20.0;
  double pose_spacing_m = 1.0;              // along the path
  double keep_straight_probability = 0.6;   // at an intersection where the street goes on
  double corner_radius_m = 3.0;             // at most half a block
  double lane_wander_m = 0.2;               // sd of the lateral offset from the centre line
  double lane_wander_correlation_m = 20.0;  // the offset's correlation length along the path
  double odometry_sigma_xy_m = 0.05;        // per pose step, x and y
  double odometry_sigma_yaw_rad = 0.01;     // per pose step
  double loop_sigma_xy_m = 0.1;             // a true claim's noise
  double loop_sigma_yaw_rad = 0.02;         // its yaw
  double information_scale = 1.0;           // information = scale x covariance^-1; < 1: the
                                            // file claims more noise than there is
  double match_radius_m = 2.0;              // the recognizer's candidates: this close, and
  double match_heading_rad = 0.3;           // headings this close
  double recognition_rate = 0.3;            // probability of a claim at a pose with candidates
  int min_loop_gap = 20;                    // poses, within one session
  double wrong_rate = 0.1;                  // of all hypotheses, in [0, 1)
  double wrong_grouped_fraction = 0.5;      // of the wrong links, in groups
  double wrong_aliased_fraction = 0.5;      // of the wrong links and groups, aliased
  int group_size = 3;                       // links per wrong group
  double random_translation_m = 10.0;       // random claims: per axis, in [-r, r]
  double aliased_translation_m = 1.0;       // aliased claims: within this radius
  double aliased_rotation_rad = 0.3;        // aliased claims: yaw in [-a, a]
  double wrong_min_distance_m = 20.0;       // a wrong link's poses are farther apart
  uint32_t seed = 1;

  // Fails naming the first field out of its range: counts below 1 (min_loop_gap below 2, fewer
  // than 2 poses per session), lengths and sigmas that are not finite and positive, probabilities
  // and fractions outside [0, 1] (wrong_rate outside [0, 1)), a corner radius above half a block.
  Status Validate() const;
};

enum class SimulatedLoopKind {
  kTrue,     // the true relative pose with noise
  kRandom,   // a random claim
  kAliased,  // two distant places claimed to be nearly the same
};

// "true", "random", "aliased".
const char* SimulatedLoopKindName(SimulatedLoopKind kind);

struct SimulatedLoop {
  int edge_index = -1;  // in FleetSimulation::file.edges
  SimulatedLoopKind kind = SimulatedLoopKind::kTrue;
  bool grouped = false;  // a link of a wrong group
  int group = -1;        // wrong links: their group (lone links one of their own), numbered in file
                         // order; true loops: -1
  bool inter_robot = false;
};

struct FleetSimulationCounts {
  int poses = 0;
  int robots = 0;
  int sessions = 0;
  int odometry = 0;
  int true_intra_robot = 0;
  int true_inter_robot = 0;
  int random_lone = 0;  // wrong links by kind
  int aliased_lone = 0;
  int random_grouped = 0;
  int aliased_grouped = 0;
  int random_groups = 0;
  int aliased_groups = 0;

  int true_loops() const { return true_intra_robot + true_inter_robot; }
  int wrong_loops() const { return random_lone + aliased_lone + random_grouped + aliased_grouped; }
};

struct FleetSimulation {
  GraphFile<Pose2> file;                  // what irrr-simulate writes
  std::vector<Pose2> ground_truth;        // per vertex id, all robots in one world frame
  std::vector<int32_t> robot_of_session;  // per session, in id order (irrr-inject --robots)
  std::vector<int> robot_of_vertex;       // per vertex id
  std::vector<int> step_of_vertex;        // when the pose was taken (robots drive at once)
  std::vector<SimulatedLoop> loops;       // every loop edge of `file`, in file order
  std::vector<LabelRow> labels;           // the same, as irrr-corrupt labels them
  FleetSimulationCounts counts;
};

// Simulates the fleet of `options`. Fails (`simulation` untouched) on options Validate rejects, or
// when the wrong claims cannot be placed (a city too small for wrong_min_distance_m).
Status SimulateFleet(const FleetSimulationOptions& options, FleetSimulation* simulation);

// "3000 poses, 3 robots, 12 sessions, 2988 odometry edges; 176 true loops (101 intra-robot, 75
// inter-robot); 20 wrong loops (5 random, 6 aliased, 3 random in 1 group(s), 6 aliased in 2
// group(s))"
std::string FormatFleetSummary(const FleetSimulationCounts& counts);

// The robot of each session as irrr-inject --robots takes it: "0,0,0,0,1,1,1,1".
std::string RobotsList(const std::vector<int32_t>& robot_of_session);

// One "x y yaw" line per pose, 17 significant digits (what irrr-batch --ground-truth reads).
// Fails if the stream fails.
Status WriteGroundTruth(std::ostream& out, const std::vector<Pose2>& ground_truth);

}  // namespace irrr

#endif  // IRRR_CLIENTS_COMMON_FLEET_SIMULATION_H_
