#include "core/warm_engine.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>

#include "core/good_set.h"
#include "core/intra_cluster.h"
#include "core/local_problem.h"
#include "core/test_statistics.h"

namespace irrr {
namespace {

// A link whose linearized statistic is this many times its threshold, and kClusterMargin times its
// cluster's median statistic, is rejected by the screen (random hypotheses score hundreds to
// millions of times it; true clusters closing long cycles up to 5 on Manhattan, and a place
// recognizer's agreeing links stand off together: KITTI 05, 17 links at 4.3 times).
// A challenger with a link whose statistic alone is kClusterMargin times the cluster's threshold
// is not tried (MayPass; nonlinear over linearized increase: 0.5-3.5 on Manhattan and Intel).
constexpr double kScreenMargin = 4.0;
constexpr double kClusterMargin = 20.0;
// The smallest pairwise factor Calibrate uses (a noiseless cluster's pairs score 0).
constexpr double kNoiselessFactor = 1e-6;
// A cluster of one link needs at least this redundancy number to be judged (Unsupported).
constexpr double kMinRedundancy = 0.1;
// The variance factor's degrees of freedom are those of its samples, at most this many: the
// factor varies along a trajectory more than a larger count would admit.
constexpr double kMaxVarianceDof = 50.0;
// A variance factor is known once one cluster has this much redundancy, or all together three
// times as much (before, wrong links clustered by chance could set it).
constexpr double kScaleMinimumDof = 30.0;
// A cluster with this much redundancy of its own is judged at the larger of the global factor and
// its own.
constexpr double kOwnFactorMinimumDof = 18.0;
// ... and at most this many times the global factor (the measurements: docs/decisions.md).
constexpr double kOwnFactorRatio = 2.0;
// Trimming rounds of a cluster's variance sample before any factor is known (Calibrate).
constexpr int kCalibrationRounds = 6;
// A good cluster accepted under a factor more than this many times today's is judged again.
constexpr double kRevalidateRatio = 2.0;
// Clusters that challenge good ones at once (Challenge), largest first.
constexpr size_t kMaxChallengers = 8;
// Links of a cluster whose ends lie within this many poses of another's ends form one run (a
// place recognizer's matches along a revisit, or a group of wrong ones): a cluster that fails the
// joint test whole is judged again run by run (JudgeRuns).
constexpr int kRunGap = 5;

}  // namespace

template <class Pose>
struct WarmEngine<Pose>::Impl {
  static constexpr int d = Pose::kDim;

  Impl(const PoseGraph<Pose>* g,
       const IrrrOptions* o,
       DecisionBook* b,
       std::vector<Pose>* e,
       const std::vector<Pose>* dead_reckoning)
      : graph(g),
        options(o),
        book(b),
        estimate(e),
        problems(g, dead_reckoning, o->optimizer),
        pairwise(g, dead_reckoning),
        good(g, e, IncrementalSolverOptions()) {}

  // ---- thresholds and the variance factor -------------------------------------------------

  TestThresholds Thresholds() const {
    return TestThresholds{
        options->alpha, test_variance > 0.0 ? test_variance : variance, variance_dof};
  }
  double Threshold(double dof) const { return Thresholds().Of(dof); }
  double LinkThreshold() const { return Threshold(d); }
  double AlignmentCap() const { return kAlignmentCap * LinkThreshold(); }

  struct Scale {
    bool known = false;
    double variance = 1.0;  // the factor the tests use
    double estimate = 1.0;  // the factor the data gave (before the cap at 1)
    double dof = std::numeric_limits<double>::infinity();
  };

  // A fixed factor from the options (known exactly); else the dof-weighted median over Algorithm
  // 1's clusters of two or more links that are not rejected (robust to a minority of wrong ones),
  // known once enough redundancy is seen; never above 1.
  Scale CurrentScale() const {
    Scale scale;
    std::vector<RedundancySample> samples;
    double total = 0.0;
    double largest = 0.0;
    for (const JudgedCluster& c : book->clusters) {
      if (!c.in_reject && c.links.size() >= 2 && c.redundancy_dof > 0.0) {
        samples.push_back({c.redundancy_chi2, c.redundancy_dof});
        total += c.redundancy_dof;
        largest = std::max(largest, c.redundancy_dof);
      }
    }
    const double robust = RobustVarianceFactor(samples);
    const bool enough =
        std::isfinite(robust) && (largest >= kScaleMinimumDof || total >= 3 * kScaleMinimumDof);
    if (enough) scale.estimate = robust;
    if (options->variance_factor > 0.0) {
      scale.known = true;
      scale.variance = options->variance_factor;
      return scale;
    }
    if (!enough) return scale;
    scale.known = true;
    // Never above 1: the data cannot tell over-confident information from wrong links clustered
    // with true ones (on KITTI an estimate above 1 let hundreds of wrong loops in; at 1 none).
    scale.variance = std::min(robust, 1.0);
    scale.dof = std::min(total, kMaxVarianceDof);
    return scale;
  }

