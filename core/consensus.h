#ifndef IRRR_CORE_CONSENSUS_H_
#define IRRR_CORE_CONSENSUS_H_

// Internal to core (included by irrr.cc and warm_engine.h only): the clusters and sets of the
// paper's Algorithms 1-3 over one graph, and the cold checks (every optimization from dead
// reckoning) that batch RRR and the paper-faithful preset run.

#include <algorithm>
#include <cmath>
#include <deque>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <numeric>
#include <tuple>
#include <vector>

#include "core/irrr.h"
#include "core/optimizer.h"
#include "core/pose_graph.h"
#include "core/test_statistics.h"

namespace irrr::internal {

// The sets of Algorithms 1-3 over one graph, shared by the incremental engine and batch RRR.
// Clusters are indices; each holds the links (graph edge indices) that survived Algorithm 1.
template <class Pose>
struct Consensus {
  struct Solution {
    OptimizerSummary summary;
    std::vector<Pose> estimate;
  };

  const PoseGraph<Pose>* graph = nullptr;
  const IrrrOptions* options = nullptr;
  std::vector<LoopDecision>* decisions = nullptr;
  // Per-session dead reckoning (each session from the identity), one pose per vertex.
  const std::vector<Pose>* dead_reckoning = nullptr;
  // Warm start for the joint tests (incremental only): the estimate of the previous step, whose
  // sessions share a frame within each component `warm_group` (per session) names.
  const std::vector<Pose>* warm = nullptr;
  std::vector<int> warm_group;

  std::vector<std::vector<int>> odometry_of_session;  // odometry edge indices per session
  std::vector<std::vector<int>> links;                // per cluster: links still in it
  std::vector<int> session_a;                         // per cluster: its two sessions
  std::vector<int> session_b;
  std::vector<char> in_r;  // passed Algorithm 1 (the paper's set R)
  std::vector<char> in_good;
  std::vector<char> in_reject;
  // Per good cluster: the candidates Algorithm 2 eliminated while it was inconsistent too.
  std::vector<std::vector<int>> opponents;
  // Per cluster (warm engine): Algorithm 1's redundancy, the chi2 of its surviving links with
  // odometry at their optimum and its degrees of freedom (0: none, a single link).
  std::vector<RedundancySample> redundancy;
  int step = 0;
  int solves = 0;      // optimizations run (reused ones not counted)
  int iterations = 0;  // their Gauss-Newton / Levenberg-Marquardt iterations

  // Changes whenever `warm` does: warm-started problems of different versions differ.
  int64_t warm_version = 0;
  // Optional: runs body(0), ..., body(n - 1), possibly concurrently, and returns when all are
  // done; with two or more workers, problems the algorithm is about to ask for are prefetched.
  ParallelFor parallel_for;
  int workers = 1;

  int AddCluster(int a, int b) {
    links.emplace_back();
    session_a.push_back(a);
    session_b.push_back(b);
    in_r.push_back(0);
    in_good.push_back(0);
    in_reject.push_back(0);
    opponents.emplace_back();
    redundancy.emplace_back();
    return static_cast<int>(links.size()) - 1;
  }

  // Every threshold is a chi-square quantile times `variance`, the variance factor of the
  // information (1 for the cold engines: the information as given).
  double variance = 1.0;
  // The degrees of freedom of `variance` as an estimate (infinite: known exactly; the tests are
  // then chi-square tests, otherwise F tests, see ScaledChiSquareThreshold).
  double variance_dof = std::numeric_limits<double>::infinity();
  // The warm engine's Algorithm 1 counts the graph test's degrees of freedom exactly, and when
  // its graph test fails drops the most suspect links one at a time without first testing every
  // link alone (with the variance factor known, the wrong link stands out; the warm engine's
  // screen and joint test judge each link against the good set afterwards).
  bool exact_graph_dof = false;
  bool individual_checks = true;
  int intra_lookahead = 0;  // > 0: Algorithm 1's lookahead instead of the options'

  // The threshold of a chi2 statistic with `dof` degrees of freedom.
  double Threshold(double dof) const {
    return ScaledChiSquareThreshold(options->alpha, dof, variance, variance_dof);
  }

  double LinkThreshold() const { return Threshold(Pose::kDim); }

  double GraphThreshold(const OptimizerSummary& summary) const {
    const int rows = summary.residual_dimension;
    const bool exact = exact_graph_dof || options->graph_dof == GraphDegreesOfFreedom::kExact;
    const int dof = exact ? rows - summary.free_parameters : rows;
    return Threshold(std::max(dof, 1));
  }

  void SetDecision(
      int edge, LoopState state, double chi2, double threshold, std::vector<int>* changed) {
    LoopDecision& d = (*decisions)[edge];
    if (d.state != state) {
      d.state = state;
      d.step = step;
      if (changed != nullptr) changed->push_back(edge);
    }
    d.chi2 = chi2;
    d.threshold = threshold;
  }

