#ifndef IRRR_CORE_WARM_ENGINE_H_
#define IRRR_CORE_WARM_ENGINE_H_

// Internal to core (included by irrr.cc only): the default decision engine, iRRR on a warm,
// incremental good-set estimate (algorithm-notes, "Where a check starts (revised)" and "Beyond
// the paper").
//
// The estimate of every component is kept at the optimum of odometry plus the good set; new poses
// extend it along their odometry (a zero residual: still the optimum). A closed cluster is judged
// cheapest first, every threshold a chi-square quantile times the estimated variance factor:
//   1. Algorithm 1 on the cluster's local problem (Consensus::IntraCluster);
//   2. a linearized screen: each link's residual at the current optimum against
//      S = J Sigma J' + Omega^-1 (Sigma from one factorization of the good set); a link far off
//      (kScreenMargin times its threshold) leaves without any nonlinear solve;
//   3. the joint test at the warm optimum of good set + cluster: the chi2 increase (likelihood
//      ratio) against chi2(alpha, its degrees of freedom), the cluster's consistency index and
//      each link's d^2 there. A cluster that passes joins the good set, and that optimum is the
//      new estimate.
//   4. Algorithm 2's elimination with reversal: when the cluster fails and good clusters are
//      themselves inconsistent at the joint optimum (consistency index >= 1), the cluster is
//      remembered as their opponent. Once the opponents hold more links than the inconsistent
//      good clusters, good set minus those plus the opponents is tested jointly; if it passes,
//      the good clusters are reversed and the opponents accepted (the largest consistent set
//      wins, as later evidence adds up).

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "core/consensus.h"
#include "core/optimizer.h"
#include "core/test_statistics.h"

namespace irrr::internal {

template <class Pose>
class WarmEngine {
 public:
  // A link whose linearized statistic is this many times its threshold is rejected by the
  // screen; closer ones go to the joint test, where the nonlinear optimum decides.
  static constexpr double kScreenMargin = 4.0;
  // A single-link cluster needs at least this redundancy number to be judged (Unsupported).
  static constexpr double kMinRedundancy = 0.1;
  // Links screened per covariance recovery (bounds its memory: 2 x 32 poses).
  static constexpr size_t kScreenChunk = 32;

  WarmEngine(Consensus<Pose>* consensus,
             std::vector<Pose>* estimate,
             const OptimizerOptions& optimizer)
      : c_(*consensus), x_(*estimate), optimizer_(optimizer) {}

  // Judges the closed cluster k (-1: none, only what waits) against the good set of the
  // components it touches. While no variance factor is known (none fixed, and too little
  // redundancy seen yet: CurrentScale), a cluster waits (kPending): no test can tell a wrong link
  // from a true one without the noise level. The step that makes one known judges everything
  // waiting, largest first (most evidence first), then in closing order.
  void Step(int k, StepResult* result) {
    const int solves_before = c_.solves;
    const int iterations_before = c_.iterations;
    EstimateVarianceFactor();
    std::vector<int> batch;
    if (k >= 0) batch.push_back(k);
    if (!scale_known_) {
      if (k >= 0 && c_.links[k].size() >= 2) Calibrate(k);
      EstimateVarianceFactor();
      if (!scale_known_ && released_) {
        // A flush or a session's end: what waits is judged with the information as given.
        variance_ = 1.0;
        c_.variance_dof = std::numeric_limits<double>::infinity();
        scale_known_ = true;
      }
      if (!scale_known_) {
        result->variance_factor = variance_;
        result->variance_estimate = estimate_;
        result->solves += c_.solves - solves_before;
        result->iterations += c_.iterations - iterations_before;
        return;  // waits
      }
      batch = Waiting();
      std::stable_sort(batch.begin(), batch.end(), [this](int a, int b) {
        return c_.links[a].size() > c_.links[b].size();
      });
    }
    Revalidate(result);
    const int good_before = GoodLinks();
    for (int q : batch) Judge(q, result);
    // Clusters that wait for support are judged again once the good set has grown.
    if (k >= 0 && GoodLinks() != good_before) {
      for (int q : Waiting()) Judge(q, result);
    }
    std::vector<int>& changed = result->changed_loops;
    std::sort(changed.begin(), changed.end());
    changed.erase(std::unique(changed.begin(), changed.end()), changed.end());
    result->solves += c_.solves - solves_before;
    result->iterations += c_.iterations - iterations_before;
    result->variance_factor = variance_;
    result->variance_estimate = estimate_;
  }