  void EstimateVarianceFactor() {
    const Scale scale = CurrentScale();
    scale_known = scale.known;
    variance = scale.variance;
    variance_estimate = scale.estimate;
    variance_dof = scale.dof;
  }

  // Before any factor is known, the redundancy of cluster q on its own scale: Algorithm 1's
  // optimum, its links failing the link test at the scale they imply set aside and the rest solved
  // again, until none fails (a trimmed estimate: one wrong link among many true ones dominates the
  // cluster's chi2 and stands out against it). The cluster itself is unchanged.
  void Calibrate(int q) {
    // The largest set of pairwise consistent links at the scale their pairs imply (at most 1, the
    // information as given): wrong links clustered with true loops, or with each other, are not
    // noise. On conservative information (Manhattan's odometry) random links a few poses long
    // agree with the rest at the nominal scale.
    const double pair_factor =
        std::clamp(pairwise.PairwiseFactor(book->clusters[q].links), kNoiselessFactor, 1.0);
    std::vector<int> links = pairwise.ConsistentSubsets(
        book->clusters[q].links,
        PairwiseThreshold<Pose>(TestThresholds{options->alpha, pair_factor}))[0];
    // With a factor known, the consistent set is the sample (Algorithm 1 judges its links).
    const int rounds = scale_known ? 1 : kCalibrationRounds;
    for (int round = 0; round < rounds && links.size() >= 2; ++round) {
      const LocalSolution solution =
          problems.Solve(problems.SessionsOf(links), links, AlignmentCap());
      const RedundancySample sample = ClusterRedundancy(pairwise, links, solution);
      if (!(sample.dof > 0.0)) break;
      book->clusters[q].redundancy_chi2 = sample.chi2;
      book->clusters[q].redundancy_dof = sample.dof;
      const double threshold = sample.chi2 / sample.dof * ChiSquareQuantile(options->alpha, d);
      std::vector<int> kept;
      for (int e : links) {
        if (solution.summary.edge_chi2[e] <= threshold) kept.push_back(e);
      }
      if (kept.size() == links.size()) break;
      links = kept;
    }
  }

  // ---- the good set --------------------------------------------------------------------------

  std::vector<int> GoodLoops() const {
    std::vector<int> loops;
    for (const JudgedCluster& c : book->clusters) {
      if (c.in_good) loops.insert(loops.end(), c.links.begin(), c.links.end());
    }
    return loops;
  }

  int GoodLinks() const {
    int n = 0;
    for (const JudgedCluster& c : book->clusters)
      n += c.in_good ? static_cast<int>(c.links.size()) : 0;
    return n;
  }

  // Whether cluster q lies within the components `components`.
  bool Within(const std::vector<int>& components, int q) const {
    const JudgedCluster& c = book->clusters[q];
    auto in = [&](int session) {
      return std::find(components.begin(), components.end(), good.ComponentOf(session)) !=
             components.end();
    };
    return in(c.session_a) && in(c.session_b);
  }

  // The clusters judged by no test yet (waiting for a variance factor or for support), in
  // closing order.
  std::vector<int> Waiting() const {
    std::vector<int> waiting;
    for (int q = 0; q < static_cast<int>(book->clusters.size()); ++q) {
      const JudgedCluster& c = book->clusters[q];
      if (c.closed && !c.in_r && !c.in_reject && !c.links.empty()) waiting.push_back(q);
    }
    return waiting;
  }

  void SortLargestFirst(std::vector<int>* clusters) const {
    std::stable_sort(clusters->begin(), clusters->end(), [this](int a, int b) {
      return book->clusters[a].links.size() > book->clusters[b].links.size();
    });
  }

  // ---- one step ------------------------------------------------------------------------------

