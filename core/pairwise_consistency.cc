#include "core/pairwise_consistency.h"

#include <algorithm>
#include <limits>

#include <Eigen/Cholesky>

#include "core/test_statistics.h"

namespace irrr {
namespace {

// Seeds tried by ConsistentSubsets' greedy search (those with the most consistent partners): the
// true links of a cluster are consistent with one another, so any of them grows the same set.
constexpr size_t kSeeds = 8;

}  // namespace

template <class Pose>
PairwiseConsistency<Pose>::PairwiseConsistency(const PoseGraph<Pose>* graph,
                                               const std::vector<Pose>* dead_reckoning)
    : graph_(graph), dead_reckoning_(dead_reckoning), odometry_(graph, dead_reckoning) {}

template <class Pose>
typename PairwiseConsistency<Pose>::Oriented PairwiseConsistency<Pose>::Orient(int e) const {
  const PoseGraph<Pose>& graph = *graph_;
  const Matrix M = TangentOfErrorVector<Pose>();
  const Edge<Pose>& edge = graph.edge(e);
  const Vertex& from = graph.vertex(edge.from);
  const Vertex& to = graph.vertex(edge.to);
  const bool from_is_a = from.session != to.session
                             ? from.session > to.session
                             : odometry_.Position(edge.from) >= odometry_.Position(edge.to);
  Oriented o;
  o.covariance = M * edge.information.inverse() * M.transpose();
  if (from_is_a) {
    o.a = edge.from;
    o.b = edge.to;
    o.z = edge.measurement;
  } else {
    o.a = edge.to;
    o.b = edge.from;
    o.z = edge.measurement.Inverse();
    const Matrix adjoint = Adjoint(edge.measurement);
    o.covariance = adjoint * o.covariance * adjoint.transpose();
  }
  return o;
}

template <class Pose>
double PairwiseConsistency<Pose>::Statistic(int l, int m) const {
  if (l == m) return 0.0;
  return Statistic(Orient(l), Orient(m));
}

template <class Pose>
double PairwiseConsistency<Pose>::Statistic(const Oriented& first, const Oriented& second) const {
  const PoseGraph<Pose>& graph = *graph_;
  const std::vector<Pose>& x = *dead_reckoning_;
  const int session_a = graph.vertex(first.a).session;
  const int session_b = graph.vertex(first.b).session;
  IRRR_CHECK(graph.vertex(second.a).session == session_a &&
             graph.vertex(second.b).session == session_b);
  // e = B^-1 L^-1 A Z with A = D(a_l -> a_m), B = D(b_l -> b_m), L = z_l, Z = z_m.
  const Pose A = x[first.a].Inverse() * x[second.a];
  const Pose B = x[first.b].Inverse() * x[second.b];
  const Pose& L = first.z;
  const Pose& Z = second.z;
  const Pose e = B.Inverse() * L.Inverse() * A * Z;
  const Pose Z_inverse = Z.Inverse();
  const Pose to_L = Z_inverse * A.Inverse() * L;
  const Matrix K_A = Adjoint(Z_inverse);
  const Matrix K_L = -Adjoint(to_L);
  const Matrix K_B = -Adjoint(to_L * B);
  const Matrix C_A =
      odometry_.Relative(session_a, odometry_.Position(first.a), odometry_.Position(second.a));
  const Matrix C_B =
      odometry_.Relative(session_b, odometry_.Position(first.b), odometry_.Position(second.b));
  const Matrix covariance = K_A * C_A * K_A.transpose() + K_B * C_B * K_B.transpose() +
                            K_L * first.covariance * K_L.transpose() + second.covariance;
  const typename Pose::Tangent r = e.Log();
  const Eigen::LDLT<Matrix> ldlt(0.5 * (covariance + covariance.transpose()));
  if (ldlt.info() != Eigen::Success) return std::numeric_limits<double>::infinity();
  return r.dot(ldlt.solve(r));
}

template <class Pose>
const std::vector<double>& PairwiseConsistency<Pose>::Statistics(
    const std::vector<int>& links) const {
  if (links == last_links_) return last_statistics_;
  const size_t n = links.size();
  last_links_ = links;
  last_statistics_.assign(n * n, 0.0);
  std::vector<Oriented> oriented;
  for (int e : links) oriented.push_back(Orient(e));
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = i + 1; j < n; ++j) {
      last_statistics_[i * n + j] =
          links[i] == links[j] ? 0.0 : Statistic(oriented[i], oriented[j]);
    }
  }
  return last_statistics_;
}

