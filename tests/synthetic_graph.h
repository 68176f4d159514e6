#ifndef IRRR_TESTS_SYNTHETIC_GRAPH_H_
#define IRRR_TESTS_SYNTHETIC_GRAPH_H_

// Seeded synthetic pose graphs with known ground truth: the workhorse of the tests.
//  - SE(2) "grid world": unit steps on a grid with random 90-degree turns (like Manhattan);
//    a loop closes wherever the robot revisits a grid cell.
//  - SE(3) helix: a climbing spiral with roll/pitch wobble; loops join each pose to the pose one
//    revolution below.
// Noise is drawn in the tangent space and applied with Retract; information = inverse covariance.

#include <cstdint>
#include <vector>

#include "core/pose_graph.h"
#include "core/status.h"

namespace irrr::testing {

struct SyntheticOptions {
  int num_poses = 300;
  int num_sessions = 1;              // the trajectory is cut into this many consecutive sessions
  double translation_sigma_m = 0.0;  // noise of odometry and loop measurements
  double rotation_sigma_rad = 0.0;
  double loop_probability = 1.0;  // chance that a revisit yields a loop hypothesis
  int min_loop_separation = 10;   // loops only between poses at least this far apart in time
  // Information = information_scale x the inverse noise covariance. Below 1 the information is
  // conservative, as in public datasets (Manhattan's optimum has chi2 146 for ~6300 degrees of
  // freedom, a scale of about 0.02).
  double information_scale = 1.0;
  uint32_t seed = 1;
};

template <class Pose>
struct SyntheticGraph {
  PoseGraph<Pose> graph;
  std::vector<Pose> ground_truth;  // world frame, indexed like graph vertices
  std::vector<int> loop_edges;     // graph edge indices of the (true) loops
};

// Every session's initial estimate is its own dead reckoning from the identity (each session in
// its own frame). Loops may join sessions.
template <class Pose>
SyntheticGraph<Pose> MakeSyntheticGraph(const SyntheticOptions& options);

// One session with 5 cm / 0.01 rad noise on every measurement, 300 poses (400 in 3D).
template <class Pose>
SyntheticOptions NoisyOptions(uint32_t seed) {
  SyntheticOptions options;
  options.num_poses = Pose::kDim == 3 ? 400 : 300;
  options.translation_sigma_m = 0.05;
  options.rotation_sigma_rad = 0.01;
  options.seed = seed;
  return options;
}

// Adds a copy of loop `loop` whose measurement is moved by `translation_m` along the first axis
// and `rotation_rad` about the last (a wrong link beside a true one); returns its edge index.
template <class Pose>
int AddMovedCopy(PoseGraph<Pose>* graph, int loop, double translation_m, double rotation_rad) {
  const Edge<Pose> model = graph->edge(loop);
  typename Pose::Tangent offset = Pose::Tangent::Zero();
  offset(0) = translation_m;
  offset(Pose::kDim - 1) = rotation_rad;
  int edge = -1;
  const Status status = graph->AddLoop(
      model.from, model.to, model.measurement * Pose::Exp(offset), model.information, &edge);
  IRRR_CHECK(status.ok());
  return edge;
}

// Tolerance-free comparison helper: largest translation (m) and rotation (rad) difference
// between two trajectories after expressing both relative to pose `anchor`.
template <class Pose>
void RelativeDifference(const std::vector<Pose>& a,
                        const std::vector<Pose>& b,
                        int anchor,
                        double* max_translation_m,
                        double* max_rotation_rad);

}  // namespace irrr::testing

#endif  // IRRR_TESTS_SYNTHETIC_GRAPH_H_