  void Step(int k, StepResult* result) {
    const int solves_before = Solves();
    const int iterations_before = Iterations();
    EstimateVarianceFactor();
    std::vector<int> batch;
    if (k >= 0) batch.push_back(k);
    if (!scale_known) {
      if (k >= 0 && book->clusters[k].links.size() >= 2) Calibrate(k);
      EstimateVarianceFactor();
      if (!scale_known && released) {
        // A flush or a session's end: what waits is judged with the information as given.
        variance = 1.0;
        variance_dof = std::numeric_limits<double>::infinity();
        scale_known = true;
      }
      if (scale_known) {
        batch = Waiting();
        SortLargestFirst(&batch);
      } else {
        batch.clear();  // waits
      }
    }
    if (scale_known) {
      Revalidate(result);
      const int good_before = GoodLinks();
      for (int q : batch) Judge(q, result);
      // Clusters that wait for support are judged again once the good set has grown.
      if (k >= 0 && GoodLinks() != good_before) {
        for (int q : Waiting()) Judge(q, result);
      }
    }
    std::vector<int>& changed = result->changed_loops;
    std::sort(changed.begin(), changed.end());
    changed.erase(std::unique(changed.begin(), changed.end()), changed.end());
    std::sort(result->sessions.begin(), result->sessions.end());
    result->sessions.erase(std::unique(result->sessions.begin(), result->sessions.end()),
                           result->sessions.end());
    result->chi2 = 0.0;
    std::vector<int> components;
    for (int s : result->sessions) components.push_back(good.ComponentOf(s));
    std::sort(components.begin(), components.end());
    components.erase(std::unique(components.begin(), components.end()), components.end());
    for (int c : components) {
      if (c >= 0) result->chi2 += good.Solver(c).chi2();
    }
    result->solves += Solves() - solves_before;
    result->iterations += Iterations() - iterations_before;
    result->variance_factor = variance;
    result->variance_estimate = variance_estimate;
  }

  int Solves() const {
    return problems.solves() + static_cast<int>(good.counters().trials + good.counters().rebuilds);
  }
  int Iterations() const {
    return problems.iterations() + static_cast<int>(good.counters().iterations);
  }

  // Reversing: good clusters accepted under a variance factor more than kRevalidateRatio times
  // the current one (early, on little evidence of the noise) leave the good set together and are
  // judged again at the current factor (Rejudge).
  void Revalidate(StepResult* result) {
    std::vector<int> suspects;
    for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
      const JudgedCluster& c = book->clusters[g];
      if (c.in_good && c.accepted_variance > kRevalidateRatio * variance) suspects.push_back(g);
    }
    if (suspects.empty()) return;
    for (int g : suspects) book->clusters[g].in_good = false;
    good.Rebuild(GoodLoops(), AlignmentCap());
    Rejudge(suspects, result);
    result->reversals += static_cast<int>(suspects.size());
  }

  // Recovering: clusters that have left the good set get back every link they held when they
  // closed and are judged again against the good set as it is now; their links that were
  // accepted and do not come back are reversed.
  void Rejudge(std::vector<int> clusters, StepResult* result) {
    std::vector<int> accepted_before;
    for (int g : clusters) {
      JudgedCluster& c = book->clusters[g];
      c.in_good = false;
      c.in_r = false;
      c.in_reject = false;
      c.links.clear();
    }
    for (int e = 0; e < graph->num_edges(); ++e) {
      const LoopDecision& decision = book->decisions[e];
      if (decision.cluster < 0 ||
          std::find(clusters.begin(), clusters.end(), decision.cluster) == clusters.end()) {
        continue;
      }
      book->clusters[decision.cluster].links.push_back(e);
      if (decision.state == LoopState::kAccepted) accepted_before.push_back(e);
    }
    SortLargestFirst(&clusters);
    ++rejudging;
    for (int g : clusters) Judge(g, result);
    --rejudging;
    for (int e : accepted_before) {
      const LoopDecision& decision = book->decisions[e];
      if (decision.state != LoopState::kAccepted) {
        book->Set(
            e, LoopState::kReversed, decision.chi2, decision.threshold, &result->changed_loops);
      }
    }
  }