  // Position of vertex v in its session's time order.
  int PositionInSession(int v) const {
    const std::vector<int>& vertices = graph->session(graph->vertex(v).session).vertices;
    return static_cast<int>(std::lower_bound(vertices.begin(), vertices.end(), v) -
                            vertices.begin());
  }

  // Brings the frame groups that `loop_edges` join into one frame (the group of the earliest
  // session), group by group in increasing group order. A group is placed through the link, among
  // those joining it to the groups already placed, that the others agree with best: the one whose
  // alignment minimises the sum of the links' d^2, each capped at kAlignmentCap x the per-link
  // threshold. A single wrong link (the first of a cluster, say) therefore cannot set the frame
  // of a session (algorithm-notes, "Tests": the other session's initial frame from a link).
  void AlignGroups(const std::vector<int>& loop_edges,
                   const std::vector<int>& group_of_session,
                   std::vector<Pose>* x) const {
    constexpr double kAlignmentCap = 10.0;
    const double cap = kAlignmentCap * LinkThreshold();
    auto group_of = [&](int v) { return group_of_session[graph->vertex(v).session]; };
    std::vector<int> groups;
    for (int e : loop_edges) {
      groups.push_back(group_of(graph->edge(e).from));
      groups.push_back(group_of(graph->edge(e).to));
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
        // The smallest unplaced group joined to a placed one, and the links joining them.
        int next = -1;
        for (int e : loop_edges) {
          const int a = group_of(graph->edge(e).from);
          const int b = group_of(graph->edge(e).to);
          if (placed[a] != placed[b]) {
            const int unplaced = placed[a] ? b : a;
            if (next < 0 || unplaced < next) next = unplaced;
          }
        }
        if (next < 0) break;
        std::vector<Pose> frame_T_next;  // per candidate link, the alignment it implies
        std::vector<int> candidates;
        for (int e : loop_edges) {
          const Edge<Pose>& edge = graph->edge(e);
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
            const Edge<Pose>& edge = graph->edge(e);
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
        for (int s = 0; s < graph->num_sessions(); ++s) {
          if (group_of_session[s] != next) continue;
          for (int v : graph->session(s).vertices) (*x)[v] = frame_T_next[best] * (*x)[v];
        }
        placed[next] = 1;
      }
    }
  }

  // One optimization of Solve, before it runs: the loops (sorted), each session's span and the
  // start. `key` names it completely: two problems with equal keys have bit-identical optima.
  struct Problem {
    std::vector<int> loop_edges;
    std::vector<int> first;  // per session: first position in the problem (-1: not in it)
    std::vector<int> last;
    bool warm_start = false;
    std::vector<int64_t> key;
  };

  // The optimum of a Problem: summary with edge_chi2 indexed like the subproblem's edges
  // (sessions' odometry span by span, then the loops), and its poses span by span.
  struct Optimum {
    OptimizerSummary summary;
    std::vector<int> graph_edge_of_sub;
    std::vector<Pose> sub_x;
  };

  std::unique_ptr<Optimizer<Pose>> optimizer;  // SerialOptimizer()
  // Optima by Problem key (options->reuse_solves), and their keys in the order they came.
  std::map<std::vector<int64_t>, std::shared_ptr<const Optimum>> memo;
  std::deque<std::vector<int64_t>> memo_order;

  Problem Prepare(const std::vector<char>& sessions,
                  const std::vector<int>& clusters,
                  bool use_warm) const {
    const int num_sessions = graph->num_sessions();
    Problem p;
    for (int c : clusters)
      p.loop_edges.insert(p.loop_edges.end(), links[c].begin(), links[c].end());
    std::sort(p.loop_edges.begin(), p.loop_edges.end());
    p.warm_start = use_warm && warm != nullptr && options->warm_start;
    p.first.assign(num_sessions, -1);
    p.last.assign(num_sessions, -1);
    auto extend = [&](int v) {
      const int s = graph->vertex(v).session;
      const int position = PositionInSession(v);
      p.first[s] = p.first[s] < 0 ? position : std::min(p.first[s], position);
      p.last[s] = std::max(p.last[s], position);
    };
    for (int e : p.loop_edges) {
      extend(graph->edge(e).from);
      extend(graph->edge(e).to);
    }
    for (int s = 0; s < num_sessions; ++s) {
      if (!sessions[s] || p.first[s] < 0) {
        p.first[s] = p.last[s] = -1;
      } else if (!options->local_problems) {
        p.first[s] = 0;
        p.last[s] = static_cast<int>(graph->session(s).vertices.size()) - 1;
      }
    }
    p.key.push_back(p.warm_start ? warm_version : -1);
    p.key.insert(p.key.end(), p.loop_edges.begin(), p.loop_edges.end());
    p.key.push_back(-1);
    for (int s = 0; s < num_sessions; ++s) {
      if (p.first[s] < 0) continue;
      p.key.insert(p.key.end(), {s, p.first[s], p.last[s]});
    }
    return p;
  }

