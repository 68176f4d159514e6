#ifndef IRRR_CORE_TIME_REVERSAL_H_
#define IRRR_CORE_TIME_REVERSAL_H_

// A pose graph with every session driven backwards, so that replaying it in arrival order
// (irrr.h, ArrivalOrder) delivers the same loops in roughly the reverse order: a way to measure
// whether iRRR's decisions depend on the order in which loops arrive.

#include <vector>

#include "core/pose_graph.h"

namespace irrr {

template <class Pose>
struct ReversedGraph {
  PoseGraph<Pose> graph;       // each session's poses in reverse time order
  std::vector<int> vertex_of;  // original vertex -> reversed vertex
  std::vector<int> edge_of;    // original edge -> reversed edge
};

// The time reversal of a valid graph (one built through PoseGraph):
//  - sessions keep their ids and order; vertices keep their ids, sessions and initial estimates.
//    Each vertex index of the original is taken by a pose of the same session (sessions that
//    interleave keep their interleaving), in reverse time order: the session's last pose where
//    its first was. Stamps are mirrored within the session, stamp' = last + first - stamp, so
//    that they increase along the reversed session.
//  - the odometry edge k -> k+1 (measurement z, information Omega) becomes the odometry edge
//    k+1 -> k of the reversed session: measurement z^-1, information transformed to first order
//    so that its d^2 at any estimate near z equals the original's.
//  - loop edges follow all poses, in their original order, with their endpoints renumbered:
//    direction, measurement and information unchanged.
// Reversing twice gives the original graph back (measurements and information to rounding). The
// graph must be valid (built through PoseGraph): a reversal PoseGraph refuses is a broken
// invariant (aborts).
template <class Pose>
ReversedGraph<Pose> TimeReversed(const PoseGraph<Pose>& graph);

// The information of the inverted measurement z^-1 of an edge whose measurement is z and
// information `information`, to first order (see time_reversal.cc).
template <class Pose>
typename Pose::Matrix InvertedInformation(const Pose& measurement,
                                          const typename Pose::Matrix& information);

}  // namespace irrr

#endif  // IRRR_CORE_TIME_REVERSAL_H_
