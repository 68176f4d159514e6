#include "core/local_problem.h"

#include <algorithm>
#include <limits>

namespace irrr {

template <class Pose>
void AlignFrames(const PoseGraph<Pose>& graph,
                 const std::vector<int>& loops,
                 const std::vector<int>& group_of_session,
                 double cap,
                 std::vector<Pose>* x) {
  auto group_of = [&](int v) { return group_of_session[graph.vertex(v).session]; };
  std::vector<int> groups;
  for (int e : loops) {
    groups.push_back(group_of(graph.edge(e).from));
    groups.push_back(group_of(graph.edge(e).to));
  }
  std::sort(groups.begin(), groups.end());
  groups.erase(std::unique(groups.begin(), groups.end()), groups.end());
  if (groups.size() < 2) return;
  std::vector<char> placed(group_of_session.size(), 0);
  // Groups connect only through links, so each connected set of groups gets its own root.
  for (int root : groups) {
    if (placed[root]) continue;
    placed[root] = 1;
    while (true) {
      // The smallest unplaced group joined to a placed one.
      int next = -1;
      for (int e : loops) {
        const int a = group_of(graph.edge(e).from);
        const int b = group_of(graph.edge(e).to);
        if (placed[a] != placed[b]) {
          const int unplaced = placed[a] ? b : a;
          if (next < 0 || unplaced < next) next = unplaced;
        }
      }
      if (next < 0) break;
      std::vector<Pose> frame_T_next;  // per candidate link, the alignment it implies
      std::vector<int> candidates;
      for (int e : loops) {
        const Edge<Pose>& edge = graph.edge(e);
        const int a = group_of(edge.from);
        const int b = group_of(edge.to);
        if (!((a == next && placed[b]) || (b == next && placed[a]))) continue;
        candidates.push_back(e);
        // x_from * measurement = x_to must hold once `next` is moved by the alignment.
        frame_T_next.push_back(
            b == next ? (*x)[edge.from] * edge.measurement * (*x)[edge.to].Inverse()
                      : (*x)[edge.to] * edge.measurement.Inverse() * (*x)[edge.from].Inverse());
      }
      int best = 0;
      double best_cost = std::numeric_limits<double>::infinity();
      for (size_t j = 0; j < candidates.size(); ++j) {
        double cost = 0.0;
        for (int e : candidates) {
          const Edge<Pose>& edge = graph.edge(e);
          const bool to_moves = group_of(edge.to) == next;
          const Pose from = to_moves ? (*x)[edge.from] : frame_T_next[j] * (*x)[edge.from];
          const Pose to = to_moves ? frame_T_next[j] * (*x)[edge.to] : (*x)[edge.to];
          cost += std::min(EdgeChi2(edge, from, to), cap);
        }
        if (cost < best_cost) {
          best_cost = cost;
          best = static_cast<int>(j);
        }
      }
      for (int s = 0; s < graph.num_sessions(); ++s) {
        if (group_of_session[s] != next) continue;
        for (int v : graph.session(s).vertices) (*x)[v] = frame_T_next[best] * (*x)[v];
      }
      placed[next] = 1;
    }
  }
}

template <class Pose>
LocalProblems<Pose>::LocalProblems(const PoseGraph<Pose>* graph,
                                   const std::vector<Pose>* dead_reckoning,
                                   const OptimizerOptions& options)
    : graph_(graph), dead_reckoning_(dead_reckoning), optimizer_(options) {}

template <class Pose>
std::vector<char> LocalProblems<Pose>::SessionsOf(const std::vector<int>& loops) const {
  std::vector<char> sessions(graph_->num_sessions(), 0);
  for (int e : loops) {
    sessions[graph_->vertex(graph_->edge(e).from).session] = 1;
    sessions[graph_->vertex(graph_->edge(e).to).session] = 1;
  }
  return sessions;
}

template <class Pose>
LocalSolution LocalProblems<Pose>::Solve(const std::vector<char>& sessions,
                                         const std::vector<int>& loops,
                                         double alignment_cap,
                                         std::vector<Pose>* estimate) {
  return Solve(sessions, loops, alignment_cap, estimate, false);
}

template <class Pose>
LocalSolution LocalProblems<Pose>::InternalRedundancy(const std::vector<int>& loops,
                                                      double alignment_cap) {
  return Solve(SessionsOf(loops), loops, alignment_cap, nullptr, true);
}

template <class Pose>
LocalSolution LocalProblems<Pose>::Solve(const std::vector<char>& sessions,
                                         const std::vector<int>& loops,
                                         double alignment_cap,
                                         std::vector<Pose>* estimate,
                                         bool split_sides) {
  // The same problem as the last one (Algorithm 1 after the own-factor sample, say): its result.
  std::vector<int> key_loops = loops;
  std::sort(key_loops.begin(), key_loops.end());
  const bool same = estimate == nullptr && last_.valid && last_.split == split_sides &&
                    last_.cap == alignment_cap && last_.sessions == sessions &&
                    last_.loops == key_loops && last_.num_vertices == graph_->num_vertices();
  if (same) return last_.solution;
  const PoseGraph<Pose>& graph = *graph_;
  const int num_sessions = graph.num_sessions();
  IRRR_CHECK(static_cast<int>(sessions.size()) == num_sessions);
  // Each session's span: its first and last loop endpoint (positions in the session).
  std::vector<int> first(num_sessions, -1);
  std::vector<int> last(num_sessions, -1);
  auto position = [&graph](int v) {
    const std::vector<int>& vertices = graph.session(graph.vertex(v).session).vertices;
    return static_cast<int>(std::lower_bound(vertices.begin(), vertices.end(), v) -
                            vertices.begin());
  };
  for (int e : loops) {
    for (int v : {graph.edge(e).from, graph.edge(e).to}) {
      const int s = graph.vertex(v).session;
      IRRR_CHECK(sessions[s]);
      const int p = position(v);
      first[s] = first[s] < 0 ? p : std::min(first[s], p);
      last[s] = std::max(last[s], p);
    }
  }
  std::vector<Pose> x = *dead_reckoning_;
  std::vector<int> group_of_session(num_sessions);
  for (int s = 0; s < num_sessions; ++s) group_of_session[s] = s;
  AlignFrames(graph, loops, group_of_session, alignment_cap, &x);

  // The subproblem: one session per span, then the loops.
  struct Span {
    int session;
    int first;
    int last;
  };
  std::vector<Span> spans;
  for (int s = 0; s < num_sessions; ++s) {
    if (first[s] >= 0) spans.push_back({s, first[s], last[s]});
  }
  if (split_sides && spans.size() == 1) {
    // One session: its loops' later ends (side a) and earlier ends (side b), each a span of its
    // own if they do not overlap; the odometry between them is left out.
    int first_a = std::numeric_limits<int>::max();
    int last_b = -1;
    for (int e : loops) {
      const int p = position(graph.edge(e).from);
      const int q = position(graph.edge(e).to);
      first_a = std::min(first_a, std::max(p, q));
      last_b = std::max(last_b, std::min(p, q));
    }
    if (last_b < first_a) {
      const Span whole = spans.front();
      spans = {{whole.session, whole.first, last_b}, {whole.session, first_a, whole.last}};
    }
  }
  // The poses kept in each session: every pose of its spans, or with chains_ only the loops'
  // endpoints (the odometry between two of them compounded into one edge).
  const bool compound = chains_ != nullptr && estimate == nullptr;
  std::vector<std::vector<int>> endpoints(num_sessions);
  if (compound) {
    for (int e : loops) {
      for (int v : {graph.edge(e).from, graph.edge(e).to}) {
        endpoints[graph.vertex(v).session].push_back(position(v));
      }
    }
    for (std::vector<int>& p : endpoints) {
      std::sort(p.begin(), p.end());
      p.erase(std::unique(p.begin(), p.end()), p.end());
    }
  }
  const typename Pose::Matrix M = TangentOfErrorVector<Pose>();
  PoseGraph<Pose> sub;
  std::vector<int> graph_edge_of_sub;  // -1 for a compounded stretch of odometry
  std::vector<int> sub_vertex(graph.num_vertices(), -1);
  std::vector<Pose> sub_x;
  for (size_t k_span = 0; k_span < spans.size(); ++k_span) {
    const Span& span = spans[k_span];
    int sub_session = -1;
    IRRR_CHECK(sub.AddSession(static_cast<int64_t>(k_span), &sub_session).ok());
    const std::vector<int>& vertices = graph.session(span.session).vertices;
    // Right perturbation covariance C of the compounded dead reckoning from position a to b; the
    // residual (g2o's chart) reads xi = M r, so its information is M' C^-1 M.
    auto compounded_information = [&](int a, int b) {
      const typename Pose::Matrix C = chains_->Relative(span.session, a, b);
      const typename Pose::Matrix information = M.transpose() * C.inverse() * M;
      return typename Pose::Matrix(0.5 * (information + information.transpose()));
    };
    std::vector<int> kept;
    std::vector<typename Pose::Matrix> stretch_information;  // per kept pose, from the previous
    if (compound) {
      for (int k : endpoints[span.session]) {
        if (k < span.first || k > span.last) continue;
        if (!kept.empty() && k > kept.back() + 1) {
          const typename Pose::Matrix information = compounded_information(kept.back(), k);
          if (!ValidateInformation<Pose>(information).ok()) {
            // Odometry of magnitudes whose compounding overflows (or loses definiteness): the
            // stretch's own poses and edges instead.
            for (int between = kept.back() + 1; between < k; ++between) {
              kept.push_back(between);
              stretch_information.emplace_back();
            }
          }
          stretch_information.push_back(information);
        } else {
          stretch_information.emplace_back();
        }
        kept.push_back(k);
      }
    } else {
      for (int k = span.first; k <= span.last; ++k) kept.push_back(k);
    }
    for (size_t j = 0; j < kept.size(); ++j) {
      const int v = vertices[kept[j]];
      Pose measurement;
      typename Pose::Matrix information;
      bool has_odometry = false;
      if (j > 0 && kept[j] == kept[j - 1] + 1) {
        const int odometry_edge = graph.OdometryInto(v);
        measurement = graph.edge(odometry_edge).measurement;
        information = graph.edge(odometry_edge).information;
        has_odometry = true;
        graph_edge_of_sub.push_back(odometry_edge);
      } else if (j > 0) {
        const int u = vertices[kept[j - 1]];
        measurement = (*dead_reckoning_)[u].Inverse() * (*dead_reckoning_)[v];
        information = stretch_information[j];
        has_odometry = true;
        graph_edge_of_sub.push_back(-1);
      }
      int index = -1;
      IRRR_CHECK(sub.AddPose(sub_session,
                             v,
                             graph.vertex(v).stamp,
                             x[v],
                             has_odometry ? &measurement : nullptr,
                             has_odometry ? &information : nullptr,
                             &index)
                     .ok());
      sub_vertex[v] = index;
      sub_x.push_back(x[v]);
    }
  }
  for (int e : loops) {
    const Edge<Pose>& edge = graph.edge(e);
    IRRR_CHECK(sub.AddLoop(sub_vertex[edge.from],
                           sub_vertex[edge.to],
                           edge.measurement,
                           edge.information,
                           nullptr)
                   .ok());
    graph_edge_of_sub.push_back(e);
  }
  LocalSolution solution;
  OptimizerSummary& summary = solution.summary;
  summary = optimizer_.Solve(sub, std::vector<char>(sub.num_edges(), 1), &sub_x);
  solution.poses_optimized = sub.num_vertices();
  ++solves_;
  iterations_ += summary.iterations;
  std::vector<double> edge_chi2(graph.num_edges(), 0.0);
  for (size_t k = 0; k < graph_edge_of_sub.size(); ++k) {
    if (graph_edge_of_sub[k] >= 0) edge_chi2[graph_edge_of_sub[k]] = summary.edge_chi2[k];
  }
  summary.edge_chi2 = std::move(edge_chi2);

  // The whole problem's dimensions: every odometry edge of `sessions` and the loops; every pose
  // of `sessions` free but one per component.
  std::vector<char> active_loops(graph.num_edges(), 0);
  for (int e : loops) active_loops[e] = 1;
  const std::vector<int> component = SessionComponents(graph, active_loops);
  std::vector<char> component_seen(num_sessions, 0);
  int odometry_edges = 0;
  int poses = 0;
  int components = 0;
  for (int s = 0; s < num_sessions; ++s) {
    if (!sessions[s]) continue;
    const int n = static_cast<int>(graph.session(s).vertices.size());
    poses += n;
    odometry_edges += std::max(n - 1, 0);
    if (!component_seen[component[s]]) {
      component_seen[component[s]] = 1;
      ++components;
    }
  }
  summary.num_active_edges = odometry_edges + static_cast<int>(loops.size());
  summary.residual_dimension = Pose::kDim * summary.num_active_edges;
  summary.free_parameters = Pose::kDim * (poses - components);
  summary.num_components = components;
  if (spans.size() == 2 && spans[0].session == spans[1].session) {
    // Split sides: the odometry between them is left out, d more rows than free parameters.
    summary.residual_dimension -= Pose::kDim * (spans[1].first - spans[0].last);
    summary.free_parameters -= Pose::kDim * (spans[1].first - spans[0].last - 1);
    summary.num_active_edges -= spans[1].first - spans[0].last;
  }
  solution.chi2 = summary.final_chi2;
  solution.dof = summary.residual_dimension - summary.free_parameters;
  last_.valid = true;
  last_.split = split_sides;
  last_.cap = alignment_cap;
  last_.sessions = sessions;
  last_.loops = key_loops;
  last_.num_vertices = graph.num_vertices();
  last_.solution = solution;

  if (estimate != nullptr) {
    estimate->resize(graph.num_vertices());
    size_t sub_index = 0;  // spans lie in the subproblem session by session
    for (int s = 0; s < num_sessions; ++s) {
      if (!sessions[s]) continue;
      const std::vector<int>& vertices = graph.session(s).vertices;
      const int n = static_cast<int>(vertices.size());
      if (first[s] < 0) {
        // No loop: the session keeps its own frame, along its odometry.
        for (int v : vertices) (*estimate)[v] = (*dead_reckoning_)[v];
        continue;
      }
      for (int k = first[s]; k <= last[s]; ++k) (*estimate)[vertices[k]] = sub_x[sub_index++];
      for (int k = first[s] - 1; k >= 0; --k) {
        (*estimate)[vertices[k]] =
            (*estimate)[vertices[k + 1]] *
            graph.edge(graph.OdometryInto(vertices[k + 1])).measurement.Inverse();
      }
      for (int k = last[s] + 1; k < n; ++k) {
        (*estimate)[vertices[k]] =
            (*estimate)[vertices[k - 1]] * graph.edge(graph.OdometryInto(vertices[k])).measurement;
      }
    }
    // Gauge: each component in the frame of its earliest session's first pose.
    std::vector<char> anchored(num_sessions, 0);
    for (int s = 0; s < num_sessions; ++s) {
      if (!sessions[s] || anchored[component[s]] || graph.session(s).vertices.empty()) continue;
      anchored[component[s]] = 1;
      const Pose origin_T_anchor = (*estimate)[graph.session(s).vertices.front()].Inverse();
      for (int t = s; t < num_sessions; ++t) {
        if (!sessions[t] || component[t] != component[s]) continue;
        for (int v : graph.session(t).vertices) (*estimate)[v] = origin_T_anchor * (*estimate)[v];
      }
    }
  }
  return solution;
}

template void AlignFrames<Pose2>(const PoseGraph<Pose2>&,
                                 const std::vector<int>&,
                                 const std::vector<int>&,
                                 double,
                                 std::vector<Pose2>*);
template void AlignFrames<Pose3>(const PoseGraph<Pose3>&,
                                 const std::vector<int>&,
                                 const std::vector<int>&,
                                 double,
                                 std::vector<Pose3>*);
template class LocalProblems<Pose2>;
template class LocalProblems<Pose3>;

}  // namespace irrr