  // Runs the optimization of `p` with `solver` (whose kept symbolic analysis, if its pattern
  // matches, changes nothing in the result). Reads shared state only: safe to run concurrently.
  Optimum Compute(const Problem& p, Optimizer<Pose>* solver) const {
    const int num_sessions = graph->num_sessions();
    // Start: warm estimate or per-session dead reckoning, then frame groups aligned.
    std::vector<Pose> x = p.warm_start ? *warm : *dead_reckoning;
    x.resize(graph->num_vertices());
    std::vector<int> group_of_session(num_sessions);
    for (int s = 0; s < num_sessions; ++s) group_of_session[s] = p.warm_start ? warm_group[s] : s;
    AlignGroups(p.loop_edges, group_of_session, &x);

    // The subproblem: one sub-session per span, then the loops.
    Optimum optimum;
    PoseGraph<Pose> sub;
    std::vector<int> sub_vertex(graph->num_vertices(), -1);
    for (int s = 0; s < num_sessions; ++s) {
      if (p.first[s] < 0) continue;
      int sub_session = -1;
      IRRR_CHECK(sub.AddSession(s, &sub_session).ok());
      const std::vector<int>& vertices = graph->session(s).vertices;
      for (int k = p.first[s]; k <= p.last[s]; ++k) {
        const int v = vertices[k];
        const Edge<Pose>* odometry =
            k > p.first[s] ? &graph->edge(odometry_of_session[s][k - 1]) : nullptr;
        if (odometry != nullptr) optimum.graph_edge_of_sub.push_back(odometry_of_session[s][k - 1]);
        int index = -1;
        IRRR_CHECK(sub.AddPose(sub_session,
                               v,
                               graph->vertex(v).stamp,
                               x[v],
                               odometry ? &odometry->measurement : nullptr,
                               odometry ? &odometry->information : nullptr,
                               &index)
                       .ok());
        sub_vertex[v] = index;
        optimum.sub_x.push_back(x[v]);
      }
    }
    for (int e : p.loop_edges) {
      const Edge<Pose>& edge = graph->edge(e);
      IRRR_CHECK(sub_vertex[edge.from] >= 0 && sub_vertex[edge.to] >= 0);
      IRRR_CHECK(sub.AddLoop(sub_vertex[edge.from],
                             sub_vertex[edge.to],
                             edge.measurement,
                             edge.information,
                             nullptr)
                     .ok());
      optimum.graph_edge_of_sub.push_back(e);
    }
    optimum.summary = solver->Solve(sub, std::vector<char>(sub.num_edges(), 1), &optimum.sub_x);
    return optimum;
  }

  // The optimizer of the serial path: one kept across solves (its symbolic analysis serves every
  // next solve of the same sparsity pattern), or a fresh one per solve without reuse_analysis.
  Optimizer<Pose>* SerialOptimizer() {
    if (!optimizer || !options->reuse_analysis) {
      optimizer = std::make_unique<Optimizer<Pose>>(options->optimizer);
    }
    return optimizer.get();
  }

  // An optimization that ran (looked-up ones are not counted).
  void Count(const Optimum& optimum) {
    ++solves;
    iterations += optimum.summary.iterations;
  }

  std::shared_ptr<const Optimum> Lookup(const std::vector<int64_t>& key) const {
    if (!options->reuse_solves) return nullptr;
    const auto it = memo.find(key);
    return it == memo.end() ? nullptr : it->second;
  }

  void Remember(const std::vector<int64_t>& key, std::shared_ptr<const Optimum> optimum) {
    if (!options->reuse_solves || memo.count(key) != 0) return;
    // First in, first out: a solve is asked again soon after it ran (the line-8 optimization
    // after Algorithm 1, the final one after a passing joint test) or after its prefetch.
    constexpr size_t kCapacity = 32;
    if (memo_order.size() >= kCapacity) {
      memo.erase(memo_order.front());
      memo_order.pop_front();
    }
    memo.emplace(key, std::move(optimum));
    memo_order.push_back(key);
  }

  // Runs the problems not solved yet concurrently (when a parallel-for with two or more workers
  // is set and solves are reused), so that the serial algorithm finds them done. The results are
  // those the serial algorithm would compute, so decisions do not depend on it.
  void Prefetch(const std::vector<Problem>& problems) {
    if (!parallel_for || workers < 2 || !options->reuse_solves) return;
    std::vector<const Problem*> missing;
    for (const Problem& p : problems) {
      if (Lookup(p.key) != nullptr) continue;
      const bool listed = std::any_of(
          missing.begin(), missing.end(), [&p](const Problem* q) { return q->key == p.key; });
      if (!listed) missing.push_back(&p);
    }
    if (missing.size() < 2) return;  // nothing to run beside it: the serial path does it
    std::vector<std::shared_ptr<const Optimum>> results(missing.size());
    parallel_for(static_cast<int>(missing.size()), [&](int i) {
      Optimizer<Pose> local(options->optimizer);
      results[i] = std::make_shared<const Optimum>(Compute(*missing[i], &local));
    });
    for (size_t i = 0; i < missing.size(); ++i) {
      Count(*results[i]);
      Remember(missing[i]->key, std::move(results[i]));
    }
  }