  // The whole pipeline for one cluster: screen, Algorithm 1, joint test (with its splits).
  void Judge(int k, StepResult* result) {
    std::vector<int>* changed = &result->changed_loops;
    JudgedCluster& cluster = book->clusters[k];
    const int component_a = good.ComponentOf(cluster.session_a);
    const int component_b = good.ComponentOf(cluster.session_b);
    for (int c : {component_a, component_b}) {
      for (int s : good.SessionsOf(c)) result->sessions.push_back(s);
    }
    // The screen first: each link alone against the good set (a few sparse solves), so that
    // Algorithm 1 weighs only links that are not far off.
    if (component_a == component_b) Screen(k, changed);
    std::vector<int> splits;
    if (book->clusters[k].links.empty()) {
      book->clusters[k].in_reject = true;
      return;
    }
    // A cluster with redundancy enough of its own is judged at the larger of the global factor and
    // its own (the noise varies along a trajectory, and a place recognizer's error with it).
    if (book->clusters[k].links.size() >= 2) Calibrate(k);
    test_variance = OwnVariance(k);
    const bool survived =
        WarmIntraCluster(&problems, &pairwise, Thresholds(), k, book, changed, &splits);
    test_variance = 0.0;
    if (!survived) {
      book->clusters[k].in_reject = true;
      return;
    }
    std::vector<int> candidates = {k};
    candidates.insert(candidates.end(), splits.begin(), splits.end());
    for (int q : candidates) {
      JudgedCluster& c = book->clusters[q];
      if (!c.in_r || c.links.empty()) continue;
      // A lone link left of a cluster is screened as one (with the others it went by their median).
      if (c.links.size() == 1 && good.ComponentOf(c.session_a) == good.ComponentOf(c.session_b)) {
        Screen(q, changed);
        if (c.links.empty()) {
          c.in_reject = true;
          continue;
        }
      }
      if (HoldIfUnsupported(q, changed)) continue;
      c.held = false;
      JointTest(q, result);
    }
  }

  // The screen: links far off at the current optimum leave cluster q (inside one component).
  void Screen(int q, std::vector<int>* changed) {
    std::vector<int>& links = book->clusters[q].links;
    const std::vector<double> statistic = LinkStatistics(links);
    // Far off: kScreenMargin times the link threshold, and kClusterMargin times the cluster's
    // median statistic (links that agree with each other go on together, however far the good
    // set's estimate is from them).
    std::vector<double> sorted = statistic;
    std::sort(sorted.begin(), sorted.end());
    const double median = links.size() >= 2 ? sorted[sorted.size() / 2] : 0.0;
    const double far = std::max(kScreenMargin * LinkThreshold(), kClusterMargin * median);
    std::vector<int> kept;
    for (size_t k = 0; k < links.size(); ++k) {
      if (statistic[k] <= far) {
        kept.push_back(links[k]);
      } else {
        book->Set(links[k], LoopState::kRejectedJointTest, statistic[k], far, changed);
      }
    }
    links = kept;
  }

  // Each link's linearized chi2 increase alone at the current optimum (its ends in one
  // component); its redundancy number goes to `control`.
  std::vector<double> LinkStatistics(const std::vector<int>& links) {
    if (static_cast<int>(control.size()) < graph->num_edges()) {
      control.resize(graph->num_edges(), -1.0);
    }
    const std::vector<LinearizedAddition> additions = good.LinearizeEach(links);
    std::vector<double> statistic(links.size());
    for (size_t k = 0; k < links.size(); ++k) {
      control[links[k]] = additions[k].redundancy;
      statistic[k] = additions[k].chi2_increase;
    }
    return statistic;
  }

  // Whether cluster q could pass the joint test against the good set now. Its chi2 increase is
  // at least that of any one of its links alone (more edges cannot lower the optimum's chi2), so
  // a link whose linearized statistic is kClusterMargin times the cluster's threshold rules it
  // out without a nonlinear trial. Clusters between two components are not ruled out here.
  bool MayPass(int q) {
    const JudgedCluster& c = book->clusters[q];
    if (good.ComponentOf(c.session_a) != good.ComponentOf(c.session_b)) return true;
    const std::vector<double> statistic = LinkStatistics(c.links);
    const double worst = *std::max_element(statistic.begin(), statistic.end());
    return worst <= kClusterMargin * Threshold(static_cast<double>(d * c.links.size()));
  }

  // A cluster of one link (none of its own to support it) whose end poses the good set knows far
  // worse than the link measures them (redundancy number below kMinRedundancy, or in two
  // components): the link would bend the estimate to fit whatever it says, so no test can tell
  // it wrong.
  bool Unsupported(int q) const {
    const JudgedCluster& c = book->clusters[q];
    if (c.links.size() != 1) return false;
    const int e = c.links.front();
    return e >= static_cast<int>(control.size()) || !(control[e] >= kMinRedundancy);
  }