  // Reversing: a good cluster accepted under a variance factor more than kRevalidateRatio times
  // the current one (early, on little evidence of the noise) leaves the good set and is judged
  // again at the current factor; its links that do not come back are reversed.
  void Revalidate(StepResult* result) {
    std::vector<int> suspects;
    accepted_variance_.resize(c_.links.size(), 0.0);
    for (int g = 0; g < static_cast<int>(c_.links.size()); ++g) {
      if (c_.in_good[g] && accepted_variance_[g] > kRevalidateRatio * variance_) {
        suspects.push_back(g);
      }
    }
    if (suspects.empty()) return;
    // All leave the good set together; each gets back every link it held when it closed.
    std::vector<int> accepted_before;
    for (int g : suspects) {
      c_.in_good[g] = 0;
      c_.in_r[g] = 0;
      c_.links[g].clear();
    }
    for (int e = 0; e < graph().num_edges(); ++e) {
      const LoopDecision& d = (*c_.decisions)[e];
      if (d.cluster < 0 ||
          std::find(suspects.begin(), suspects.end(), d.cluster) == suspects.end()) {
        continue;
      }
      c_.links[d.cluster].push_back(e);
      if (d.state == LoopState::kAccepted) accepted_before.push_back(e);
    }
    const std::vector<char> all(graph().num_sessions(), 1);
    std::vector<Pose> x = x_;
    optimizer_.Solve(graph(), Active(all, c_.GoodWithin(all)), &x);
    ++c_.solves;
    x_ = x;
    Reanchor();
    std::stable_sort(suspects.begin(), suspects.end(), [this](int a, int b) {
      return c_.links[a].size() > c_.links[b].size();
    });
    for (int g : suspects) Judge(g, result);
    for (int e : accepted_before) {
      const LoopDecision& d = (*c_.decisions)[e];
      if (d.state != LoopState::kAccepted) {
        c_.SetDecision(e, LoopState::kReversed, d.chi2, d.threshold, &result->changed_loops);
      }
    }
    result->reversals += static_cast<int>(suspects.size());
  }

  int GoodLinks() const {
    int n = 0;
    for (int q = 0; q < static_cast<int>(c_.links.size()); ++q) {
      if (c_.in_good[q]) n += static_cast<int>(c_.links[q].size());
    }
    return n;
  }

  // The clusters judged by no test yet (waiting for a variance factor or for support), in
  // closing order.
  std::vector<int> Waiting() const {
    std::vector<int> waiting;
    for (int q = 0; q < static_cast<int>(std::min(c_.links.size(), closed_.size())); ++q) {
      if (closed_[q] && !c_.in_r[q] && !c_.in_reject[q] && !c_.links[q].empty()) {
        waiting.push_back(q);
      }
    }
    return waiting;
  }

  // A flush or a session's end: clusters that wait for a variance factor are judged with the
  // information as given if none is known by their step.
  void Release() { released_ = true; }
  // Whether released clusters wait for a step of their own (no variance factor known yet).
  bool HasReleased() const {
    if (!released_ || CurrentScale().known) return false;
    for (int q : Waiting()) {
      if (!IsHeld(q)) return true;
    }
    return false;
  }

  // Cluster q has closed (called before its step; clusters split off by Algorithm 1 are judged
  // in the step that made them).
  void Closed(int q) {
    if (static_cast<int>(closed_.size()) <= q) closed_.resize(q + 1, 0);
    closed_[q] = 1;
  }

  double variance_factor() const { return variance_; }