  // Optimizes the odometry of `sessions` plus the links of `clusters` (the paper's PoseGraphIC,
  // PoseGraphPR or PoseGraphJC). Returns a summary whose edge_chi2 is indexed like the graph and
  // whose chi2, residual_dimension and free_parameters are those of the whole problem, so the
  // graph test means what the paper says.
  //
  // Locality: a stretch of odometry that no loop closes (before the first or after the last loop
  // endpoint of a session) has zero residual at the optimum, so only each session's span between
  // its first and last loop endpoint is optimized (options->local_problems). The start is the
  // dead reckoning of each session, or with `warm` the caller's estimate (whose frame groups are
  // the sessions' components in `warm_group`); groups joined by links are then aligned through
  // their most agreed-on link. With `estimate`, the complete optimum of `sessions` is returned
  // (the unlooped stretches chained along their odometry), each component in the frame of its
  // earliest session's first pose; other vertices are copied from `base`.
  //
  // Reuse (options->reuse_solves): an optimization asked again with the same problem (same loops,
  // spans and start) is not run again.
  Solution Solve(const std::vector<char>& sessions,
                 const std::vector<int>& clusters,
                 bool use_warm,
                 const std::vector<Pose>* base = nullptr) {
    const Problem p = Prepare(sessions, clusters, use_warm);
    std::shared_ptr<const Optimum> optimum = Lookup(p.key);
    if (optimum == nullptr) {
      optimum = std::make_shared<const Optimum>(Compute(p, SerialOptimizer()));
      Count(*optimum);
      Remember(p.key, optimum);
    }
    return Finish(sessions, p, *optimum, base);
  }

  Solution Finish(const std::vector<char>& sessions,
                  const Problem& p,
                  const Optimum& optimum,
                  const std::vector<Pose>* base) const {
    const int num_sessions = graph->num_sessions();
    Solution solution;
    OptimizerSummary& summary = solution.summary;
    summary = optimum.summary;
    std::vector<double> edge_chi2(graph->num_edges(), 0.0);
    for (size_t k = 0; k < optimum.graph_edge_of_sub.size(); ++k)
      edge_chi2[optimum.graph_edge_of_sub[k]] = optimum.summary.edge_chi2[k];
    summary.edge_chi2 = std::move(edge_chi2);

    // The whole problem's dimensions: every odometry edge of `sessions` and the loops; every
    // pose of `sessions` free but one per component.
    int odometry_edges = 0;
    int poses = 0;
    std::vector<char> active_loops(graph->num_edges(), 0);
    for (int e : p.loop_edges) active_loops[e] = 1;
    const std::vector<int> component = SessionComponents(*graph, active_loops);
    std::vector<char> component_seen(num_sessions, 0);
    int components = 0;
    for (int s = 0; s < num_sessions; ++s) {
      if (!sessions[s]) continue;
      odometry_edges += static_cast<int>(odometry_of_session[s].size());
      poses += static_cast<int>(graph->session(s).vertices.size());
      if (!component_seen[component[s]]) {
        component_seen[component[s]] = 1;
        ++components;
      }
    }
    summary.num_active_edges = odometry_edges + static_cast<int>(p.loop_edges.size());
    summary.residual_dimension = Pose::kDim * summary.num_active_edges;
    summary.free_parameters = Pose::kDim * (poses - components);
    summary.num_components = components;

    if (base != nullptr) {
      solution.estimate = *base;
      solution.estimate.resize(graph->num_vertices());
      size_t sub_index = 0;  // spans lie in the subproblem session by session
      for (int s = 0; s < num_sessions; ++s) {
        if (!sessions[s]) continue;
        const std::vector<int>& vertices = graph->session(s).vertices;
        const std::vector<int>& odometry = odometry_of_session[s];
        const int n = static_cast<int>(vertices.size());
        if (p.first[s] < 0) {
          // No loop: the session keeps its own frame, along its odometry.
          for (int k = 0; k < n; ++k)
            solution.estimate[vertices[k]] = (*dead_reckoning)[vertices[k]];
          continue;
        }
        for (int k = p.first[s]; k <= p.last[s]; ++k) {
          solution.estimate[vertices[k]] = optimum.sub_x[sub_index++];
        }
        for (int k = p.first[s] - 1; k >= 0; --k) {
          solution.estimate[vertices[k]] =
              solution.estimate[vertices[k + 1]] * graph->edge(odometry[k]).measurement.Inverse();
        }
        for (int k = p.last[s] + 1; k < n; ++k) {
          solution.estimate[vertices[k]] =
              solution.estimate[vertices[k - 1]] * graph->edge(odometry[k - 1]).measurement;
        }
      }
      // Gauge: each component in the frame of its earliest session's first pose.
      std::vector<char> anchored(num_sessions, 0);
      for (int s = 0; s < num_sessions; ++s) {
        if (!sessions[s] || anchored[component[s]]) continue;
        anchored[component[s]] = 1;
        const Pose origin_T_anchor =
            solution.estimate[graph->session(s).vertices.front()].Inverse();
        for (int t = s; t < num_sessions; ++t) {
          if (!sessions[t] || component[t] != component[s]) continue;
          for (int v : graph->session(t).vertices) {
            solution.estimate[v] = origin_T_anchor * solution.estimate[v];
          }
        }
      }
    }
    return solution;
  }

