#include "core/outliers.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>
#include <vector>

#include <Eigen/Cholesky>
#include <catch2/catch.hpp>

#include "core/graph_io.h"
#include "core/pose.h"
#include "tests/rotation_angle.h"
#include "tests/synthetic_graph.h"

namespace irrr {
namespace {

using testing::MakeSyntheticGraph;
using testing::NoisyOptions;

// Compositions along a few hundred poses of a grid world or helix round off at 1e-12; a cycle
// that the generator closes exactly closes to this.
constexpr double kClosureTolerance = 1e-9;

template <class Pose>
bool SamePose(const Pose& a, const Pose& b) {
  return a.ErrorVector() == b.ErrorVector();
}

// Vertex index -> its position in its session.
template <class Pose>
std::vector<int> PositionsInSessions(const PoseGraph<Pose>& graph) {
  std::vector<int> position(graph.num_vertices(), -1);
  for (int s = 0; s < graph.num_sessions(); ++s) {
    const std::vector<int>& vertices = graph.session(s).vertices;
    for (size_t i = 0; i < vertices.size(); ++i) position[vertices[i]] = static_cast<int>(i);
  }
  return position;
}

// from_T_to along the odometry of one session (either direction).
template <class Pose>
Pose AlongOdometry(const PoseGraph<Pose>& graph, int from, int to) {
  const bool backwards = to < from;
  const int early = std::min(from, to);
  const int late = std::max(from, to);
  Pose early_T_late;
  // Session vertices are consecutive indices in a synthetic graph; walk back from `late`.
  std::vector<Pose> steps;
  for (int v = late; v != early; v = graph.edge(graph.OdometryInto(v)).from) {
    REQUIRE(graph.OdometryInto(v) >= 0);
    steps.push_back(graph.edge(graph.OdometryInto(v)).measurement);
  }
  for (auto it = steps.rbegin(); it != steps.rend(); ++it) early_T_late = early_T_late * *it;
  return backwards ? early_T_late.Inverse() : early_T_late;
}

template <class Pose>
PoseGraph<Pose> ThreeSessionGraph(uint32_t seed) {
  testing::SyntheticOptions options = NoisyOptions<Pose>(seed);
  options.num_sessions = 3;
  return MakeSyntheticGraph<Pose>(options).graph;
}

// Step i of a chain: forward with a small turn.
template <class Pose>
Pose Step(int i) {
  if constexpr (Pose::kDim == 3) {
    return Pose2(1.0, 0.05 * std::sin(0.1 * i), 0.02 * std::cos(0.07 * i));
  } else {
    return Pose3(ExpSO3(Eigen::Vector3d(0.01, -0.02, 0.03 * std::cos(0.07 * i))),
                 Eigen::Vector3d(1.0, 0.05 * std::sin(0.1 * i), 0.02));
  }
}

// A correlated covariance in the error chart (SE(3): the quaternion's vector part, half the
// angle), with centimetre and centiradian scales.
template <class Pose>
typename Pose::Matrix Covariance() {
  typename Pose::Matrix A = Pose::Matrix::Zero();
  for (int i = 0; i < Pose::kDim; ++i) {
    A(i, i) = i < Pose::kTranslationDim ? 0.05 : 0.01;
    for (int j = 0; j < i; ++j) A(i, j) = 0.3 * A(i, i) * (j % 2 == 0 ? 1.0 : -1.0);
  }
  return A * A.transpose();
}

// Two sessions of chained odometry (ids 0..n-1 and n+1..2n; the second starts away from the
// origin), and loops among them, one a second (i-1, i) edge, which is a loop hypothesis.
template <class Pose>
GraphFile<Pose> ChainFile(int n) {
  GraphFile<Pose> file;
  const typename Pose::Matrix information = Covariance<Pose>().inverse();
  for (int session = 0; session < 2; ++session) {
    const int64_t first = session == 0 ? 0 : n + 1;
    Pose estimate = session == 0 ? Pose() : Step<Pose>(7);
    for (int i = 0; i < n; ++i) {
      if (i > 0) {
        FileEdge<Pose> odometry;
        odometry.from = first + i - 1;
        odometry.to = first + i;
        odometry.measurement = Step<Pose>(i);
        odometry.information = information;
        file.edges.push_back(odometry);
        estimate = estimate * odometry.measurement;
      }
      FileVertex<Pose> vertex;
      vertex.id = first + i;
      vertex.estimate = estimate;
      file.vertices.push_back(vertex);
    }
  }
  for (int64_t from : {int64_t{10}, int64_t{n + 20}}) {
    FileEdge<Pose> loop;
    loop.from = from;
    loop.to = from + 1;
    loop.measurement = Step<Pose>(3);
    file.edges.push_back(loop);
    loop.from = from + 50;
    loop.to = from;
    file.edges.push_back(loop);
  }
  return file;
}

// The graph of `file` and which file edges are odometry.
template <class Pose>
void ReadBack(const GraphFile<Pose>& file, PoseGraph<Pose>* graph, std::vector<bool>* odometry) {
  std::vector<int> graph_edge_of_file_edge;
  REQUIRE(BuildPoseGraph(file, graph, &graph_edge_of_file_edge).ok());
  odometry->clear();
  for (int e : graph_edge_of_file_edge) {
    odometry->push_back(graph->edge(e).kind == EdgeKind::kOdometry);
  }
}

// Every session's vertex estimates are its first vertex's composed with its dead reckoning.
template <class Pose>
void RequireChainedEstimates(const GraphFile<Pose>& file) {
  PoseGraph<Pose> graph;
  std::vector<bool> odometry;
  ReadBack(file, &graph, &odometry);
  const std::vector<Pose> dead_reckoning = graph.OdometryEstimate();
  std::map<int64_t, Pose> estimate_of_id;
  for (const FileVertex<Pose>& v : file.vertices) estimate_of_id[v.id] = v.estimate;
  for (int s = 0; s < graph.num_sessions(); ++s) {
    const Pose first = estimate_of_id.at(graph.vertex(graph.session(s).vertices[0]).id);
    for (int v : graph.session(s).vertices) {
      const Pose difference =
          (first * dead_reckoning[v]).Inverse() * estimate_of_id.at(graph.vertex(v).id);
      REQUIRE(difference.translation().norm() < kClosureTolerance);
      REQUIRE(RotationAngle(difference) < kClosureTolerance);
    }
  }
}

TEMPLATE_TEST_CASE("Aliased wrong loops claim two distant poses are nearly the same place",
                   "[outliers]",
                   Pose2,
                   Pose3) {
  const PoseGraph<TestType> graph = ThreeSessionGraph<TestType>(1);
  const std::vector<int> position = PositionsInSessions(graph);
  OutlierOptions options;
  options.mode = OutlierMode::kAliased;
  options.count = 200;
  options.seed = 5;
  INFO("seed " << options.seed);
  std::vector<OutlierLink<TestType>> links;
  REQUIRE(MakeOutliers(graph, options, &links).ok());
  REQUIRE(links.size() == 200);
  std::set<int> sessions_joined;
  for (const OutlierLink<TestType>& link : links) {
    CHECK(link.measurement.translation().norm() <= options.aliased_translation_m);
    CHECK(RotationAngle(link.measurement) <= options.aliased_rotation_rad + 1e-12);
    const int session_from = graph.vertex(link.from).session;
    const int session_to = graph.vertex(link.to).session;
    if (session_from == session_to) {
      CHECK(std::abs(position[link.from] - position[link.to]) >= 2);
    }
    sessions_joined.insert(session_from * 3 + session_to);
  }
  // Any sessions, as kRandom: 200 links over three sessions join more than one pair.
  CHECK(sessions_joined.size() > 3);

  std::vector<OutlierLink<TestType>> again;
  REQUIRE(MakeOutliers(graph, options, &again).ok());
  REQUIRE(again.size() == links.size());
  for (size_t k = 0; k < links.size(); ++k) {
    CHECK(again[k].from == links[k].from);
    CHECK(again[k].to == links[k].to);
    CHECK(SamePose(again[k].measurement, links[k].measurement));
  }
  options.seed = 6;
  std::vector<OutlierLink<TestType>> other;
  REQUIRE(MakeOutliers(graph, options, &other).ok());
  REQUIRE(other.size() == links.size());
  int different = 0;
  for (size_t k = 0; k < links.size(); ++k) {
    if (other[k].from != links[k].from || other[k].to != links[k].to ||
        !SamePose(other[k].measurement, links[k].measurement)) {
      ++different;
    }
  }
  CHECK(different > 0);

  // Tighter bounds are honoured; out-of-range bounds are refused.
  options.aliased_translation_m = 0.1;
  options.aliased_rotation_rad = 0.05;
  REQUIRE(MakeOutliers(graph, options, &other).ok());
  for (const OutlierLink<TestType>& link : other) {
    CHECK(link.measurement.translation().norm() <= 0.1);
    CHECK(RotationAngle(link.measurement) <= 0.05 + 1e-12);
  }
  options.aliased_rotation_rad = -0.1;
  CHECK_FALSE(MakeOutliers(graph, options, &other).ok());
  CHECK(other.size() == links.size());
}

TEMPLATE_TEST_CASE("Aliased groups agree with each other and with the dead reckoning",
                   "[outliers]",
                   Pose2,
                   Pose3) {
  const PoseGraph<TestType> graph = ThreeSessionGraph<TestType>(2);
  const std::vector<int> position = PositionsInSessions(graph);
  OutlierOptions options;
  options.mode = OutlierMode::kAliasedGrouped;
  options.count = 60;
  options.group_size = 4;
  options.seed = 9;
  INFO("seed " << options.seed);
  std::vector<OutlierLink<TestType>> links;
  REQUIRE(MakeOutliers(graph, options, &links).ok());
  REQUIRE(links.size() == 60);  // 15 groups of 4
  const int group = options.group_size;
  for (size_t g = 0; g < links.size() / group; ++g) {
    const OutlierLink<TestType>* first = &links[g * group];
    // The claim between the two places is small.
    CHECK(first->measurement.translation().norm() <= options.aliased_translation_m);
    CHECK(RotationAngle(first->measurement) <= options.aliased_rotation_rad + 1e-12);
    for (int m = 0; m < group; ++m) {
      const OutlierLink<TestType>& link = first[m];
      // Link m joins the m-th poses of two runs of consecutive poses.
      CHECK(graph.vertex(link.from).session == graph.vertex(first->from).session);
      CHECK(graph.vertex(link.to).session == graph.vertex(first->to).session);
      CHECK(position[link.from] == position[first->from] + m);
      CHECK(position[link.to] == position[first->to] + m);
      if (graph.vertex(link.from).session == graph.vertex(link.to).session) {
        CHECK(std::abs(position[link.from] - position[link.to]) >= 2 + group);
      }
    }
    // a_i -> b_i -> (odometry) b_j -> (link j reversed) a_j -> (odometry) a_i is the identity.
    for (int i = 0; i < group; ++i) {
      for (int j = 0; j < group; ++j) {
        if (i == j) continue;
        const OutlierLink<TestType>& li = first[i];
        const OutlierLink<TestType>& lj = first[j];
        const TestType cycle = li.measurement * AlongOdometry(graph, li.to, lj.to) *
                               lj.measurement.Inverse() * AlongOdometry(graph, lj.from, li.from);
        INFO("group " << g << " links " << i << ", " << j);
        CHECK(cycle.translation().norm() < kClosureTolerance);
        CHECK(RotationAngle(cycle) < kClosureTolerance);
      }
    }
  }
}

TEMPLATE_TEST_CASE("Noisy odometry is k times as noisy as its information says",
                   "[outliers]",
                   Pose2,
                   Pose3) {
  constexpr int kPosesPerSession = 2001;  // 4000 odometry edges in all
  constexpr double k = 2.0;
  // r' Omega r is chi2(dim) times k^2; its mean over 4000 edges has a relative standard deviation
  // sqrt(2 / (4000 dim)) (1.3% in 2D, 0.9% in 3D); 5% is 3.9 of them in 2D.
  constexpr double kMeanTolerance = 0.05;
  // Entries of the whitened sample covariance have standard deviations 0.016 to 0.022.
  constexpr double kCovarianceTolerance = 0.1;
  using Matrix = typename TestType::Matrix;
  using Tangent = typename TestType::Tangent;
  const GraphFile<TestType> clean = ChainFile<TestType>(kPosesPerSession);
  GraphFile<TestType> noisy = clean;
  const uint32_t seed = 3;
  INFO("seed " << seed);
  REQUIRE(PerturbOdometry(k, seed, &noisy).ok());
  REQUIRE(noisy.edges.size() == clean.edges.size());
  REQUIRE(noisy.vertices.size() == clean.vertices.size());

  PoseGraph<TestType> graph;
  std::vector<bool> odometry;
  ReadBack(clean, &graph, &odometry);
  const Matrix L = Covariance<TestType>().llt().matrixL();
  const Matrix L_inverse = L.inverse();
  double chi2_sum = 0.0;
  Matrix whitened_sum = Matrix::Zero();
  int num_odometry = 0;
  for (size_t e = 0; e < clean.edges.size(); ++e) {
    const FileEdge<TestType>& before = clean.edges[e];
    const FileEdge<TestType>& after = noisy.edges[e];
    CHECK(after.from == before.from);
    CHECK(after.to == before.to);
    CHECK(after.information == before.information);
    if (!odometry[e]) {
      CHECK(SamePose(after.measurement, before.measurement));
      continue;
    }
    const Tangent r = RelativePoseResidual<TestType>(
        after.measurement, TestType(), before.measurement, nullptr, nullptr);
    chi2_sum += r.dot(before.information * r);
    const Tangent w = L_inverse * r / k;
    whitened_sum += w * w.transpose();
    ++num_odometry;
  }
  REQUIRE(num_odometry == 2 * (kPosesPerSession - 1));
  const double mean_chi2 = chi2_sum / num_odometry;
  const double expected = k * k * TestType::kDim;
  CHECK(std::abs(mean_chi2 / expected - 1.0) < kMeanTolerance);
  const Matrix whitened_covariance = whitened_sum / num_odometry;
  CHECK((whitened_covariance - Matrix::Identity()).cwiseAbs().maxCoeff() < kCovarianceTolerance);

  // The first vertex of each session keeps its estimate; the rest follow the noisy odometry.
  RequireChainedEstimates(noisy);
  CHECK(SamePose(noisy.vertices[0].estimate, clean.vertices[0].estimate));
  CHECK(SamePose(noisy.vertices[kPosesPerSession].estimate,
                 clean.vertices[kPosesPerSession].estimate));
  CHECK_FALSE(SamePose(noisy.vertices[kPosesPerSession - 1].estimate,
                       clean.vertices[kPosesPerSession - 1].estimate));

  // Reproducible by seed, and a stream of its own per seed.
  GraphFile<TestType> again = clean;
  REQUIRE(PerturbOdometry(k, seed, &again).ok());
  GraphFile<TestType> other = clean;
  REQUIRE(PerturbOdometry(k, seed + 1, &other).ok());
  CHECK(SamePose(again.edges[5].measurement, noisy.edges[5].measurement));
  CHECK_FALSE(SamePose(other.edges[5].measurement, noisy.edges[5].measurement));

  // A factor that is not positive is refused and leaves the file as it was.
  GraphFile<TestType> untouched = clean;
  CHECK_FALSE(PerturbOdometry(0.0, seed, &untouched).ok());
  CHECK(SamePose(untouched.edges[5].measurement, clean.edges[5].measurement));
}

TEMPLATE_TEST_CASE("Odometry faults replace a few odometry measurements by wrong motions",
                   "[outliers]",
                   Pose2,
                   Pose3) {
  const GraphFile<TestType> clean = ChainFile<TestType>(300);
  PoseGraph<TestType> graph;
  std::vector<bool> odometry;
  ReadBack(clean, &graph, &odometry);
  constexpr int kFaults = 12;
  const uint32_t seed = 4;
  INFO("seed " << seed);
  GraphFile<TestType> faulty = clean;
  std::vector<int> faults;
  REQUIRE(InjectOdometryFaults(kFaults, seed, &faulty, &faults).ok());
  REQUIRE(static_cast<int>(faults.size()) == kFaults);
  CHECK(std::is_sorted(faults.begin(), faults.end()));
  CHECK(static_cast<int>(std::set<int>(faults.begin(), faults.end()).size()) == kFaults);

  std::vector<int> changed;
  std::set<int> sessions_hit;
  for (size_t e = 0; e < clean.edges.size(); ++e) {
    const FileEdge<TestType>& before = clean.edges[e];
    const FileEdge<TestType>& after = faulty.edges[e];
    CHECK(after.information == before.information);
    if (SamePose(after.measurement, before.measurement)) continue;
    changed.push_back(static_cast<int>(e));
    CHECK(odometry[e]);
    // The extra motion: 1-3 m horizontally (3D: up to 0.3 m in z), 0.3-1.0 rad.
    const TestType extra = before.measurement.Inverse() * after.measurement;
    CHECK(extra.translation().norm() >= 1.0 - 1e-9);
    CHECK(extra.translation().norm() <= std::hypot(3.0, 0.3) + 1e-9);
    CHECK(RotationAngle(extra) >= 0.3 - 1e-9);
    CHECK(RotationAngle(extra) <= 1.0 + 1e-9);
    sessions_hit.insert(graph.vertex(graph.FindVertex(before.to)).session);
  }
  CHECK(changed == faults);
  CHECK(sessions_hit.size() == 2);  // the sessions are taken in turn
  RequireChainedEstimates(faulty);

  GraphFile<TestType> again = clean;
  std::vector<int> faults_again;
  REQUIRE(InjectOdometryFaults(kFaults, seed, &again, &faults_again).ok());
  CHECK(faults_again == faults);
  for (int e : faults) CHECK(SamePose(again.edges[e].measurement, faulty.edges[e].measurement));
  GraphFile<TestType> other = clean;
  std::vector<int> faults_other;
  REQUIRE(InjectOdometryFaults(kFaults, seed + 1, &other, &faults_other).ok());
  CHECK(faults_other != faults);

  // More faults than odometry edges: refused, outputs untouched.
  GraphFile<TestType> untouched = clean;
  std::vector<int> kept = {7};
  CHECK_FALSE(InjectOdometryFaults(2 * 299 + 1, seed, &untouched, &kept).ok());
  CHECK(kept == std::vector<int>{7});
  CHECK(SamePose(untouched.vertices.back().estimate, clean.vertices.back().estimate));
}

}  // namespace
}  // namespace irrr