  // What the step state holds of the engine, per cluster (IrrrStepState).
  double AcceptedVariance(int q) const {
    return q < static_cast<int>(accepted_variance_.size()) ? accepted_variance_[q] : 0.0;
  }
  bool IsClosed(int q) const { return q < static_cast<int>(closed_.size()) && closed_[q]; }
  void Restore(int q, double accepted_variance, bool closed) {
    accepted_variance_.resize(std::max<size_t>(accepted_variance_.size(), q + 1), 0.0);
    closed_.resize(std::max<size_t>(closed_.size(), q + 1), 0);
    accepted_variance_[q] = accepted_variance;
    closed_[q] = closed ? 1 : 0;
  }
  void Clear() {
    accepted_variance_.clear();
    closed_.clear();
    held_.clear();
  }

 private:
  static constexpr int kDim = Pose::kDim;
  const PoseGraph<Pose>& graph() const { return *c_.graph; }
  double Threshold(double dof) const { return c_.Threshold(dof); }

  // Odometry of `sessions` and the loops of `clusters`, as the optimizer's active flags.
  std::vector<char> Active(const std::vector<char>& sessions,
                           const std::vector<int>& clusters) const {
    std::vector<char> active(graph().num_edges(), 0);
    for (int s = 0; s < graph().num_sessions(); ++s) {
      if (!sessions[s]) continue;
      for (int e : c_.odometry_of_session[s]) active[e] = 1;
    }
    for (int q : clusters) {
      for (int e : c_.links[q]) active[e] = 1;
    }
    return active;
  }

  // Residual rows minus free parameters of an active set over `sessions`: kDim x (loops -
  // sessions + components), each session's odometry chain being exactly determined.
  double Redundancy(const std::vector<char>& sessions, const std::vector<char>& active) const {
    int loops = 0;
    for (int e = 0; e < graph().num_edges(); ++e) {
      loops += active[e] && graph().edge(e).kind == EdgeKind::kLoop ? 1 : 0;
    }
    const std::vector<int> component = SessionComponents(graph(), active);
    std::vector<char> seen(graph().num_sessions(), 0);
    int num_sessions = 0;
    int components = 0;
    for (int s = 0; s < graph().num_sessions(); ++s) {
      if (!sessions[s] || graph().session(s).vertices.empty()) continue;
      ++num_sessions;
      if (!seen[component[s]]) {
        seen[component[s]] = 1;
        ++components;
      }
    }
    return kDim * static_cast<double>(loops - num_sessions + components);
  }

  double Chi2(const std::vector<char>& active, const std::vector<Pose>& x) const {
    double chi2 = 0.0;
    for (int e = 0; e < graph().num_edges(); ++e) {
      if (active[e]) chi2 += EdgeChi2(graph().edge(e), x);
    }
    return chi2;
  }

  // Before any variance factor is known, the redundancy of cluster q on its own scale: Algorithm
  // 1's optimum, its links failing the per-link test at the scale they imply set aside and the
  // rest solved again, until none fails (a trimmed estimate: one wrong link among many true ones
  // dominates the cluster's chi2 and stands out against it). The cluster itself is unchanged.
  void Calibrate(int q) {
    const std::vector<int> links = c_.links[q];
    for (int round = 0; round < kCalibrationRounds && c_.links[q].size() >= 2; ++round) {
      const OptimizerSummary summary = c_.Solve(c_.SessionsOf({q}), {q}, false).summary;
      const double dof = summary.residual_dimension - summary.free_parameters;
      if (!summary.IsSolutionUsable() || dof <= 0.0) break;
      c_.redundancy[q] = {summary.final_chi2, dof};
      const double threshold =
          summary.final_chi2 / dof * ChiSquareQuantile(c_.options->alpha, kDim);
      std::vector<int> kept;
      for (int e : c_.links[q]) {
        if (summary.edge_chi2[e] <= threshold) kept.push_back(e);
      }
      if (kept.size() == c_.links[q].size()) break;
      c_.links[q] = kept;
    }
    c_.links[q] = links;
  }