  std::vector<char> SessionsOf(const std::vector<int>& clusters) const {
    std::vector<char> sessions(graph->num_sessions(), 0);
    for (int c : clusters) sessions[session_a[c]] = sessions[session_b[c]] = 1;
    return sessions;
  }

  bool Within(const std::vector<char>& sessions, int c) const {
    return sessions[session_a[c]] && sessions[session_b[c]];
  }

  // Algorithm 1: optimize odometry plus cluster c alone; the graph test decides for the cluster,
  // then the per-link test removes the links that fail it. Returns whether links remain.
  bool IntraCluster(int c, std::vector<int>* changed) {
    const double link_threshold = LinkThreshold();
    bool checked_individually = false;
    std::vector<std::pair<double, int>> set_aside;  // (chi2 when set aside, link)
    while (!links[c].empty()) {
      const Solution solution = Solve(SessionsOf({c}), {c}, false);
      const OptimizerSummary& summary = solution.summary;
      const double graph_threshold = GraphThreshold(summary);
      if (summary.IsSolutionUsable() && summary.final_chi2 < graph_threshold &&
          options->prune_failing_clusters) {
        // A wrong link (or a group of them) bends the optimum and can push true links over the
        // per-link threshold: set every failing link aside, judge the rest again without them,
        // and afterwards re-admit each set-aside link that fits the consistent rest.
        std::vector<int> kept;
        for (int e : links[c]) {
          if (summary.edge_chi2[e] < link_threshold) {
            kept.push_back(e);
          } else {
            SetDecision(
                e, LoopState::kRejectedLinkTest, summary.edge_chi2[e], link_threshold, changed);
            set_aside.push_back({summary.edge_chi2[e], e});
          }
        }
        if (kept.size() < links[c].size()) {
          links[c] = kept;
          continue;
        }
      }
      if (summary.IsSolutionUsable() && summary.final_chi2 < graph_threshold) {
        std::vector<int> kept;
        for (int e : links[c]) {
          const double chi2 = summary.edge_chi2[e];
          if (chi2 < link_threshold) {
            kept.push_back(e);
            SetDecision(e, LoopState::kPending, chi2, link_threshold, changed);
          } else {
            SetDecision(e, LoopState::kRejectedLinkTest, chi2, link_threshold, changed);
          }
        }
        links[c] = kept;
        break;
      }
      if (!options->prune_failing_clusters || links[c].size() == 1 || !summary.IsSolutionUsable()) {
        for (int e : links[c]) {
          SetDecision(
              e, LoopState::kRejectedClusterTest, summary.final_chi2, graph_threshold, changed);
        }
        links[c].clear();
        break;
      }
      if (!checked_individually && individual_checks) {
        // A wrong link distorts the joint optimum, so its chi2 does not reliably single it out:
        // first test every link alone with odometry, and keep those consistent on their own.
        checked_individually = true;
        const std::vector<int> members = links[c];
        std::vector<int> kept;
        const size_t batch = 2 * static_cast<size_t>(std::max(workers, 1));
        for (size_t k = 0; k < members.size(); ++k) {
          const int e = members[k];
          if (k % batch == 0) {
            std::vector<Problem> next;
            for (size_t j = k; j < std::min(k + batch, members.size()); ++j) {
              links[c] = {members[j]};
              next.push_back(Prepare(SessionsOf({c}), {c}, false));
            }
            Prefetch(next);
          }
          links[c] = {e};
          const Solution alone = Solve(SessionsOf({c}), {c}, false);
          const double chi2 = alone.summary.edge_chi2[e];
          if (alone.summary.IsSolutionUsable() &&
              alone.summary.final_chi2 < GraphThreshold(alone.summary) && chi2 < link_threshold) {
            kept.push_back(e);
          } else {
            SetDecision(e, LoopState::kRejectedLinkTest, chi2, link_threshold, changed);
          }
        }
        links[c] = kept;
        continue;
      }
      // Still inconsistent together: among the links of largest chi2 (as many as
      // elimination_lookahead), drop the one without which the others fit best (the largest chi2
      // at the joint optimum may belong to a true link that a wrong one bent).
      const std::vector<int> members = links[c];
      std::vector<int> suspects = members;
      std::sort(suspects.begin(), suspects.end(), [&summary](int a, int b) {
        return summary.edge_chi2[a] > summary.edge_chi2[b];
      });
      suspects.resize(std::min<size_t>(
          suspects.size(), intra_lookahead > 0 ? intra_lookahead : options->elimination_lookahead));
      int worst = -1;
      double best_rest = std::numeric_limits<double>::infinity();
      std::vector<Problem> rests;
      for (int e : suspects) {
        links[c].clear();
        for (int other : members) {
          if (other != e) links[c].push_back(other);
        }
        rests.push_back(Prepare(SessionsOf({c}), {c}, false));
      }
      Prefetch(rests);
      for (int e : suspects) {
        links[c].clear();
        for (int other : members) {
          if (other != e) links[c].push_back(other);
        }
        const Solution rest = Solve(SessionsOf({c}), {c}, false);
        const double normalized = rest.summary.final_chi2 / GraphThreshold(rest.summary);
        if (rest.summary.IsSolutionUsable() && normalized < best_rest) {
          best_rest = normalized;
          worst = e;
        }
      }
      links[c] = members;
      if (worst < 0) worst = members.front();
      SetDecision(
          worst, LoopState::kRejectedLinkTest, summary.edge_chi2[worst], link_threshold, changed);
      links[c].erase(std::find(links[c].begin(), links[c].end(), worst));
      set_aside.push_back({summary.edge_chi2[worst], worst});
    }
    if (!links[c].empty() && !set_aside.empty()) Readmit(c, set_aside, changed);
    in_r[c] = links[c].empty() ? 0 : 1;
    bool survived = in_r[c] != 0;
    if (survived && options->split_failing_links) {
      // Beyond the paper: the links that left a surviving cluster may be a consistent group of
      // their own (a wrong group clustered in time with true loops, or the reverse); they become
      // a new cluster, judged by Algorithm 1 like any other.
      std::vector<int> left;
      for (const auto& [unused, e] : set_aside) {
        if (std::find(links[c].begin(), links[c].end(), e) == links[c].end()) left.push_back(e);
      }
      if (!left.empty()) {
        std::sort(left.begin(), left.end());
        const int split = AddCluster(session_a[c], session_b[c]);
        links[split] = left;
        for (int e : left) (*decisions)[e].cluster = split;
        survived = IntraCluster(split, changed) || survived;
      }
    }
    return survived;
  }

