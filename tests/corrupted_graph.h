#ifndef IRRR_TESTS_CORRUPTED_GRAPH_H_
#define IRRR_TESTS_CORRUPTED_GRAPH_H_

// A synthetic world with MakeOutliers' wrong loops appended, for the iRRR and speed tests.

#include <vector>

#include <catch2/catch.hpp>

#include "core/outliers.h"
#include "tests/synthetic_graph.h"

namespace irrr {
namespace testing {

// 240 poses with small noise and conservative information, loops at half the revisits.
template <class Pose>
SyntheticOptions NoisyWorld(uint32_t seed) {
  SyntheticOptions options;
  options.num_poses = 240;
  options.translation_sigma_m = 0.05;
  options.rotation_sigma_rad = 0.01;
  options.loop_probability = 0.5;
  // Conservative information, like the public datasets': with exact information the per-link
  // test at alpha = 0.95 rejects about 5% of true links by construction.
  options.information_scale = 0.25;
  options.seed = seed;
  return options;
}

template <class Pose>
struct Corrupted {
  PoseGraph<Pose> clean;
  PoseGraph<Pose> graph;         // clean + outliers appended
  std::vector<char> is_outlier;  // per edge of `graph`
};

template <class Pose>
Corrupted<Pose> MakeCorrupted(const SyntheticOptions& synthetic, const OutlierOptions& outliers) {
  Corrupted<Pose> out;
  out.clean = MakeSyntheticGraph<Pose>(synthetic).graph;
  out.graph = out.clean;
  std::vector<OutlierLink<Pose>> links;
  const Status status = MakeOutliers(out.clean, outliers, &links);
  INFO(status.message());
  REQUIRE(status.ok());
  out.is_outlier.assign(out.clean.num_edges(), 0);
  for (const OutlierLink<Pose>& link : links) {
    REQUIRE(
        out.graph.AddLoop(link.from, link.to, link.measurement, link.information, nullptr).ok());
    out.is_outlier.push_back(1);
  }
  return out;
}

}  // namespace testing
}  // namespace irrr

#endif  // IRRR_TESTS_CORRUPTED_GRAPH_H_