  void RecordRedundancy(int q) {
    const auto solution = c_.Solve(c_.SessionsOf({q}), {q}, false);
    const OptimizerSummary& summary = solution.summary;
    c_.redundancy[q] = {summary.final_chi2,
                        static_cast<double>(summary.residual_dimension - summary.free_parameters)};
  }

  // The variance factor and its degrees of freedom: a fixed one from the options (known
  // exactly), else the median over Algorithm 1's clusters of two or more links (robust to a
  // minority of wrong ones), else 1 with none. A cluster whose links agree with odometry to
  // rounding (a synthesized or duplicated constraint) says nothing of the noise and is left out.
  // Its degrees of freedom are those of the samples, at most kMaxVarianceDof: the factor varies
  // along a trajectory more than a larger count would admit.
  void EstimateVarianceFactor() {
    const Scale scale = CurrentScale();
    scale_known_ = scale.known;
    variance_ = scale.variance;
    estimate_ = scale.estimate;
    c_.variance_dof = scale.dof;
  }

  struct Scale {
    bool known = false;
    double variance = 1.0;  // the factor the tests use
    double estimate = 1.0;  // the factor the data gave (before the cap at 1)
    double dof = std::numeric_limits<double>::infinity();
  };

  Scale CurrentScale() const {
    Scale scale;
    std::vector<RedundancySample> samples;
    double dof = 0.0;
    double largest = 0.0;
    for (size_t q = 0; q < c_.redundancy.size(); ++q) {
      const RedundancySample& sample = c_.redundancy[q];
      if (!c_.in_reject[q] && c_.links[q].size() >= 2 && sample.dof > 0.0 &&
          sample.chi2 > kNoiseless * sample.dof) {
        samples.push_back(sample);
        dof += sample.dof;
        largest = std::max(largest, sample.dof);
      }
    }
    const double robust = RobustVarianceFactor(samples);
    const bool enough =
        std::isfinite(robust) && (largest >= kScaleMinimumDof || dof >= 3 * kScaleMinimumDof);
    if (enough) scale.estimate = robust;
    if (c_.options->variance_factor > 0.0) {
      scale.known = true;
      scale.variance = c_.options->variance_factor;
      return scale;
    }
    if (!enough) return scale;
    scale.known = true;
    // Never above 1: a factor above 1 says the information is over-confident, and the data cannot
    // tell that from wrong links clustered with true ones (on KITTI's place-recognition graphs the
    // estimate came out above 1 and let hundreds of wrong loops in; at 1 none). Over-confident
    // information is fixed with irrr.variance_factor.
    scale.variance = std::min(robust, 1.0);
    scale.dof = std::min(dof, kMaxVarianceDof);
    return scale;
  }