  // An unsupported cluster waits, as judged by nothing yet, for a good set that can check it.
  bool HoldIfUnsupported(int q, std::vector<int>* changed) {
    if (!Unsupported(q)) return false;
    JudgedCluster& c = book->clusters[q];
    c.in_r = false;
    c.held = true;
    book->Set(c.links.front(), LoopState::kPending, 0.0, 0.0, changed);
    return true;
  }

  // The components a cluster touches.
  std::vector<int> ComponentsOf(int q) const {
    const JudgedCluster& c = book->clusters[q];
    std::vector<int> components = {good.ComponentOf(c.session_a), good.ComponentOf(c.session_b)};
    if (components[0] == components[1]) components.pop_back();
    return components;
  }

  double ConsistencyIndex(int q, double* chi2) const {
    *chi2 = 0.0;
    for (int e : book->clusters[q].links) *chi2 += good.EdgeChi2(e);
    return *chi2 / Threshold(d * static_cast<double>(book->clusters[q].links.size()));
  }

  // Whether cluster q passes at the open trial's optimum: its consistency index, and each link.
  bool Consistent(int q) const {
    double chi2;
    if (ConsistencyIndex(q, &chi2) >= 1.0) return false;
    for (int e : book->clusters[q].links) {
      if (!(good.EdgeChi2(e) < LinkThreshold())) return false;
    }
    return true;
  }

  // The larger of the global factor and cluster q's own (kOwnFactorMinimumDof of redundancy);
  // 0 (the global factor) otherwise. At most kOwnFactorRatio times the global factor and 1: wrong
  // links raise a cluster's own factor (Sphere2500 + 1000 random: to 6.9, seven wrong loops in).
  double OwnVariance(int q) const {
    const JudgedCluster& c = book->clusters[q];
    if (c.redundancy_dof < kOwnFactorMinimumDof) return 0.0;
    const double own = std::min(c.redundancy_chi2 / c.redundancy_dof, kOwnFactorRatio * variance);
    return std::max(variance, std::min(own, 1.0));
  }

  // The parts a cluster failing the joint test is judged again as: each run of two links or more
  // (links whose ends lie within kRunGap poses of another's ends), in the order of its first
  // link, and the lone links together (on their own, lone wrong links a few poses long are hard to
  // tell from true ones).
  std::vector<std::vector<int>> Runs(const std::vector<int>& links) const {
    std::vector<int> run(links.size());
    for (size_t k = 0; k < links.size(); ++k) run[k] = static_cast<int>(k);
    std::function<int(int)> root = [&](int k) { return run[k] == k ? k : run[k] = root(run[k]); };
    auto near = [this](int a, int b) {
      const Edge<Pose>& x = graph->edge(a);
      const Edge<Pose>& y = graph->edge(b);
      return std::abs(std::min(x.from, x.to) - std::min(y.from, y.to)) <= kRunGap &&
             std::abs(std::max(x.from, x.to) - std::max(y.from, y.to)) <= kRunGap;
    };
    for (size_t a = 0; a < links.size(); ++a) {
      for (size_t b = 0; b < a; ++b) {
        if (near(links[a], links[b])) run[root(static_cast<int>(a))] = root(static_cast<int>(b));
      }
    }
    std::vector<std::vector<int>> runs;
    std::vector<int> index(links.size(), -1);
    for (size_t k = 0; k < links.size(); ++k) {
      int& r = index[root(static_cast<int>(k))];
      if (r < 0) {
        r = static_cast<int>(runs.size());
        runs.emplace_back();
      }
      runs[r].push_back(links[k]);
    }
    std::vector<std::vector<int>> parts;
    std::vector<int> lone;
    for (std::vector<int>& r : runs) {
      if (r.size() >= 2) {
        parts.push_back(std::move(r));
      } else {
        lone.push_back(r.front());
      }
    }
    if (!lone.empty()) parts.push_back(lone);
    return parts;
  }

