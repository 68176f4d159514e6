#include "core/time_reversal.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <catch2/catch.hpp>

#include "core/irrr.h"
#include "core/optimizer.h"
#include "core/outliers.h"
#include "core/pose.h"
#include "tests/corrupted_graph.h"
#include "tests/synthetic_graph.h"

namespace irrr {
namespace {

using testing::MakeCorrupted;
using testing::MakeSyntheticGraph;
using testing::NoisyOptions;
using testing::NoisyWorld;
using testing::SyntheticOptions;

// `estimate` (indexed like the original's vertices) indexed like the reversed graph's.
template <class Pose>
std::vector<Pose> Mapped(const std::vector<Pose>& estimate, const std::vector<int>& vertex_of) {
  std::vector<Pose> out(estimate.size());
  for (size_t v = 0; v < estimate.size(); ++v) out[vertex_of[v]] = estimate[v];
  return out;
}

template <class Pose>
double TotalChi2(const PoseGraph<Pose>& graph, const std::vector<Pose>& estimate, EdgeKind kind) {
  double chi2 = 0.0;
  for (const Edge<Pose>& edge : graph.edges()) {
    if (edge.kind == kind) chi2 += EdgeChi2(edge, estimate);
  }
  return chi2;
}

template <class Pose>
Pose RandomPose(std::mt19937* rng, double translation_m, double rotation_rad) {
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  typename Pose::Tangent xi;
  constexpr int t = Pose::kTranslationDim;
  for (int k = 0; k < Pose::kDim; ++k)
    xi(k) = (k < t ? translation_m : rotation_rad) * uniform(*rng);
  return Pose::Exp(xi);
}

// A random symmetric positive definite information with correlations, eigenvalues in [1, 1e4].
template <class Pose>
typename Pose::Matrix RandomInformation(std::mt19937* rng) {
  using Matrix = typename Pose::Matrix;
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  Matrix a;
  for (int r = 0; r < Pose::kDim; ++r) {
    for (int c = 0; c < Pose::kDim; ++c) a(r, c) = uniform(*rng);
  }
  const Eigen::HouseholderQR<Matrix> qr(a);
  const Matrix q = qr.householderQ();
  typename Pose::Tangent eigenvalues;
  for (int k = 0; k < Pose::kDim; ++k) eigenvalues(k) = std::pow(10.0, 2.0 + 2.0 * uniform(*rng));
  return q * eigenvalues.asDiagonal() * q.transpose();
}

// The residual of an edge near its measurement (x_to = x_from z Exp(delta), |delta| ~ h = 1e-5)
// has size h; the inverted edge's error is -M e up to terms of order h^2 times the measurement's
// lever arm (up to 3 m here), so d^2 agrees to a relative O(h * lever arm): measured up to 9e-5,
// a margin of 10. The other adjoint convention (M = T^-1 Adjoint(z^-1) T) misses by 300-700
// relative, the SE(3) transform without the chart factor T by 60.
constexpr double kFirstOrderRelative = 1e-3;

TEMPLATE_TEST_CASE("The inverted edge's information gives it the original's d^2 to first order",
                   "[reversal]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  // Rotations up to pi (the SE(3) chart's quaternion sign flips there) and the identity.
  const double rotation_rad = GENERATE(0.0, 0.5, M_PI);
  const double step_m = GENERATE(0.0, 1.0, 3.0);
  INFO("rotations up to " << rotation_rad << " rad, translations up to " << step_m << " m");
  for (int trial = 0; trial < 200; ++trial) {
    INFO("trial " << trial);
    const Pose measurement = RandomPose<Pose>(&rng, step_m, rotation_rad);
    const Pose from = RandomPose<Pose>(&rng, 10.0, M_PI);
    typename Pose::Tangent delta;
    for (int k = 0; k < Pose::kDim; ++k) delta(k) = 1e-5 * uniform(rng);
    const Pose to = from * measurement * Pose::Exp(delta);
    Edge<Pose> edge;
    edge.measurement = measurement;
    edge.information = RandomInformation<Pose>(&rng);
    Edge<Pose> inverted;
    inverted.measurement = measurement.Inverse();
    inverted.information = InvertedInformation(measurement, edge.information);
    REQUIRE(ValidateInformation<Pose>(inverted.information).ok());
    const double d2 = EdgeChi2(edge, from, to);
    const double inverted_d2 = EdgeChi2(inverted, to, from);
    INFO("d2 " << d2 << ", inverted " << inverted_d2);
    CHECK(std::abs(inverted_d2 - d2) <= kFirstOrderRelative * d2);
  }
}

// Synthetic graphs on the ground truth plus noise of this size: odometry residuals of order
// kTinySigma, where the first-order information transform holds to a relative O(kTinySigma).
constexpr double kTinySigma = 1e-6;
// d^2 of one odometry edge: relative O(kTinySigma * lever arm (1 m steps) * a few sigmas of
// noise), plus the rounding of residuals of size 1e-6 computed from poses 10 m from the origin
// (1e-15 * 10 m / 1e-6, relative 1e-8). Measured up to 1.8 kTinySigma.
constexpr double kEdgeRelative = 20.0 * kTinySigma;
// Sums of d^2 over the graph: the per-edge differences are of both signs (measured up to 2e-8).
constexpr double kTotalRelative = 1e-6;

template <class Pose>
SyntheticOptions TinyNoise(uint32_t seed) {
  SyntheticOptions options = NoisyOptions<Pose>(seed);
  options.num_sessions = 3;
  options.translation_sigma_m = kTinySigma;
  options.rotation_sigma_rad = kTinySigma;
  return options;
}

TEMPLATE_TEST_CASE("A time-reversed graph has the original's chi2 at the same poses",
                   "[reversal]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  const uint32_t seed = GENERATE(1u, 2u);
  INFO("seed " << seed);
  const auto synthetic = MakeSyntheticGraph<Pose>(TinyNoise<Pose>(seed));
  const PoseGraph<Pose>& graph = synthetic.graph;
  REQUIRE(graph.num_sessions() == 3);
  REQUIRE(!synthetic.loop_edges.empty());
  const ReversedGraph<Pose> reversed = TimeReversed(graph);

  SECTION("at the initial estimate: loops the same, the whole graph within 1e-6") {
    const std::vector<Pose>& estimate = graph.initial_estimate();
    const std::vector<Pose> mapped = Mapped(estimate, reversed.vertex_of);
    // The reversed graph keeps every vertex's initial estimate.
    CHECK(reversed.graph.initial_estimate().size() == mapped.size());
    for (size_t v = 0; v < mapped.size(); ++v) {
      CHECK(reversed.graph.initial_estimate()[v].ErrorVector() == mapped[v].ErrorVector());
    }
    const double loops = TotalChi2(graph, estimate, EdgeKind::kLoop);
    CHECK(loops > 0.0);
    CHECK(TotalChi2(reversed.graph, mapped, EdgeKind::kLoop) == loops);
    const double total = loops + TotalChi2(graph, estimate, EdgeKind::kOdometry);
    const double reversed_total = TotalChi2(reversed.graph, mapped, EdgeKind::kLoop) +
                                  TotalChi2(reversed.graph, mapped, EdgeKind::kOdometry);
    CHECK(std::abs(reversed_total - total) <= kTotalRelative * total);
  }

  SECTION("at the ground truth: every edge's d^2 to first order in the noise") {
    const std::vector<Pose>& truth = synthetic.ground_truth;
    const std::vector<Pose> mapped = Mapped(truth, reversed.vertex_of);
    double total = 0.0;
    double reversed_total = 0.0;
    for (int e = 0; e < graph.num_edges(); ++e) {
      const double d2 = EdgeChi2(graph.edge(e), truth);
      const double reversed_d2 = EdgeChi2(reversed.graph.edge(reversed.edge_of[e]), mapped);
      INFO("edge " << e << ": d2 " << d2 << ", reversed " << reversed_d2);
      if (graph.edge(e).kind == EdgeKind::kLoop) {
        CHECK(reversed_d2 == d2);
      } else {
        CHECK(std::abs(reversed_d2 - d2) <= kEdgeRelative * std::max(d2, 1.0));
      }
      total += d2;
      reversed_total += reversed_d2;
    }
    // Odometry and loops at the truth both weigh about one unit of d^2 per degree of freedom.
    CHECK(total > graph.num_edges());
    CHECK(std::abs(reversed_total - total) <= kTotalRelative * total);
  }
}

template <class Pose>
double MaxAbs(const typename Pose::Matrix& m) {
  return m.cwiseAbs().maxCoeff();
}

TEMPLATE_TEST_CASE("Reversing a graph twice gives it back", "[reversal]", Pose2, Pose3) {
  using Pose = TestType;
  SyntheticOptions options = NoisyOptions<Pose>(3);
  options.num_sessions = 3;
  OutlierOptions outliers;
  outliers.mode = OutlierMode::kRandomGrouped;
  outliers.count = 12;
  const PoseGraph<Pose> graph = MakeCorrupted<Pose>(options, outliers).graph;
  const ReversedGraph<Pose> once = TimeReversed(graph);
  const ReversedGraph<Pose> twice = TimeReversed(once.graph);
  REQUIRE(twice.graph.num_vertices() == graph.num_vertices());
  REQUIRE(twice.graph.num_edges() == graph.num_edges());
  REQUIRE(twice.graph.num_sessions() == graph.num_sessions());
  for (int v = 0; v < graph.num_vertices(); ++v) {
    INFO("vertex " << v);
    const int back = twice.vertex_of[once.vertex_of[v]];
    CHECK(back == v);
    CHECK(twice.graph.vertex(back).id == graph.vertex(v).id);
    CHECK(twice.graph.vertex(back).session == graph.vertex(v).session);
    CHECK(twice.graph.vertex(back).stamp == graph.vertex(v).stamp);
  }
  // Two inversions of a measurement round off at 1e-15; two transforms of an information at
  // 1e-15 times the condition of Adjoint(z)^2 (steps of a metre or so).
  constexpr double kSame = 1e-9;
  for (int e = 0; e < graph.num_edges(); ++e) {
    INFO("edge " << e);
    const Edge<Pose>& edge = graph.edge(e);
    const Edge<Pose>& back = twice.graph.edge(twice.edge_of[once.edge_of[e]]);
    CHECK(twice.edge_of[once.edge_of[e]] == e);  // loops follow all poses in both
    CHECK(back.kind == edge.kind);
    CHECK(back.from == edge.from);
    CHECK(back.to == edge.to);
    CHECK((back.measurement.ErrorVector() - edge.measurement.ErrorVector()).cwiseAbs().maxCoeff() <=
          kSame);
    CHECK(MaxAbs<Pose>(back.information - edge.information) <=
          kSame * MaxAbs<Pose>(edge.information));
  }
}

TEMPLATE_TEST_CASE("A time-reversed graph drives each session backwards",
                   "[reversal]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  SyntheticOptions options = NoisyOptions<Pose>(4);
  options.num_sessions = 3;
  const PoseGraph<Pose> graph = MakeSyntheticGraph<Pose>(options).graph;
  const ReversedGraph<Pose> reversed = TimeReversed(graph);
  const PoseGraph<Pose>& out = reversed.graph;
  REQUIRE(out.num_vertices() == graph.num_vertices());
  REQUIRE(out.num_edges() == graph.num_edges());
  REQUIRE(out.num_sessions() == graph.num_sessions());

  for (int s = 0; s < graph.num_sessions(); ++s) {
    INFO("session " << s);
    CHECK(out.session(s).id == graph.session(s).id);
    const std::vector<int>& vertices = graph.session(s).vertices;
    const std::vector<int>& backwards = out.session(s).vertices;
    REQUIRE(backwards.size() == vertices.size());
    const double first = graph.vertex(vertices.front()).stamp;
    const double last = graph.vertex(vertices.back()).stamp;
    for (size_t k = 0; k < vertices.size(); ++k) {
      const int v = vertices[vertices.size() - 1 - k];  // the original pose at position k
      REQUIRE(backwards[k] == reversed.vertex_of[v]);
      const Vertex& vertex = out.vertex(backwards[k]);
      CHECK(vertex.id == graph.vertex(v).id);
      CHECK(vertex.session == s);
      CHECK(vertex.stamp == last + first - graph.vertex(v).stamp);
      if (k > 0) CHECK(vertex.stamp > out.vertex(backwards[k - 1]).stamp);
      // The odometry into it comes from its time successor, and inverts the original's.
      const int odometry = out.OdometryInto(backwards[k]);
      if (k == 0) {
        CHECK(odometry == -1);
        continue;
      }
      REQUIRE(odometry >= 0);
      const int original = graph.OdometryInto(vertices[vertices.size() - k]);
      REQUIRE(original >= 0);
      CHECK(reversed.edge_of[original] == odometry);
      CHECK(out.edge(odometry).from == reversed.vertex_of[vertices[vertices.size() - k]]);
      CHECK(out.edge(odometry).to == backwards[k]);
      const Pose identity = out.edge(odometry).measurement * graph.edge(original).measurement;
      CHECK(identity.ErrorVector().norm() <= 1e-12);
    }
  }
  // Loops after every odometry edge, in the original order, endpoints renumbered, the rest as is.
  int previous = -1;
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose>& edge = graph.edge(e);
    if (edge.kind != EdgeKind::kLoop) continue;
    INFO("loop " << e);
    const int r = reversed.edge_of[e];
    CHECK(r > previous);
    CHECK(r >= graph.num_vertices() - graph.num_sessions());
    previous = r;
    CHECK(out.edge(r).kind == EdgeKind::kLoop);
    CHECK(out.edge(r).from == reversed.vertex_of[edge.from]);
    CHECK(out.edge(r).to == reversed.vertex_of[edge.to]);
    CHECK(out.edge(r).measurement.ErrorVector() == edge.measurement.ErrorVector());
    CHECK(out.edge(r).information == edge.information);
  }
}

// The synthetic robot revisits places every few poses; a cluster gap of 10 poses keeps clusters
// to one visit (as in irrr_test.cc).
IrrrOptions SyntheticIrrrOptions() {
  IrrrOptions options;
  options.cluster_gap = 10.0;
  return options;
}

TEMPLATE_TEST_CASE("iRRR accepts the same loops whether the sessions run forwards or backwards",
                   "[reversal]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  const uint32_t seed = GENERATE(1u, 2u);
  INFO("seed " << seed);
  SyntheticOptions synthetic = NoisyWorld<Pose>(seed);
  synthetic.num_sessions = 2;
  OutlierOptions outliers;
  outliers.mode = OutlierMode::kRandom;
  outliers.count = 10;
  outliers.seed = seed;
  const auto corrupted = MakeCorrupted<Pose>(synthetic, outliers);
  const PoseGraph<Pose>& graph = corrupted.graph;
  const ReversedGraph<Pose> reversed = TimeReversed(graph);
  const IrrrOptions options = SyntheticIrrrOptions();
  const auto forward = RunIncrementalIrrr<Pose>(graph, options, nullptr, nullptr);
  const auto backward = RunIncrementalIrrr<Pose>(reversed.graph, options, nullptr, nullptr);
  int accepted = 0;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind != EdgeKind::kLoop) continue;
    INFO("loop " << e << (corrupted.is_outlier[e] ? " (wrong)" : " (true)"));
    const bool accepted_forward = forward[e].state == LoopState::kAccepted;
    CHECK(accepted_forward == (backward[reversed.edge_of[e]].state == LoopState::kAccepted));
    CHECK(!(accepted_forward && corrupted.is_outlier[e]));
    accepted += accepted_forward ? 1 : 0;
  }
  CHECK(accepted > 0);
}

}  // namespace
}  // namespace irrr