  // The screen: links far off at the current optimum leave cluster q. Only for a cluster inside
  // one component (across two, the relative frame is not known yet).
  void Screen(int q, const std::vector<char>& active_good, std::vector<int>* changed) {
    if (!factorized_ && !optimizer_.FactorizeAt(graph(), active_good, x_)) return;
    factorized_ = true;
    // Each link against the covariance of its end poses, kScreenChunk links at a time: the dense
    // covariance of every vertex of a large cluster at once would take gigabytes.
    const std::vector<int>& links = c_.links[q];
    std::vector<LinearizedAddition> additions(links.size());
    for (size_t first = 0; first < links.size(); first += kScreenChunk) {
      const size_t last = std::min(links.size(), first + kScreenChunk);
      std::vector<int> vertices;
      for (size_t i = first; i < last; ++i) {
        vertices.push_back(graph().edge(links[i]).from);
        vertices.push_back(graph().edge(links[i]).to);
      }
      std::sort(vertices.begin(), vertices.end());
      vertices.erase(std::unique(vertices.begin(), vertices.end()), vertices.end());
      Eigen::MatrixXd covariance;
      if (!optimizer_.Covariance(vertices, &covariance)) return;  // the joint test decides
      const auto index_of = [&vertices](int v) {
        return kDim * static_cast<int>(std::lower_bound(vertices.begin(), vertices.end(), v) -
                                       vertices.begin());
      };
      for (size_t i = first; i < last; ++i) {
        const Edge<Pose>& edge = graph().edge(links[i]);
        const int a = index_of(edge.from);
        const int b = index_of(edge.to);
        Eigen::MatrixXd pair(2 * kDim, 2 * kDim);
        pair << covariance.block<kDim, kDim>(a, a), covariance.block<kDim, kDim>(a, b),
            covariance.block<kDim, kDim>(b, a), covariance.block<kDim, kDim>(b, b);
        additions[i] = LinearizeAddition<Pose>({&edge}, x_, {edge.from, edge.to}, pair);
      }
    }
    const double far = kScreenMargin * Threshold(kDim);
    control_.resize(graph().num_edges(), 0.0);
    std::vector<int> kept;
    std::vector<std::pair<int, double>> far_off;
    for (size_t i = 0; i < links.size(); ++i) {
      const int e = links[i];
      const double statistic = additions[i].chi2_increase;
      control_[e] = std::isfinite(additions[i].redundancy) ? additions[i].redundancy : 0.0;
      if (statistic <= far) {
        kept.push_back(e);
      } else {
        far_off.push_back({e, statistic});
      }
    }
    // A cluster of several links all far off goes on to the joint test whole: it is either a
    // wrong group, which the joint test rejects as well, or true links against a wrong good
    // cluster, whose conflict only the joint test records (Challenge).
    if (kept.empty() && far_off.size() >= 2) return;
    for (const auto& [e, statistic] : far_off) {
      c_.SetDecision(e, LoopState::kRejectedJointTest, statistic, far, changed);
    }
    c_.links[q] = kept;
  }

  struct Joint {
    OptimizerSummary summary;
    std::vector<Pose> x;
    double increase = 0.0;  // chi2 increase over the good set's optimum
    double dof = 0.0;       // its degrees of freedom
  };

  // Optimizes `active` warm from x_ (frame groups joined by `joining` aligned first) and compares
  // with the optimum of `base_active`, whose chi2 at `base_x` is given.
  Joint SolveJoint(const std::vector<char>& sessions,
                   const std::vector<char>& active,
                   const std::vector<int>& joining,
                   const std::vector<char>& base_active,
                   double base_chi2,
                   const std::vector<Pose>& start) {
    Joint joint;
    joint.x = start;
    c_.AlignGroups(joining, SessionComponents(graph(), base_active), &joint.x);
    joint.summary = optimizer_.Solve(graph(), active, &joint.x);
    factorized_ = false;
    ++c_.solves;
    c_.iterations += joint.summary.iterations;
    joint.increase = joint.summary.final_chi2 - base_chi2;
    joint.dof = Redundancy(sessions, active) - Redundancy(sessions, base_active);
    return joint;
  }

  // Whether clusters pass at a joint optimum: each link, and each cluster's consistency index.
  bool Consistent(const std::vector<int>& clusters, const OptimizerSummary& summary) const {
    for (int q : clusters) {
      double chi2;
      double threshold;
      if (c_.ConsistencyIndex(q, summary, &chi2, &threshold) >= 1.0) return false;
      for (int e : c_.links[q]) {
        if (!(summary.edge_chi2[e] < c_.LinkThreshold())) return false;
      }
    }
    return true;
  }

  bool IncreasePasses(const Joint& joint) const {
    return joint.summary.IsSolutionUsable() &&
           (joint.dof <= 0.0 || joint.increase < Threshold(joint.dof));
  }

  void Accept(const std::vector<int>& clusters, const Joint& joint, std::vector<int>* changed) {
    for (int q : clusters) {
      c_.in_good[q] = 1;
      c_.in_reject[q] = 0;
      if (accepted_variance_.size() < c_.links.size()) accepted_variance_.resize(c_.links.size());
      accepted_variance_[q] = variance_;
      for (int e : c_.links[q]) {
        c_.SetDecision(
            e, LoopState::kAccepted, joint.summary.edge_chi2[e], c_.LinkThreshold(), changed);
      }
    }
    x_ = joint.x;
  }