  // Cluster q, inconsistent with the good set as a whole, judged again as its runs: the largest
  // stays q, each other becomes a cluster of its own; each is joint-tested on its own, largest
  // first (a run of one link the good set cannot check waits, as in Judge).
  void JudgeRuns(int q, std::vector<std::vector<int>> runs, StepResult* result) {
    std::stable_sort(
        runs.begin(), runs.end(), [](const auto& a, const auto& b) { return a.size() > b.size(); });
    std::vector<int> clusters = {q};
    book->clusters[q].links = runs.front();
    for (size_t k = 1; k < runs.size(); ++k) {
      const int part = book->AddCluster(book->clusters[q].session_a, book->clusters[q].session_b);
      book->clusters[part].links = runs[k];
      book->clusters[part].closed = true;
      book->clusters[part].in_r = true;
      for (int e : runs[k]) book->decisions[e].cluster = part;
      clusters.push_back(part);
    }
    // At the global factor: the cluster's own factor held the wrong runs' residuals.
    const double own = test_variance;
    test_variance = 0.0;
    for (int r : clusters) {
      if (!HoldIfUnsupported(r, &result->changed_loops)) JointTestAtScale(r, result);
    }
    test_variance = own;
  }

  bool IncreasePasses(const typename GoodSet<Pose>::Trial& trial) const {
    return trial.ok && (trial.dof <= 0.0 || trial.increase < Threshold(trial.dof));
  }

  void Accept(int q, std::vector<int>* changed) {
    JudgedCluster& c = book->clusters[q];
    for (int e : c.links) {
      book->Set(e, LoopState::kAccepted, good.EdgeChi2(e), LinkThreshold(), changed);
    }
    c.in_good = true;
    c.in_reject = false;
    c.in_r = true;
    c.accepted_variance = variance;
  }

  void JointTest(int q, StepResult* result) {
    // A cluster with redundancy enough of its own is judged at the larger of the global factor
    // and its own (the noise varies along a trajectory; Algorithm 1's graph test has already
    // bounded its own factor by the global one's threshold).
    test_variance = OwnVariance(q);
    JointTestAtScale(q, result);
    test_variance = 0.0;
  }