template <class Pose>
bool PairwiseConsistency<Pose>::Noiseless(const std::vector<int>& links, double tiny) const {
  for (size_t k = 1; k < links.size(); ++k) {
    if (!(Statistic(links.front(), links[k]) < tiny)) return false;
  }
  return true;
}

template <class Pose>
double PairwiseConsistency<Pose>::PairwiseFactor(const std::vector<int>& links) const {
  constexpr size_t kFactorPairs = 2000;
  const size_t n = links.size();
  const size_t pairs = n * (n - 1) / 2;
  if (n < 2) return 0.0;
  const size_t stride = std::max<size_t>(1, pairs / kFactorPairs);
  const std::vector<double>& all = Statistics(links);
  std::vector<double> statistics;
  size_t index = 0;
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = i + 1; j < n; ++j, ++index) {
      if (index % stride == 0) statistics.push_back(all[i * n + j]);
    }
  }
  auto middle = statistics.begin() + statistics.size() / 2;
  std::nth_element(statistics.begin(), middle, statistics.end());
  return *middle / ChiSquareMedian(Pose::kDim);
}

template <class Pose>
std::vector<std::vector<int>> PairwiseConsistency<Pose>::ConsistentSubsets(
    const std::vector<int>& links, double threshold) const {
  const int n = static_cast<int>(links.size());
  const std::vector<double>& statistics = Statistics(links);
  std::vector<std::vector<char>> consistent(n, std::vector<char>(n, 1));
  for (int i = 0; i < n; ++i) {
    for (int j = i + 1; j < n; ++j) {
      consistent[i][j] = consistent[j][i] = statistics[i * n + j] < threshold ? 1 : 0;
    }
  }
  std::vector<std::vector<int>> subsets;
  std::vector<int> remaining(n);
  for (int i = 0; i < n; ++i) remaining[i] = i;
  while (!remaining.empty()) {
    // Partners of each remaining link among the remaining ones.
    std::vector<int> degree(n, 0);
    for (int i : remaining) {
      for (int j : remaining) degree[i] += i != j && consistent[i][j] ? 1 : 0;
    }
    std::vector<int> seeds = remaining;
    std::stable_sort(
        seeds.begin(), seeds.end(), [&](int a, int b) { return degree[a] > degree[b]; });
    if (seeds.size() > kSeeds) seeds.resize(kSeeds);
    std::vector<int> best;
    for (int seed : seeds) {
      std::vector<int> clique = {seed};
      std::vector<int> candidates;
      for (int j : remaining) {
        if (j != seed && consistent[seed][j]) candidates.push_back(j);
      }
      // Each candidate's partners among the candidates, kept as candidates leave (O(n^2) per
      // seed instead of counting them again at each pick).
      std::vector<int> partners(n, 0);
      for (int c : candidates) {
        for (int o : candidates) partners[c] += o != c && consistent[c][o] ? 1 : 0;
      }
      while (!candidates.empty()) {
        // The candidate consistent with most of the other candidates joins (the first of them).
        int pick = -1;
        int pick_partners = -1;
        for (int c : candidates) {
          if (partners[c] > pick_partners) {
            pick = c;
            pick_partners = partners[c];
          }
        }
        clique.push_back(pick);
        std::vector<int> still;
        std::vector<int> gone;
        for (int c : candidates) {
          if (c != pick) (consistent[pick][c] ? still : gone).push_back(c);
        }
        for (int c : still) {
          partners[c] -= 1;  // the pick
          for (int o : gone) partners[c] -= consistent[c][o] ? 1 : 0;
        }
        candidates.swap(still);
      }
      if (clique.size() > best.size()) best = clique;
    }
    std::sort(best.begin(), best.end());
    std::vector<int> subset;
    for (int i : best) subset.push_back(links[i]);
    subsets.push_back(subset);
    std::vector<int> rest;
    for (int i : remaining) {
      if (!std::binary_search(best.begin(), best.end(), i)) rest.push_back(i);
    }
    remaining.swap(rest);
  }
  return subsets;
}

template class PairwiseConsistency<Pose2>;
template class PairwiseConsistency<Pose3>;

}  // namespace irrr