  // The whole pipeline for one cluster: screen, Algorithm 1, joint test (with its splits).
  void Judge(int k, StepResult* result) {
    c_.variance = variance_;
    c_.exact_graph_dof = true;
    c_.individual_checks = false;
    c_.intra_lookahead = 1;
    factorized_ = false;
    std::vector<int>* changed = &result->changed_loops;
    const std::vector<char> sessions = SessionsTouching(k);
    for (int s = 0; s < graph().num_sessions(); ++s) {
      if (sessions[s] && std::find(result->sessions.begin(), result->sessions.end(), s) ==
                             result->sessions.end()) {
        result->sessions.push_back(s);
      }
    }
    // The screen first: each link alone against the good set (one factorization, a few solves),
    // so that Algorithm 1 weighs only links that are not far off.
    {
      const std::vector<char> active_good = Active(sessions, c_.GoodWithin(sessions));
      const std::vector<int> component = SessionComponents(graph(), active_good);
      if (component[c_.session_a[k]] == component[c_.session_b[k]]) {
        Screen(k, active_good, changed);
      }
    }
    const int first_split = static_cast<int>(c_.links.size());
    if (c_.links[k].empty() || !c_.IntraCluster(k, changed)) {
      c_.in_reject[k] = 1;
      return;
    }
    std::vector<int> candidates = {k};
    for (int q = first_split; q < static_cast<int>(c_.links.size()); ++q) {
      closed_.resize(c_.links.size(), 0);
      closed_[q] = 1;
      candidates.push_back(q);
    }
    for (int q : candidates) {
      if (!c_.in_r[q] || c_.links[q].empty()) continue;
      if (Unsupported(q)) {
        // Waits, as judged by nothing yet, for a good set that can check it.
        c_.in_r[q] = 0;
        held_.resize(c_.links.size(), 0);
        held_[q] = 1;
        const int e = c_.links[q].front();
        c_.SetDecision(e, LoopState::kPending, 0.0, 0.0, changed);
        continue;
      }
      RecordRedundancy(q);
      JointTest(q, sessions, changed, result);
    }
  }

  // A cluster of one link (none of its own to support it) whose end poses the good set knows far
  // worse than the link measures them (redundancy number below kMinRedundancy, or in two
  // components): the link would bend the estimate to fit whatever it says, so no test can tell
  // it wrong.
  bool IsHeld(int q) const { return q < static_cast<int>(held_.size()) && held_[q]; }

  bool Unsupported(int q) const {
    if (c_.links[q].size() != 1) return false;
    const int e = c_.links[q].front();
    return e >= static_cast<int>(control_.size()) || control_[e] < kMinRedundancy;
  }

  // The component of every session under the good set.
  std::vector<int> GoodComponents() const {
    const std::vector<char> all(graph().num_sessions(), 1);
    return SessionComponents(graph(), Active(all, c_.GoodWithin(all)));
  }

  // The sessions of the components (under the good set) that cluster q touches.
  std::vector<char> SessionsTouching(int q) const {
    const std::vector<int> component = GoodComponents();
    std::vector<char> sessions(graph().num_sessions(), 0);
    for (int s = 0; s < graph().num_sessions(); ++s) {
      sessions[s] =
          component[s] == component[c_.session_a[q]] || component[s] == component[c_.session_b[q]];
    }
    return sessions;
  }

  void JointTest(int q,
                 const std::vector<char>& sessions,
                 std::vector<int>* changed,
                 StepResult* result) {
    const std::vector<int> good = c_.GoodWithin(sessions);
    const std::vector<char> active_good = Active(sessions, good);
    const double good_chi2 = Chi2(active_good, x_);
    // A cluster with redundancy enough of its own is judged at the larger of the global factor
    // and its own (the noise varies along a trajectory; Algorithm 1's graph test has already
    // bounded its own factor by the global one's threshold).
    const RedundancySample& own = c_.redundancy[q];
    const double global_variance = c_.variance;
    if (own.dof >= kScaleMinimumDof) c_.variance = std::max(global_variance, own.chi2 / own.dof);
    JointTestAtScale(q, sessions, good, active_good, good_chi2, changed, result);
    c_.variance = global_variance;
  }