  void JointTestAtScale(int q, StepResult* result) {
    std::vector<int>* changed = &result->changed_loops;
    while (true) {
      std::vector<int>& links = book->clusters[q].links;
      const std::vector<int> components = ComponentsOf(q);
      const typename GoodSet<Pose>::Trial trial = good.Try(links, AlignmentCap());
      if (!trial.ok) {
        for (int e : links) {
          book->Set(e,
                    LoopState::kRejectedJointTest,
                    std::numeric_limits<double>::quiet_NaN(),
                    std::numeric_limits<double>::quiet_NaN(),
                    changed);
        }
        book->clusters[q].in_reject = true;
        return;
      }
      double cluster_chi2;
      const double index = ConsistencyIndex(q, &cluster_chi2);
      if (IncreasePasses(trial) && index < 1.0) {
        // Links failing on their own leave; the rest is judged again without them.
        std::vector<int> kept;
        std::vector<std::pair<int, double>> failing;
        for (int e : links) {
          const double chi2 = good.EdgeChi2(e);
          if (chi2 < LinkThreshold()) {
            kept.push_back(e);
          } else {
            failing.push_back({e, chi2});
          }
        }
        if (failing.empty()) {
          good.Commit();
          Accept(q, changed);
          return;
        }
        good.Rollback();
        for (const auto& [e, chi2] : failing) {
          book->Set(e, LoopState::kRejectedLinkTest, chi2, LinkThreshold(), changed);
        }
        links = kept;
        if (kept.empty()) break;
        continue;
      }
      // Inconsistent as a whole. A cluster of several runs (Runs: a few wrong links among
      // a place's true ones form runs of their own) is judged again as its runs, each a cluster
      // of its own, so that a wrong run does not take the true ones down with it.
      const std::vector<std::vector<int>> runs = Runs(links);
      if (runs.size() >= 2) {
        good.Rollback();
        JudgeRuns(q, runs, result);
        return;
      }
      // With the good clusters that are inconsistent too, if any.
      std::vector<std::pair<double, int>> ranked;  // (consistency index, good cluster)
      for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
        if (!book->clusters[g].in_good || !Within(components, g)) continue;
        double chi2;
        const double g_index = ConsistencyIndex(g, &chi2);
        if (g_index >= 1.0) ranked.push_back({g_index, g});
      }
      std::sort(ranked.rbegin(), ranked.rend());
      std::vector<int> suspects;  // most inconsistent first
      for (const auto& [unused, g] : ranked) suspects.push_back(g);
      good.Rollback();
      const double threshold = trial.dof > 0.0 ? Threshold(trial.dof) : 0.0;
      for (int e : links) {
        book->Set(e, LoopState::kRejectedJointTest, trial.increase, threshold, changed);
      }
      book->clusters[q].in_reject = true;
      for (int g : suspects) book->clusters[g].opponents.push_back(q);
      if (!suspects.empty()) Challenge(suspects, components, result);
      return;
    }
    book->clusters[q].in_reject = true;
  }

  // Reversal (Algorithm 2 with later evidence): when a cluster falls against good clusters that
  // are inconsistent too (the suspects, most inconsistent first), the clusters that fell against
  // them so far (their opponents) challenge them (Replace): first the most inconsistent suspect
  // alone (a small wrong cluster bends the map, so true ones near it look inconsistent too).
  void Challenge(const std::vector<int>& suspects,
                 const std::vector<int>& components,
                 StepResult* result) {
    if (rejudging > 0) return;  // one challenge at a time: what it re-judges does not challenge
    std::vector<int> challengers;
    size_t challenger_links = 0;
    size_t smallest_suspect = std::numeric_limits<size_t>::max();
    for (int g : suspects) {
      smallest_suspect = std::min(smallest_suspect, book->clusters[g].links.size());
      for (int r : book->clusters[g].opponents) {
        const JudgedCluster& c = book->clusters[r];
        // A lone link cannot outvote anything: wrong ones fail against a good cluster one after
        // the other, each bending it, and none agrees with another.
        if (!c.in_reject || c.in_good || c.links.size() < 2 || !Within(components, r) ||
            std::find(challengers.begin(), challengers.end(), r) != challengers.end()) {
          continue;
        }
        challengers.push_back(r);
      }
    }
    SortLargestFirst(&challengers);
    if (challengers.size() > kMaxChallengers) challengers.resize(kMaxChallengers);
    for (int r : challengers) challenger_links += book->clusters[r].links.size();
    if (challenger_links <= smallest_suspect) return;
    if (suspects.size() >= 2 && Replace({suspects.front()}, challengers, components, result)) {
      return;
    }
    Replace(suspects, challengers, components, result);
  }

  // From the good set without `suspects`, each challenger and then each suspect is added if it
  // passes the joint test. A good set so built with more links replaces the current one (true):
  // suspects left out are reversed, challengers taken in accepted (the largest consistent set
  // wins).
  bool Replace(const std::vector<int>& suspects,
               const std::vector<int>& challengers,
               const std::vector<int>& components,
               StepResult* result) {
    std::vector<int> before;  // the good clusters now
    size_t good_links = 0;
    for (int g = 0; g < static_cast<int>(book->clusters.size()); ++g) {
      if (!book->clusters[g].in_good) continue;
      before.push_back(g);
      if (Within(components, g)) good_links += book->clusters[g].links.size();
    }
    std::vector<int> base;
    size_t base_links = 0;
    for (int g : before) {
      if (std::find(suspects.begin(), suspects.end(), g) != suspects.end()) continue;
      base.push_back(g);
      if (Within(components, g)) base_links += book->clusters[g].links.size();
    }
    const std::vector<Pose> saved = *estimate;
    auto loops_of = [this](const std::vector<int>& clusters) {
      std::vector<int> loops;
      for (int g : clusters) {
        loops.insert(loops.end(), book->clusters[g].links.begin(), book->clusters[g].links.end());
      }
      return loops;
    };
    good.Rebuild(loops_of(base), AlignmentCap());
    std::vector<int> taken;
    auto take_if_passes = [&](int q) {
      const typename GoodSet<Pose>::Trial trial = good.Try(book->clusters[q].links, AlignmentCap());
      if (!trial.ok) return;
      if (!IncreasePasses(trial) || !Consistent(q)) {
        good.Rollback();
        return;
      }
      good.Commit();
      taken.push_back(q);
      base_links += book->clusters[q].links.size();
    };
    for (int r : challengers) {
      if (MayPass(r)) take_if_passes(r);
    }
    // Without a challenger taken, the suspects taken back cannot make the good set larger.
    if (!taken.empty()) {
      std::vector<int> sorted_suspects = suspects;
      SortLargestFirst(&sorted_suspects);
      for (int g : sorted_suspects) take_if_passes(g);
    }
    if (base_links <= good_links) {
      // The good set stays as it was.
      *estimate = saved;
      good.Rebuild(loops_of(before), AlignmentCap());
      return false;
    }
    for (int q : taken) {
      if (!book->clusters[q].in_good) Accept(q, &result->changed_loops);
    }
    std::vector<int> reversed;
    for (int g : suspects) {
      if (std::find(taken.begin(), taken.end(), g) == taken.end()) reversed.push_back(g);
    }
    int since = book->step;  // the earliest acceptance of a reversed cluster's link
    for (int g : reversed) {
      for (int e : book->clusters[g].links) since = std::min(since, book->decisions[e].step);
    }
    for (int g : reversed) book->clusters[g].in_good = false;
    Recover(since, reversed, components, result);
    Rejudge(reversed, result);
    ++result->reversals;
    return true;
  }

  // Recovering: links refused by the good set's tests since step `since`, while the reversed
  // clusters bent its estimate, are judged again without them: those of each cluster (but the
  // reversed, judged again whole) as a cluster of their own.
  void Recover(int since,
               const std::vector<int>& reversed,
               const std::vector<int>& components,
               StepResult* result) {
    std::vector<std::pair<int, int>> refused;  // (cluster, link)
    for (int e = 0; e < graph->num_edges(); ++e) {
      const LoopDecision& decision = book->decisions[e];
      if (decision.cluster < 0 || decision.step < since ||
          (decision.state != LoopState::kRejectedJointTest &&
           decision.state != LoopState::kRejectedLinkTest) ||
          std::find(reversed.begin(), reversed.end(), decision.cluster) != reversed.end() ||
          !Within(components, decision.cluster)) {
        continue;
      }
      refused.push_back({decision.cluster, e});
    }
    std::sort(refused.begin(), refused.end());
    std::vector<int> parts;
    for (size_t k = 0; k < refused.size(); ++k) {
      const int g = refused[k].first;
      if (k == 0 || refused[k - 1].first != g) {
        parts.push_back(book->AddCluster(book->clusters[g].session_a, book->clusters[g].session_b));
        book->clusters[parts.back()].closed = true;
      }
      std::vector<int>& links = book->clusters[g].links;
      links.erase(std::remove(links.begin(), links.end(), refused[k].second), links.end());
      book->clusters[parts.back()].links.push_back(refused[k].second);
      book->decisions[refused[k].second].cluster = parts.back();
    }
    SortLargestFirst(&parts);
    ++rejudging;
    for (int q : parts) Judge(q, result);
    --rejudging;
  }

  const PoseGraph<Pose>* graph;
  const IrrrOptions* options;
  DecisionBook* book;
  std::vector<Pose>* estimate;
  LocalProblems<Pose> problems;
  PairwiseConsistency<Pose> pairwise;
  GoodSet<Pose> good;
  double variance = 1.0;  // the factor of the tests (the estimate, at most 1)
  // A cluster with redundancy enough of its own is judged at a larger factor (JointTest); 0: none.
  double test_variance = 0.0;
  double variance_estimate = 1.0;
  double variance_dof = std::numeric_limits<double>::infinity();
  bool scale_known = false;
  bool released = false;
  int rejudging = 0;            // Rejudge under way (no challenge starts inside one)
  std::vector<double> control;  // per loop edge: its redundancy number at its last screen
};

