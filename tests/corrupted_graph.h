#ifndef IRRR_TESTS_CORRUPTED_GRAPH_H_
#define IRRR_TESTS_CORRUPTED_GRAPH_H_

// A synthetic world with MakeOutliers' wrong loops appended, for the iRRR and speed tests.

#include <map>
#include <vector>

#include <catch2/catch.hpp>

#include "core/decisions.h"
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

// `clean` with MakeOutliers' wrong loops appended.
template <class Pose>
Corrupted<Pose> Corrupt(const PoseGraph<Pose>& clean, const OutlierOptions& outliers) {
  Corrupted<Pose> out;
  out.clean = clean;
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

template <class Pose>
Corrupted<Pose> MakeCorrupted(const SyntheticOptions& synthetic, const OutlierOptions& outliers) {
  return Corrupt(MakeSyntheticGraph<Pose>(synthetic).graph, outliers);
}

// `count` wrong loops of `mode` drawn with `seed` (the other OutlierOptions as default).
inline OutlierOptions Outliers(OutlierMode mode, int count, uint32_t seed) {
  OutlierOptions outliers;
  outliers.mode = mode;
  outliers.count = count;
  outliers.seed = seed;
  return outliers;
}

// Loops of a corrupted graph accepted by `decisions`, true and wrong.
struct AcceptedLoops {
  int true_loops = 0;
  int accepted_true = 0;
  int accepted_wrong = 0;
};

template <class Pose>
AcceptedLoops CountAccepted(const Corrupted<Pose>& corrupted,
                            const std::vector<LoopDecision>& decisions) {
  AcceptedLoops count;
  for (int e = 0; e < corrupted.graph.num_edges(); ++e) {
    if (corrupted.graph.edge(e).kind != EdgeKind::kLoop) continue;
    const bool accepted = decisions[e].state == LoopState::kAccepted;
    if (corrupted.is_outlier[e]) {
      count.accepted_wrong += accepted ? 1 : 0;
    } else {
      ++count.true_loops;
      count.accepted_true += accepted ? 1 : 0;
    }
  }
  return count;
}

// The loops `decisions` leave pending in a cluster of two links or more (only a lone link nothing
// can check yet may wait for good).
template <class Pose>
std::vector<int> PendingInClusters(const PoseGraph<Pose>& graph,
                                   const std::vector<LoopDecision>& decisions) {
  std::map<int, int> links_of_cluster;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kLoop) ++links_of_cluster[decisions[e].cluster];
  }
  std::vector<int> pending;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kLoop && decisions[e].state == LoopState::kPending &&
        links_of_cluster[decisions[e].cluster] >= 2) {
      pending.push_back(e);
    }
  }
  return pending;
}

// The edges of the map `decisions` leave: the odometry and the accepted loops (an `active` mask
// for Optimizer::Solve and SessionComponents).
template <class Pose>
std::vector<char> MapEdges(const PoseGraph<Pose>& graph,
                           const std::vector<LoopDecision>& decisions) {
  std::vector<char> active(graph.num_edges(), 0);
  for (int e = 0; e < graph.num_edges(); ++e) {
    active[e] =
        graph.edge(e).kind == EdgeKind::kOdometry || decisions[e].state == LoopState::kAccepted;
  }
  return active;
}

// `graph` with odometry edge `edge`'s measurement moved by `offset` (a fault), initial estimate
// unchanged.
template <class Pose>
PoseGraph<Pose> WithFault(const PoseGraph<Pose>& graph,
                          int edge,
                          const typename Pose::Tangent& offset) {
  PoseGraph<Pose> out;
  for (int s = 0; s < graph.num_sessions(); ++s) {
    int index = -1;
    REQUIRE(out.AddSession(graph.session(s).id, &index).ok());
  }
  for (int v = 0; v < graph.num_vertices(); ++v) {
    const int odometry = graph.OdometryInto(v);
    Pose measurement;
    if (odometry >= 0) {
      measurement = graph.edge(odometry).measurement;
      if (odometry == edge) measurement = measurement * Pose::Exp(offset);
    }
    int index = -1;
    REQUIRE(out.AddPose(graph.vertex(v).session,
                        graph.vertex(v).id,
                        graph.vertex(v).stamp,
                        graph.initial_estimate()[v],
                        odometry >= 0 ? &measurement : nullptr,
                        odometry >= 0 ? &graph.edge(odometry).information : nullptr,
                        &index)
                .ok());
  }
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose>& loop = graph.edge(e);
    if (loop.kind != EdgeKind::kLoop) continue;
    REQUIRE(out.AddLoop(loop.from, loop.to, loop.measurement, loop.information, nullptr).ok());
  }
  return out;
}

}  // namespace testing
}  // namespace irrr

#endif  // IRRR_TESTS_CORRUPTED_GRAPH_H_