  // Tries the set-aside links of cluster c one by one (most plausible first) against its
  // consistent links; a link that passes the per-link test without making the graph test or any
  // member fail joins the cluster again.
  void Readmit(int c, std::vector<std::pair<double, int>> set_aside, std::vector<int>* changed) {
    const double link_threshold = LinkThreshold();
    std::sort(set_aside.begin(), set_aside.end());
    for (const auto& [unused, e] : set_aside) {
      links[c].push_back(e);
      const Solution trial = Solve(SessionsOf({c}), {c}, false);
      bool fits = trial.summary.IsSolutionUsable() &&
                  trial.summary.final_chi2 < GraphThreshold(trial.summary);
      for (int member : links[c]) {
        fits = fits && trial.summary.edge_chi2[member] < link_threshold;
      }
      if (fits) {
        for (int member : links[c]) {
          SetDecision(member,
                      LoopState::kPending,
                      trial.summary.edge_chi2[member],
                      link_threshold,
                      changed);
        }
      } else {
        links[c].pop_back();
      }
    }
  }

  // Consistency index of cluster c at a solution: D_C^2(c) / chi2(alpha, kDim * |c|).
  double ConsistencyIndex(int c,
                          const OptimizerSummary& summary,
                          double* chi2,
                          double* threshold) const {
    *chi2 = 0.0;
    for (int e : links[c]) *chi2 += summary.edge_chi2[e];
    *threshold = Threshold(Pose::kDim * static_cast<double>(links[c].size()));
    return *chi2 / *threshold;
  }

  struct JointTest {
    bool pass = false;
    std::vector<std::pair<double, int>> by_index;  // (consistency index, cluster) of eligibles
  };

  bool WarmStartable() const { return warm != nullptr && options->warm_start; }

  // Algorithm 2's tests at a joint optimum of the clusters `tested`: D_C^2 < chi2(alpha, d_C) and
  // D_G^2 < chi2(alpha, d_G) (and, beyond the paper, every cluster's consistency index below 1).
  JointTest Judge(const std::vector<int>& tested,
                  const OptimizerSummary& summary,
                  bool incremental) const {
    JointTest test;
    double cluster_chi2 = 0.0;
    double num_links = 0.0;
    bool each_consistent = true;
    for (int c : tested) {
      double chi2;
      double threshold;
      const double index = ConsistencyIndex(c, summary, &chi2, &threshold);
      cluster_chi2 += chi2;
      num_links += static_cast<double>(links[c].size());
      each_consistent = each_consistent && index < 1.0;
      if (incremental || !in_good[c]) test.by_index.push_back({index, c});
    }
    const double cluster_threshold = Threshold(Pose::kDim * num_links);
    test.pass = summary.IsSolutionUsable() && cluster_chi2 < cluster_threshold &&
                summary.final_chi2 < GraphThreshold(summary) &&
                (!options->require_each_cluster_consistent || each_consistent);
    return test;
  }

