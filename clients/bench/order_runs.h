#ifndef IRRR_CLIENTS_BENCH_ORDER_RUNS_H_
#define IRRR_CLIENTS_BENCH_ORDER_RUNS_H_

// The accuracy benchmark's --order: a method run on the time reversal of a graph
// (core/time_reversal.h), its result brought back to the original graph, and how two runs'
// decisions differ.

#include <vector>

#include "core/time_reversal.h"

namespace irrr {

// Which order the sessions run in for iRRR and RRR.
enum class RunOrder {
  kForward,   // as recorded
  kReversed,  // every session driven backwards, so that loops arrive in roughly reverse order
  kBoth,      // iRRR in both orders, its decisions compared
};

// What the order means for the table, as a Markdown paragraph (empty for kForward).
const char* RunOrderNote(RunOrder order);

// A run's accepted loops (per edge of `reversed.graph`) and estimate (per vertex of it), brought
// back to `graph`'s edges and vertices, each connected component of the odometry and the accepted
// loops put in the frame of its earliest session's first pose in time order (as forward runs give
// their estimates; the reversed run anchors at that session's last pose), so that the map scores
// the same way. Both must come from a whole run on `reversed.graph`.
template <class Pose>
void FromReversed(const PoseGraph<Pose>& graph,
                  const ReversedGraph<Pose>& reversed,
                  std::vector<char>* accepted,
                  std::vector<Pose>* estimate);

// The loop edges of `graph` accepted in one of two runs and not in the other (per-edge flags).
template <class Pose>
int OrderDiffs(const PoseGraph<Pose>& graph,
               const std::vector<char>& accepted,
               const std::vector<char>& other);

}  // namespace irrr

#endif  // IRRR_CLIENTS_BENCH_ORDER_RUNS_H_