  void JointTestAtScale(int q,
                        const std::vector<char>& sessions,
                        const std::vector<int>& good,
                        const std::vector<char>& active_good,
                        double good_chi2,
                        std::vector<int>* changed,
                        StepResult* result) {
    while (true) {
      std::vector<int> tested = good;
      tested.push_back(q);
      const Joint joint =
          SolveJoint(sessions, Active(sessions, tested), c_.links[q], active_good, good_chi2, x_);
      const OptimizerSummary& summary = joint.summary;
      const bool increase_passes = IncreasePasses(joint);
      double cluster_chi2;
      double cluster_threshold;
      const double index = c_.ConsistencyIndex(q, summary, &cluster_chi2, &cluster_threshold);
      if (increase_passes && index < 1.0) {
        // Links failing on their own leave; the rest is judged again without them.
        std::vector<int> kept;
        for (int e : c_.links[q]) {
          if (summary.edge_chi2[e] < c_.LinkThreshold()) {
            kept.push_back(e);
          } else {
            c_.SetDecision(
                e, LoopState::kRejectedLinkTest, summary.edge_chi2[e], c_.LinkThreshold(), changed);
          }
        }
        if (kept.size() == c_.links[q].size()) {
          Accept({q}, joint, changed);
          Reanchor();
          return;
        }
        c_.links[q] = kept;
        if (kept.empty()) break;
        continue;
      }
      // Inconsistent: with the good clusters that are inconsistent too, if any.
      std::vector<int> suspects;
      for (int g : good) {
        double chi2;
        double threshold;
        if (c_.ConsistencyIndex(g, summary, &chi2, &threshold) >= 1.0) suspects.push_back(g);
      }
      const double threshold = joint.dof > 0.0 ? Threshold(joint.dof) : 0.0;
      for (int e : c_.links[q]) {
        c_.SetDecision(e, LoopState::kRejectedJointTest, joint.increase, threshold, changed);
      }
      c_.in_reject[q] = 1;
      for (int g : suspects) c_.opponents[g].push_back(q);
      if (!suspects.empty()) Challenge(suspects, sessions, changed, result);
      return;
    }
    c_.in_reject[q] = 1;
  }