  // Algorithm 2 (written as a loop instead of the paper's tail recursion): optimize good and
  // candidate clusters together; accept all of them if the joint tests pass, otherwise drop the
  // cluster with the largest consistency index and try again. In the incremental version members
  // of the good set may be dropped too (III.B). Dropped clusters go to `rejected`.
  void InterCluster(const std::vector<char>& sessions,
                    std::vector<int> candidate,
                    bool incremental,
                    std::vector<int>* rejected,
                    std::vector<int>* changed) {
    std::vector<char> revived(links.size(), 0);
    while (!candidate.empty()) {
      const std::vector<int> good = GoodWithin(sessions);
      std::vector<int> tested = good;
      tested.insert(tested.end(), candidate.begin(), candidate.end());
      // Joint tests start warm (the previous step's estimate); a failure is confirmed from dead
      // reckoning, since a warm start bent by a cluster that is about to go can end in a wrong
      // local minimum (seen on the 3D helix).
      Solution solution = Solve(sessions, tested, true);
      JointTest test = Judge(tested, solution.summary, incremental);
      if (!test.pass && WarmStartable()) {
        solution = Solve(sessions, tested, false);
        test = Judge(tested, solution.summary, incremental);
      }
      const OptimizerSummary& summary = solution.summary;
      const bool pass = test.pass;
      std::vector<std::pair<double, int>>& by_index = test.by_index;
      if (pass) {
        const double link_threshold = LinkThreshold();
        for (int c : tested) {
          in_good[c] = 1;
          for (int e : links[c]) {
            SetDecision(e, LoopState::kAccepted, summary.edge_chi2[e], link_threshold, changed);
          }
        }
        return;
      }
      IRRR_CHECK(!by_index.empty());
      std::sort(by_index.begin(), by_index.end(), std::greater<>());
      int worst = by_index.front().second;
      // Beyond the paper: a wrong cluster bends the joint optimum, and a true cluster next to it
      // can show the larger index. Each of the few largest is left out in turn. If leaving out
      // some of them makes the rest pass Algorithm 2's tests, the one to go is the one with the
      // fewest links (the largest consistent set wins: a small wrong group accepted early must
      // not outvote a large true cluster); on equal sizes a candidate goes before a member of
      // the good set, then the one whose absence leaves the smallest D_G^2 (a wrong link that
      // odometry can absorb still bends it). If none does, the paper's choice stands (the
      // largest index): ranking failing rests by how close they come let two wrong single links,
      // each absorbed by odometry, outvote a true cluster of 89 (3D helix, local outliers).
      const int lookahead =
          std::min<int>(options->elimination_lookahead, static_cast<int>(by_index.size()));
      if (lookahead > 1) {
        // Ordered: links left out, good member, score (only leave-one-outs that pass).
        using Rank = std::tuple<size_t, bool, double>;
        Rank best;
        bool have_best = false;
        // The first two parts of a rank are known before any solve. Leave-one-outs are tried by
        // them (in index order among equals, the order that breaks ties as before); with
        // options->lazy_lookahead, once one passes, those whose first two parts are larger
        // cannot outrank it and are not solved.
        auto known_rank = [&](int k) {
          const int c = by_index[k].second;
          return std::make_pair(links[c].size(), in_good[c] != 0);
        };
        std::vector<int> order(lookahead);
        std::iota(order.begin(), order.end(), 0);
        if (options->lazy_lookahead) {
          std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
            return known_rank(a) < known_rank(b);
          });
        }
        auto rest_without = [&](int k) {
          std::vector<int> rest;
          for (int c : tested) {
            if (c != by_index[k].second) rest.push_back(c);
          }
          return rest;
        };
        std::vector<Problem> rests;
        const int prefetched =
            options->lazy_lookahead ? std::min(lookahead, std::max(workers, 1)) : lookahead;
        for (int i = 0; i < prefetched; ++i) {
          rests.push_back(Prepare(sessions, rest_without(order[i]), false));
        }
        Prefetch(rests);
        for (int k : order) {
          if (have_best && options->lazy_lookahead &&
              known_rank(k) > std::make_pair(std::get<0>(best), std::get<1>(best))) {
            break;
          }
          const int left_out = by_index[k].second;
          const std::vector<int> rest = rest_without(k);
          const Solution without = Solve(sessions, rest, false);
          if (!without.summary.IsSolutionUsable()) continue;
          if (!Judge(rest, without.summary, incremental).pass) continue;
          const Rank rank{links[left_out].size(),
                          in_good[left_out] != 0,
                          without.summary.final_chi2 / GraphThreshold(without.summary)};
          if (!have_best || rank < best) {
            best = rank;
            have_best = true;
            worst = left_out;
          }
        }
      }
      if (incremental && options->revive_opponents && !in_good[worst]) {
        // Beyond the paper: a good cluster accepted on thin evidence (the first link between two
        // sessions, say) makes every later true cluster there fail one at a time, and the reject
        // set keeps them apart. When a candidate falls against good clusters that are themselves
        // inconsistent, the earlier candidates that fell against the same good clusters are
        // tested again together with it, so that the evidence adds up (each at most once a call).
        bool any_revived = false;
        for (int c : good) {
          double chi2;
          double threshold;
          if (ConsistencyIndex(c, summary, &chi2, &threshold) < 1.0) continue;
          for (int loser : opponents[c]) {
            if (revived[loser] || in_good[loser] || !in_reject[loser] || links[loser].empty() ||
                std::find(candidate.begin(), candidate.end(), loser) != candidate.end()) {
              continue;
            }
            revived[loser] = 1;
            in_reject[loser] = 0;
            candidate.push_back(loser);
            any_revived = true;
          }
          opponents[c].push_back(worst);
        }
        if (any_revived) continue;
      }
      double chi2;
      double threshold;
      ConsistencyIndex(worst, summary, &chi2, &threshold);
      const LoopState state = in_good[worst] ? LoopState::kReversed : LoopState::kRejectedJointTest;
      for (int e : links[worst]) SetDecision(e, state, chi2, threshold, changed);
      in_good[worst] = 0;
      candidate.erase(std::remove(candidate.begin(), candidate.end(), worst), candidate.end());
      rejected->push_back(worst);
    }
  }

  // Algorithm 3 over the clusters of R within `sessions`. Batch: the reject set is cleared
  // whenever the good set grows. Incremental: it is never cleared.
  void Algorithm3(const std::vector<char>& sessions, bool incremental, std::vector<int>* changed) {
    const double link_threshold = LinkThreshold();
    while (true) {
      std::vector<int> current;
      for (int c = 0; c < static_cast<int>(in_r.size()); ++c) {
        if (in_r[c] && !in_good[c] && !in_reject[c] && Within(sessions, c)) current.push_back(c);
      }
      if (current.empty()) return;
      // Line 8: the current set alone (algorithm-notes: not the good set).
      const Solution solution = Solve(sessions, current, false);
      std::vector<int> candidate;
      for (int c : current) {
        bool any = false;
        for (int e : links[c]) any = any || solution.summary.edge_chi2[e] < link_threshold;
        if (any && solution.summary.IsSolutionUsable()) candidate.push_back(c);
      }
      if (candidate.empty()) {
        if (options->settle_undecided) {
          // Beyond the paper: a cluster of R that never becomes a candidate (bent at the line-8
          // optimum by the other clusters of the current set) would stay undecided, and in the
          // incremental version bend every later line-8 optimization. Each is tested alone
          // against the good set instead, so that every judged cluster ends good or rejected.
          for (int c : current) {
            std::vector<int> rejected;
            InterCluster(sessions, {c}, incremental, &rejected, changed);
            for (int r : rejected) in_reject[r] = 1;
          }
        }
        return;
      }
      int good_before = 0;
      for (int c = 0; c < static_cast<int>(in_good.size()); ++c) good_before += in_good[c];
      std::vector<int> rejected;
      InterCluster(sessions, candidate, incremental, &rejected, changed);
      if (incremental && options->retry_within_step && rejected.size() >= 2) {
        // Beyond the paper: a cluster eliminated while a wrong one was still in the test may have
        // fallen because of it; those eliminated in this call get one more joint test against the
        // good set that resulted (the batch version gets this by clearing the reject set).
        std::vector<int> retried;
        InterCluster(sessions, rejected, incremental, &retried, changed);
        rejected = retried;
      }
      int good_after = 0;
      for (int c = 0; c < static_cast<int>(in_good.size()); ++c) good_after += in_good[c];
      if (!incremental && good_after > good_before) {
        std::fill(in_reject.begin(), in_reject.end(), 0);
      } else {
        for (int c : rejected) in_reject[c] = 1;
      }
      // Batch RRR ends when a round neither grows the good set nor rejects anything new; the
      // incremental version always removes candidates from the current set.
      if (!incremental && good_after <= good_before && rejected.empty()) return;
    }
  }

  std::vector<int> GoodWithin(const std::vector<char>& sessions) const {
    std::vector<int> good;
    for (int c = 0; c < static_cast<int>(in_good.size()); ++c) {
      if (in_good[c] && Within(sessions, c)) good.push_back(c);
    }
    return good;
  }
};

}  // namespace irrr::internal

#endif  // IRRR_CORE_CONSENSUS_H_
