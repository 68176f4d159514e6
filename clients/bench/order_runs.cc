#include "clients/bench/order_runs.h"

#include <utility>

#include "core/optimizer.h"

namespace irrr {

const char* RunOrderNote(RunOrder order) {
  switch (order) {
    case RunOrder::kForward:
      return "";
    case RunOrder::kReversed:
      return "Order reversed: iRRR and RRR decided on the time reversal of each graph (every "
             "session driven backwards, so that loops arrive in roughly reverse order); their "
             "decisions and maps are scored on the original graph's edges and vertices.\n\n";
    case RunOrder::kBoth:
      return "Order both: iRRR also decided on the time reversal of each graph (every session "
             "driven backwards, so that loops arrive in roughly reverse order); its row holds the "
             "forward run's figures, and order diffs = the loops accepted in one order and not "
             "the other.\n\n";
  }
  return "";
}

template <class Pose>
void FromReversed(const PoseGraph<Pose>& graph,
                  const ReversedGraph<Pose>& reversed,
                  std::vector<char>* accepted,
                  std::vector<Pose>* estimate) {
  std::vector<char> accepted_here(graph.num_edges(), 0);
  std::vector<char> active(graph.num_edges(), 0);
  for (int e = 0; e < graph.num_edges(); ++e) {
    accepted_here[e] = (*accepted)[reversed.edge_of[e]];
    active[e] = graph.edge(e).kind == EdgeKind::kOdometry || accepted_here[e];
  }
  std::vector<Pose> estimate_here(graph.num_vertices());
  for (int v = 0; v < graph.num_vertices(); ++v) {
    estimate_here[v] = (*estimate)[reversed.vertex_of[v]];
  }
  // Components are numbered by their earliest session; each is re-anchored at that session's
  // first pose.
  const std::vector<int> component = SessionComponents(graph, active);
  std::vector<int> anchor(graph.num_sessions(), -1);  // per component
  for (int s = graph.num_sessions() - 1; s >= 0; --s) {
    if (!graph.session(s).vertices.empty())
      anchor[component[s]] = graph.session(s).vertices.front();
  }
  std::vector<Pose> anchor_inverse(graph.num_sessions());
  for (int c = 0; c < graph.num_sessions(); ++c) {
    if (anchor[c] >= 0) anchor_inverse[c] = estimate_here[anchor[c]].Inverse();
  }
  for (int v = 0; v < graph.num_vertices(); ++v) {
    estimate_here[v] = anchor_inverse[component[graph.vertex(v).session]] * estimate_here[v];
  }
  *accepted = std::move(accepted_here);
  *estimate = std::move(estimate_here);
}

template <class Pose>
int OrderDiffs(const PoseGraph<Pose>& graph,
               const std::vector<char>& accepted,
               const std::vector<char>& other) {
  int diffs = 0;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind == EdgeKind::kLoop && (accepted[e] != 0) != (other[e] != 0)) ++diffs;
  }
  return diffs;
}

template void FromReversed<Pose2>(const PoseGraph<Pose2>&,
                                  const ReversedGraph<Pose2>&,
                                  std::vector<char>*,
                                  std::vector<Pose2>*);
template void FromReversed<Pose3>(const PoseGraph<Pose3>&,
                                  const ReversedGraph<Pose3>&,
                                  std::vector<char>*,
                                  std::vector<Pose3>*);
template int OrderDiffs<Pose2>(const PoseGraph<Pose2>&,
                               const std::vector<char>&,
                               const std::vector<char>&);
template int OrderDiffs<Pose3>(const PoseGraph<Pose3>&,
                               const std::vector<char>&,
                               const std::vector<char>&);

}  // namespace irrr