  // Reversal (Algorithm 2 with later evidence): when a cluster falls against good clusters that
  // are inconsistent too (the suspects), the clusters that fell against them so far (their
  // opponents, at most kMaxChallengers, largest first) challenge them: from the good set without
  // the suspects, each challenger and then each suspect is added if it passes the joint test. If
  // the good set so built holds more links than the current one, it replaces it: suspects left
  // out are reversed, challengers taken in are accepted (the largest consistent set wins, as
  // later evidence adds up). Otherwise nothing changes.
  void Challenge(const std::vector<int>& suspects,
                 const std::vector<char>& sessions,
                 std::vector<int>* changed,
                 StepResult* result) {
    std::vector<int> challengers;
    size_t challenger_links = 0;
    size_t smallest_suspect = std::numeric_limits<size_t>::max();
    for (int g : suspects) {
      smallest_suspect = std::min(smallest_suspect, c_.links[g].size());
      for (int r : c_.opponents[g]) {
        if (!c_.in_reject[r] || c_.in_good[r] || c_.links[r].empty() || !c_.Within(sessions, r) ||
            std::find(challengers.begin(), challengers.end(), r) != challengers.end()) {
          continue;
        }
        challengers.push_back(r);
      }
    }
    std::stable_sort(challengers.begin(), challengers.end(), [this](int a, int b) {
      return c_.links[a].size() > c_.links[b].size();
    });
    if (challengers.size() > kMaxChallengers) challengers.resize(kMaxChallengers);
    for (int r : challengers) challenger_links += c_.links[r].size();
    if (challenger_links <= smallest_suspect) return;

    const std::vector<int> good = c_.GoodWithin(sessions);
    std::vector<int> base;
    size_t good_links = 0;
    for (int g : good) {
      good_links += c_.links[g].size();
      if (std::find(suspects.begin(), suspects.end(), g) == suspects.end()) base.push_back(g);
    }
    const std::vector<char> active_good = Active(sessions, good);
    Joint current =
        SolveJoint(sessions, Active(sessions, base), {}, active_good, Chi2(active_good, x_), x_);
    if (!current.summary.IsSolutionUsable()) return;
    std::vector<int> ordered = challengers;
    std::vector<int> sorted_suspects = suspects;
    std::stable_sort(sorted_suspects.begin(), sorted_suspects.end(), [this](int a, int b) {
      return c_.links[a].size() > c_.links[b].size();
    });
    ordered.insert(ordered.end(), sorted_suspects.begin(), sorted_suspects.end());
    size_t base_links = 0;
    for (int g : base) base_links += c_.links[g].size();
    for (int q : ordered) {
      std::vector<int> tested = base;
      tested.push_back(q);
      const std::vector<char> active_base = Active(sessions, base);
      Joint joint = SolveJoint(sessions,
                               Active(sessions, tested),
                               c_.links[q],
                               active_base,
                               current.summary.final_chi2,
                               current.x);
      if (!IncreasePasses(joint) || !Consistent({q}, joint.summary)) continue;
      base = tested;
      base_links += c_.links[q].size();
      current = std::move(joint);
    }
    if (base_links <= good_links) return;
    std::vector<int> taken;
    for (int g : suspects) {
      if (std::find(base.begin(), base.end(), g) != base.end()) continue;
      double chi2;
      double threshold;
      c_.ConsistencyIndex(g, current.summary, &chi2, &threshold);
      for (int e : c_.links[g]) c_.SetDecision(e, LoopState::kReversed, chi2, threshold, changed);
      c_.in_good[g] = 0;
      c_.in_reject[g] = 1;
    }
    for (int q : base) {
      if (!c_.in_good[q]) taken.push_back(q);
    }
    Accept(base, current, changed);
    Reanchor();
    ++result->reversals;
  }

  // Gauge: each component in the frame of its earliest session's first pose (a reversal can
  // split a component; the later part then moves to its own frame).
  void Reanchor() {
    const std::vector<int> component = GoodComponents();
    std::vector<char> anchored(graph().num_sessions(), 0);
    for (int s = 0; s < graph().num_sessions(); ++s) {
      if (anchored[component[s]] || graph().session(s).vertices.empty()) continue;
      anchored[component[s]] = 1;
      const Pose origin_T_anchor = x_[graph().session(s).vertices.front()].Inverse();
      for (int t = s; t < graph().num_sessions(); ++t) {
        if (component[t] != component[s]) continue;
        for (int v : graph().session(t).vertices) x_[v] = origin_T_anchor * x_[v];
      }
    }
  }

  static constexpr double kNoiseless = 1e-12;
  static constexpr double kMaxVarianceDof = 50.0;
  // A variance factor is known once one cluster has this much redundancy, or all together three
  // times as much (before, wrong links clustered by chance could set it).
  static constexpr double kScaleMinimumDof = 30.0;
  static constexpr int kCalibrationRounds = 6;
  static constexpr double kRevalidateRatio = 2.0;
  static constexpr size_t kMaxChallengers = 8;

  Consensus<Pose>& c_;
  std::vector<Pose>& x_;
  Optimizer<Pose> optimizer_;
  double variance_ = 1.0;
  double estimate_ = 1.0;
  bool scale_known_ = false;
  bool released_ = false;
  std::vector<double> accepted_variance_;  // per cluster: the variance factor it was accepted at
  std::vector<char> closed_;               // per cluster: closed (judged, or waiting)
  // Whether optimizer_ holds the factorization of this step's good set at x_ (the screen's).
  bool factorized_ = false;
  std::vector<double> control_;  // per loop edge: its redundancy number at its last screen
  std::vector<char> held_;       // per cluster: waits for support (Unsupported)
};

}  // namespace irrr::internal

#endif  // IRRR_CORE_WARM_ENGINE_H_