template <class Pose>
WarmEngine<Pose>::WarmEngine(const PoseGraph<Pose>* graph,
                             const IrrrOptions* options,
                             DecisionBook* book,
                             std::vector<Pose>* estimate,
                             const std::vector<Pose>* dead_reckoning)
    : impl_(std::make_unique<Impl>(graph, options, book, estimate, dead_reckoning)) {}

template <class Pose>
WarmEngine<Pose>::~WarmEngine() = default;

template <class Pose>
void WarmEngine<Pose>::AddPose(int vertex) {
  impl_->good.AddPose(vertex);
  impl_->pairwise.Update();
}

template <class Pose>
void WarmEngine<Pose>::Release() {
  impl_->released = true;
}

template <class Pose>
bool WarmEngine<Pose>::HasReleased() const {
  const Impl& m = *impl_;
  if (!m.released || m.CurrentScale().known) return false;
  for (int q : m.Waiting()) {
    if (!m.book->clusters[q].held) return true;
  }
  return false;
}

template <class Pose>
void WarmEngine<Pose>::Step(int cluster, StepResult* result) {
  impl_->Step(cluster, result);
}

template <class Pose>
std::vector<int> WarmEngine<Pose>::Components() const {
  return impl_->good.Components();
}

template <class Pose>
void WarmEngine<Pose>::Restore() {
  Impl& m = *impl_;
  m.control.clear();
  m.good.Rebuild(m.GoodLoops(), m.AlignmentCap());
}

template class WarmEngine<Pose2>;
template class WarmEngine<Pose3>;

}  // namespace irrr
