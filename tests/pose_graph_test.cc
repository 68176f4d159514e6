#include "core/pose_graph.h"

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <catch2/catch.hpp>

namespace irrr {
namespace {

using Catch::Contains;

constexpr double kPi = M_PI;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
// Chaining a handful of unit-sized odometry steps rounds at ~1e-16 per step.
constexpr double kChainTolerance = 1e-12;
constexpr int kNumRandomInformationMatrices = 200;  // per dimension

// A pose with yaw about z (SE(3): also a small tilt so that all quaternion entries are used).
template <class Pose>
Pose MakePose(double x_m, double y_m, double yaw_rad);

template <>
Pose2 MakePose<Pose2>(double x_m, double y_m, double yaw_rad) {
  return Pose2(x_m, y_m, yaw_rad);
}

template <>
Pose3 MakePose<Pose3>(double x_m, double y_m, double yaw_rad) {
  const Eigen::Quaterniond q(Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()) *
                             Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitX()));
  return Pose3(q, Eigen::Vector3d(x_m, y_m, 0.25));
}

// A pose whose translation is NaN.
template <class Pose>
Pose NaNPose() {
  return MakePose<Pose>(kNaN, 0.0, 0.0);
}

template <class Pose>
typename Pose::Matrix Information() {
  return Pose::Matrix::Identity();
}

// Largest entry of the difference of rotation matrices and translations.
template <class Pose>
double PoseDifference(const Pose& a, const Pose& b) {
  return std::max((a.rotation() - b.rotation()).cwiseAbs().maxCoeff(),
                  (a.translation() - b.translation()).cwiseAbs().maxCoeff());
}

// A graph with one session (id 7) holding vertices 10 and 11 (indices 0 and 1) and a second
// session (id 8) holding vertex 20 (index 2): no loops, one odometry edge.
template <class Pose>
PoseGraph<Pose> SmallGraph() {
  PoseGraph<Pose> graph;
  const typename Pose::Matrix information = Information<Pose>();
  const Pose step = MakePose<Pose>(1.0, 0.0, 0.1);
  int index = -1;
  REQUIRE(graph.AddSession(7, &index).ok());
  REQUIRE(index == 0);
  REQUIRE(graph.AddSession(8, &index).ok());
  REQUIRE(index == 1);
  REQUIRE(graph.AddPose(0, 10, 1.0, Pose(), nullptr, nullptr, nullptr).ok());
  REQUIRE(graph.AddPose(0, 11, 2.0, step, &step, &information, nullptr).ok());
  REQUIRE(graph.AddPose(1, 20, 0.5, Pose(), nullptr, nullptr, nullptr).ok());
  return graph;
}

// Sizes of everything a mutator could touch.
struct GraphSize {
  int vertices;
  int edges;
  int sessions;
  std::vector<size_t> session_sizes;

  template <class Pose>
  explicit GraphSize(const PoseGraph<Pose>& graph)
      : vertices(graph.num_vertices()), edges(graph.num_edges()), sessions(graph.num_sessions()) {
    for (int s = 0; s < graph.num_sessions(); ++s) {
      session_sizes.push_back(graph.session(s).vertices.size());
    }
  }
  bool operator==(const GraphSize& o) const {
    return vertices == o.vertices && edges == o.edges && sessions == o.sessions &&
           session_sizes == o.session_sizes;
  }
};

// Requires a failed AddPose that names the vertex and the key words and leaves the graph as it
// was (counts, lookups, and the output index untouched).
template <class Pose>
void RequireAddPoseFails(PoseGraph<Pose>* graph,
                         int session,
                         int64_t vertex_id,
                         double stamp,
                         const Pose& initial_estimate,
                         const Pose* odometry,
                         const typename Pose::Matrix* odometry_information,
                         const std::vector<std::string>& key_words) {
  const GraphSize before(*graph);
  const int found_before = graph->FindVertex(vertex_id);
  int vertex_index = -123;
  const Status status = graph->AddPose(
      session, vertex_id, stamp, initial_estimate, odometry, odometry_information, &vertex_index);
  INFO("message: " << status.message());
  REQUIRE(!status.ok());
  CHECK_THAT(status.message(), Contains("vertex " + std::to_string(vertex_id)));
  for (const std::string& word : key_words) CHECK_THAT(status.message(), Contains(word));
  CHECK(GraphSize(*graph) == before);
  CHECK(graph->FindVertex(vertex_id) == found_before);
  CHECK(vertex_index == -123);
  CHECK(static_cast<int>(graph->initial_estimate().size()) == graph->num_vertices());
}

template <class Pose>
void RequireAddLoopFails(PoseGraph<Pose>* graph,
                         int from_vertex,
                         int to_vertex,
                         const Pose& measurement,
                         const typename Pose::Matrix& information,
                         const std::vector<std::string>& key_words) {
  const GraphSize before(*graph);
  int edge_index = -123;
  const Status status =
      graph->AddLoop(from_vertex, to_vertex, measurement, information, &edge_index);
  INFO("message: " << status.message());
  REQUIRE(!status.ok());
  for (const std::string& word : key_words) CHECK_THAT(status.message(), Contains(word));
  CHECK(GraphSize(*graph) == before);
  CHECK(edge_index == -123);
}

// ---- AddSession ----

TEMPLATE_TEST_CASE("AddSession rejects a duplicate id, naming it", "[pose_graph]", Pose2, Pose3) {
  PoseGraph<TestType> graph = SmallGraph<TestType>();
  const GraphSize before(graph);
  int index = -123;
  const Status status = graph.AddSession(8, &index);
  INFO("message: " << status.message());
  REQUIRE(!status.ok());
  CHECK_THAT(status.message(), Contains("session 8"));
  CHECK_THAT(status.message(), Contains("exists"));
  CHECK(GraphSize(graph) == before);
  CHECK(index == -123);
  CHECK(graph.FindSession(8) == 1);
}

// ---- AddPose ----

TEMPLATE_TEST_CASE(
    "AddPose rejects invalid input, naming the vertex, and leaves the graph unchanged",
    "[pose_graph]",
    Pose2,
    Pose3) {
  using Pose = TestType;
  using Matrix = typename Pose::Matrix;
  PoseGraph<Pose> graph = SmallGraph<Pose>();
  const Matrix information = Information<Pose>();
  const Pose step = MakePose<Pose>(1.0, 0.0, 0.1);

  SECTION("the first pose of a session with odometry") {
    int session = -1;
    REQUIRE(graph.AddSession(9, &session).ok());
    RequireAddPoseFails(
        &graph, session, 30, 0.0, Pose(), &step, &information, {"first pose", "odometry"});
  }
  SECTION("a later pose without odometry") {
    RequireAddPoseFails<Pose>(
        &graph, 0, 12, 3.0, step, nullptr, nullptr, {"missing odometry", "previous pose"});
  }
  SECTION("a later pose with odometry but without its information") {
    RequireAddPoseFails<Pose>(&graph, 0, 12, 3.0, step, &step, nullptr, {"missing odometry"});
  }
  SECTION("a duplicate vertex id, also in another session") {
    RequireAddPoseFails(&graph, 0, 11, 3.0, step, &step, &information, {"duplicate vertex id"});
    RequireAddPoseFails(&graph, 1, 10, 3.0, step, &step, &information, {"duplicate vertex id"});
  }
  SECTION("a stamp older than the session's previous pose") {
    RequireAddPoseFails(&graph, 0, 12, 1.5, step, &step, &information, {"stamp", "older"});
  }
  SECTION("a non-finite stamp") {
    RequireAddPoseFails(&graph, 0, 12, kNaN, step, &step, &information, {"stamp", "non-finite"});
  }
  SECTION("NaN in the initial estimate") {
    RequireAddPoseFails(&graph,
                        0,
                        12,
                        3.0,
                        NaNPose<Pose>(),
                        &step,
                        &information,
                        {"initial estimate", "non-finite"});
    // Also for the first pose of a session.
    int session = -1;
    REQUIRE(graph.AddSession(9, &session).ok());
    RequireAddPoseFails<Pose>(
        &graph, session, 30, 0.0, NaNPose<Pose>(), nullptr, nullptr, {"initial estimate"});
  }
  SECTION("NaN in the odometry measurement") {
    const Pose bad = NaNPose<Pose>();
    RequireAddPoseFails(&graph, 0, 12, 3.0, step, &bad, &information, {"odometry", "non-finite"});
  }
  SECTION("odometry information that is not positive definite") {
    Matrix indefinite = Matrix::Identity();
    indefinite(Pose::kDim - 1, Pose::kDim - 1) = -1.0;
    RequireAddPoseFails(
        &graph, 0, 12, 3.0, step, &step, &indefinite, {"odometry", "not positive definite"});
    const Matrix zero = Matrix::Zero();
    RequireAddPoseFails(
        &graph, 0, 12, 3.0, step, &step, &zero, {"odometry", "not positive definite"});
  }
  SECTION("asymmetric odometry information") {
    Matrix asymmetric = Matrix::Identity() * 2.0;
    asymmetric(0, 1) = 1.0;
    asymmetric(1, 0) = 0.5;
    RequireAddPoseFails(
        &graph, 0, 12, 3.0, step, &step, &asymmetric, {"odometry", "not symmetric"});
  }
  SECTION("odometry information with NaN or infinity") {
    Matrix with_nan = Matrix::Identity();
    with_nan(1, 1) = kNaN;
    RequireAddPoseFails(&graph, 0, 12, 3.0, step, &step, &with_nan, {"odometry", "non-finite"});
    Matrix with_inf = Matrix::Identity();
    with_inf(0, 1) = with_inf(1, 0) = std::numeric_limits<double>::infinity();
    RequireAddPoseFails(&graph, 0, 12, 3.0, step, &step, &with_inf, {"odometry", "non-finite"});
  }
  SECTION("an unknown session index") {
    RequireAddPoseFails<Pose>(
        &graph, 2, 12, 3.0, step, nullptr, nullptr, {"unknown session index 2"});
    RequireAddPoseFails<Pose>(
        &graph, -1, 12, 3.0, step, nullptr, nullptr, {"unknown session index -1"});
  }
  // After any of the failures the same vertex id can still be added correctly.
  const int session = graph.num_sessions() - 1;
  const bool first = graph.session(session).vertices.empty();
  int vertex_index = -1;
  const Status status = graph.AddPose(session,
                                      12,
                                      3.0,
                                      step,
                                      first ? nullptr : &step,
                                      first ? nullptr : &information,
                                      &vertex_index);
  INFO("message: " << status.message());
  CHECK(status.ok());
  CHECK(vertex_index == graph.num_vertices() - 1);
  CHECK(graph.FindVertex(12) == vertex_index);
}

TEST_CASE("AddPose rejects a Pose3 with a non-unit quaternion", "[pose_graph]") {
  PoseGraph<Pose3> graph = SmallGraph<Pose3>();
  const Pose3::Matrix information = Information<Pose3>();
  const Pose3 step = MakePose<Pose3>(1.0, 0.0, 0.1);
  const Pose3 not_a_rotation(Eigen::Quaterniond(2.0, 0.0, 0.0, 0.0), Eigen::Vector3d::Zero());
  RequireAddPoseFails(&graph,
                      0,
                      12,
                      3.0,
                      not_a_rotation,
                      &step,
                      &information,
                      {"initial estimate", "quaternion", "unit norm"});
  RequireAddPoseFails(&graph,
                      0,
                      12,
                      3.0,
                      step,
                      &not_a_rotation,
                      &information,
                      {"odometry", "quaternion", "unit norm"});
  // Rounding drift of a stored unit quaternion is accepted.
  const Eigen::Quaterniond drifted(1.0 + 1e-9, 0.0, 0.0, 0.0);
  CHECK(ValidatePose(Pose3(drifted, Eigen::Vector3d::Zero())).ok());
  CHECK(!ValidatePose(Pose3(Eigen::Quaterniond(0.0, 0.0, 0.0, 0.0), Eigen::Vector3d::Zero())).ok());
}

// ---- AddLoop ----

TEMPLATE_TEST_CASE(
    "AddLoop rejects invalid input, naming both vertices, and leaves the graph "
    "unchanged",
    "[pose_graph]",
    Pose2,
    Pose3) {
  using Pose = TestType;
  using Matrix = typename Pose::Matrix;
  PoseGraph<Pose> graph = SmallGraph<Pose>();
  const Matrix information = Information<Pose>();
  const Pose measurement = MakePose<Pose>(0.5, 0.5, -0.2);

  SECTION("an unknown vertex index") {
    RequireAddLoopFails(&graph, 0, 3, measurement, information, {"0 -> 3", "unknown vertex"});
    RequireAddLoopFails(&graph, 99, 1, measurement, information, {"99 -> 1", "unknown vertex"});
    RequireAddLoopFails(&graph, -1, 1, measurement, information, {"-1 -> 1", "unknown vertex"});
  }
  SECTION("a self-loop") {
    // Vertex index 1 has id 11.
    RequireAddLoopFails(&graph, 1, 1, measurement, information, {"vertex 11", "self-loop"});
  }
  SECTION("information that is not positive definite") {
    Matrix indefinite = Matrix::Identity();
    indefinite(2, 2) = -1.0;
    // Index 0 is vertex 10, index 2 is vertex 20.
    RequireAddLoopFails(
        &graph, 0, 2, measurement, indefinite, {"vertex 10", "vertex 20", "not positive definite"});
  }
  SECTION("asymmetric or non-finite information") {
    Matrix asymmetric = Matrix::Identity() * 2.0;
    asymmetric(0, 1) = 1.0;
    asymmetric(1, 0) = 0.5;
    RequireAddLoopFails(
        &graph, 2, 1, measurement, asymmetric, {"vertex 20", "vertex 11", "not symmetric"});
    Matrix with_nan = Matrix::Identity();
    with_nan(0, 0) = kNaN;
    RequireAddLoopFails(
        &graph, 2, 1, measurement, with_nan, {"vertex 20", "vertex 11", "non-finite"});
  }
  SECTION("a non-finite measurement") {
    RequireAddLoopFails(&graph,
                        0,
                        1,
                        NaNPose<Pose>(),
                        information,
                        {"vertex 10", "vertex 11", "measurement", "non-finite"});
  }
}

TEST_CASE("AddLoop rejects a Pose3 measurement with a non-unit quaternion", "[pose_graph]") {
  PoseGraph<Pose3> graph = SmallGraph<Pose3>();
  const Pose3 not_a_rotation(Eigen::Quaterniond(2.0, 0.0, 0.0, 0.0), Eigen::Vector3d::Zero());
  RequireAddLoopFails(&graph,
                      0,
                      2,
                      not_a_rotation,
                      Pose3::Matrix::Identity(),
                      {"vertex 10", "vertex 20", "measurement", "unit norm"});
}

// ---- Valid building ----

TEMPLATE_TEST_CASE(
    "A graph of two sessions with interleaved poses keeps sessions, edges and "
    "lookups consistent",
    "[pose_graph]",
    Pose2,
    Pose3) {
  using Pose = TestType;
  using Matrix = typename Pose::Matrix;
  PoseGraph<Pose> graph;
  int session_a = -1;
  int session_b = -1;
  REQUIRE(graph.AddSession(100, &session_a).ok());
  REQUIRE(graph.AddSession(200, &session_b).ok());
  REQUIRE(session_a == 0);
  REQUIRE(session_b == 1);

  // Vertex ids 1, 3, 5 go to session 100 and 2, 4 to session 200, in the order 1, 2, 3, 4, 5.
  // Stamps are ordered per session only (session 200 starts earlier than session 100's end).
  const int sessions[] = {session_a, session_b, session_a, session_b, session_a};
  const double stamps[] = {10.0, 5.0, 10.0, 6.0, 12.0};  // an equal stamp is allowed
  std::vector<Pose> odometry;
  std::vector<Matrix> informations;
  std::vector<Pose> initial;
  for (int i = 0; i < 5; ++i) {
    odometry.push_back(MakePose<Pose>(1.0 + i, -0.5 * i, 0.3 * i - 0.5));
    informations.push_back(Matrix::Identity() * (i + 1.0));
    initial.push_back(MakePose<Pose>(10.0 * i, 1.0, -0.2 * i));
  }
  for (int i = 0; i < 5; ++i) {
    const bool first = i < 2;
    int vertex_index = -1;
    const Status status = graph.AddPose(sessions[i],
                                        i + 1,
                                        stamps[i],
                                        initial[i],
                                        first ? nullptr : &odometry[i],
                                        first ? nullptr : &informations[i],
                                        &vertex_index);
    INFO("vertex " << i + 1 << ": " << status.message());
    REQUIRE(status.ok());
    CHECK(vertex_index == i);
  }
  REQUIRE(graph.num_sessions() == 2);
  REQUIRE(graph.num_vertices() == 5);
  REQUIRE(graph.num_edges() == 3);
  CHECK(graph.session(0).id == 100);
  CHECK(graph.session(1).id == 200);
  CHECK(graph.session(0).vertices == std::vector<int>{0, 2, 4});
  CHECK(graph.session(1).vertices == std::vector<int>{1, 3});
  for (int i = 0; i < 5; ++i) {
    INFO("vertex index " << i);
    CHECK(graph.vertex(i).id == i + 1);
    CHECK(graph.vertex(i).session == sessions[i]);
    CHECK(graph.vertex(i).stamp == stamps[i]);
    CHECK(graph.FindVertex(i + 1) == i);
    CHECK(PoseDifference(graph.initial_estimate()[i], initial[i]) == 0.0);
  }

  // Odometry edges in arrival order: 1 -> 3 (indices 0 -> 2), 2 -> 4 (1 -> 3), 3 -> 5 (2 -> 4).
  const int expected_from[] = {0, 1, 2};
  const int expected_to[] = {2, 3, 4};
  for (int e = 0; e < 3; ++e) {
    INFO("edge " << e);
    const Edge<Pose>& edge = graph.edge(e);
    CHECK(edge.kind == EdgeKind::kOdometry);
    CHECK(edge.from == expected_from[e]);
    CHECK(edge.to == expected_to[e]);
    CHECK(PoseDifference(edge.measurement, odometry[e + 2]) == 0.0);
    CHECK(edge.information == informations[e + 2]);
  }

  // Loops: within a session, across sessions, and a duplicate kept as a separate measurement.
  const Pose loop_measurement = MakePose<Pose>(0.1, 0.2, 0.3);
  const Matrix loop_information = Matrix::Identity() * 7.0;
  const int loops[][2] = {{4, 0}, {1, 4}, {1, 4}};
  for (int k = 0; k < 3; ++k) {
    int edge_index = -1;
    const Status status =
        graph.AddLoop(loops[k][0], loops[k][1], loop_measurement, loop_information, &edge_index);
    INFO("loop " << k << ": " << status.message());
    REQUIRE(status.ok());
    CHECK(edge_index == 3 + k);
    const Edge<Pose>& edge = graph.edge(edge_index);
    CHECK(edge.kind == EdgeKind::kLoop);
    CHECK(edge.from == loops[k][0]);
    CHECK(edge.to == loops[k][1]);
    CHECK(PoseDifference(edge.measurement, loop_measurement) == 0.0);
    CHECK(edge.information == loop_information);
  }
  // A pose after the loops still chains to its session's last pose (index 3, id 4).
  const Pose step = MakePose<Pose>(1.0, 0.0, 0.0);
  const Matrix information = Matrix::Identity();
  int vertex_index = -1;
  REQUIRE(graph.AddPose(session_b, 6, 7.0, step, &step, &information, &vertex_index).ok());
  CHECK(vertex_index == 5);
  CHECK(graph.session(1).vertices == std::vector<int>{1, 3, 5});
  REQUIRE(graph.num_edges() == 7);
  CHECK(graph.edge(6).kind == EdgeKind::kOdometry);
  CHECK(graph.edge(6).from == 3);
  CHECK(graph.edge(6).to == 5);
  CHECK(graph.edges().size() == 7);

  CHECK(graph.FindVertex(0) == -1);
  CHECK(graph.FindVertex(999) == -1);
  CHECK(graph.FindSession(100) == 0);
  CHECK(graph.FindSession(200) == 1);
  CHECK(graph.FindSession(0) == -1);
  CHECK(graph.FindSession(300) == -1);
}

TEST_CASE("An empty graph has nothing and finds nothing", "[pose_graph]") {
  const PoseGraph<Pose2> graph;
  CHECK(graph.num_vertices() == 0);
  CHECK(graph.num_edges() == 0);
  CHECK(graph.num_sessions() == 0);
  CHECK(graph.FindVertex(0) == -1);
  CHECK(graph.FindSession(0) == -1);
  CHECK(graph.OdometryEstimate().empty());
}

// ---- OdometryEstimate ----

TEST_CASE("OdometryEstimate chains SE(2) odometry from the identity per session, by hand",
          "[pose_graph]") {
  PoseGraph<Pose2> graph;
  const Pose2::Matrix information = Information<Pose2>();
  // Odometry (1, 0, pi/2) twice: (0, 0, 0) -> (1, 0, pi/2) -> (1, 1, pi).
  const Pose2 turn(1.0, 0.0, kPi / 2.0);
  // Initial estimates far from the dead reckoning, to show they are not used.
  const Pose2 elsewhere(50.0, -50.0, 1.0);
  REQUIRE(graph.AddSession(1, nullptr).ok());
  REQUIRE(graph.AddSession(2, nullptr).ok());
  REQUIRE(graph.AddPose(0, 1, 0.0, elsewhere, nullptr, nullptr, nullptr).ok());
  REQUIRE(graph.AddPose(1, 2, 0.0, elsewhere, nullptr, nullptr, nullptr).ok());
  REQUIRE(graph.AddPose(0, 3, 1.0, elsewhere, &turn, &information, nullptr).ok());
  REQUIRE(graph.AddLoop(2, 1, Pose2(3.0, 3.0, 3.0), information, nullptr).ok());
  REQUIRE(graph.AddPose(0, 4, 2.0, elsewhere, &turn, &information, nullptr).ok());
  // Session 2: a straight step of 2 m.
  const Pose2 straight(2.0, 0.0, 0.0);
  REQUIRE(graph.AddPose(1, 5, 1.0, elsewhere, &straight, &information, nullptr).ok());

  const std::vector<Pose2> estimate = graph.OdometryEstimate();
  REQUIRE(estimate.size() == 5);
  const Pose2 expected[] = {
      Pose2(0.0, 0.0, 0.0),
      Pose2(0.0, 0.0, 0.0),
      Pose2(1.0, 0.0, kPi / 2.0),
      Pose2(1.0, 1.0, kPi),
      Pose2(2.0, 0.0, 0.0),
  };
  for (int i = 0; i < 5; ++i) {
    INFO("vertex index " << i << ": " << estimate[i].ErrorVector().transpose());
    CHECK(PoseDifference(estimate[i], expected[i]) <= kChainTolerance);
  }
}

TEST_CASE("OdometryEstimate chains SE(3) odometry from the identity per session, by hand",
          "[pose_graph]") {
  PoseGraph<Pose3> graph;
  const Pose3::Matrix information = Information<Pose3>();
  // 90 degrees about z with a 1 m step along x, twice: -> (1, 0, 0) facing +y -> (1, 1, 0)
  // facing -x (180 degrees about z).
  const double h = std::sqrt(0.5);
  const Pose3 turn(Eigen::Quaterniond(h, 0.0, 0.0, h), Eigen::Vector3d(1.0, 0.0, 0.0));
  REQUIRE(graph.AddSession(1, nullptr).ok());
  REQUIRE(graph.AddPose(0, 1, 0.0, turn, nullptr, nullptr, nullptr).ok());
  REQUIRE(graph.AddPose(0, 2, 1.0, turn, &turn, &information, nullptr).ok());
  REQUIRE(graph.AddPose(0, 3, 2.0, turn, &turn, &information, nullptr).ok());
  const std::vector<Pose3> estimate = graph.OdometryEstimate();
  REQUIRE(estimate.size() == 3);
  const Pose3 expected[] = {
      Pose3(),
      turn,
      Pose3(Eigen::Quaterniond(0.0, 0.0, 0.0, 1.0), Eigen::Vector3d(1.0, 1.0, 0.0)),
  };
  for (int i = 0; i < 3; ++i) {
    INFO("vertex index " << i << ": " << estimate[i].ErrorVector().transpose());
    CHECK(PoseDifference(estimate[i], expected[i]) <= kChainTolerance);
  }
}

TEMPLATE_TEST_CASE("OdometryEstimate equals the product of each session's odometry",
                   "[pose_graph]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  const uint32_t seed = 31;
  INFO("seed " << seed << ", " << Pose::kName);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  std::uniform_int_distribution<int> pick_session(0, 2);
  const typename Pose::Matrix information = Pose::Matrix::Identity();
  PoseGraph<Pose> graph;
  for (int s = 0; s < 3; ++s) REQUIRE(graph.AddSession(s, nullptr).ok());
  std::vector<Pose> expected;
  std::vector<Pose> session_end(3);
  std::vector<bool> session_started(3, false);
  for (int i = 0; i < 60; ++i) {
    const int s = pick_session(rng);
    const Pose step = MakePose<Pose>(uniform(rng), uniform(rng), 3.0 * uniform(rng));
    const Pose* odometry = session_started[s] ? &step : nullptr;
    REQUIRE(
        graph.AddPose(s, i, i, step, odometry, odometry ? &information : nullptr, nullptr).ok());
    session_end[s] = session_started[s] ? Pose(session_end[s] * step) : Pose();
    session_started[s] = true;
    expected.push_back(session_end[s]);
    if (i > 2) {
      REQUIRE(graph.AddLoop(i, i / 2, step, information, nullptr).ok());
    }
  }
  const std::vector<Pose> estimate = graph.OdometryEstimate();
  REQUIRE(estimate.size() == expected.size());
  for (size_t i = 0; i < expected.size(); ++i) {
    INFO("vertex index " << i);
    CHECK(PoseDifference(estimate[i], expected[i]) <= kChainTolerance);
  }
}

// ---- ValidateInformation ----

template <int kDim>
Eigen::Matrix<double, kDim, kDim> RandomMatrix(std::mt19937& rng, int rows, int cols) {
  std::normal_distribution<double> normal(0.0, 1.0);
  Eigen::Matrix<double, kDim, kDim> m = Eigen::Matrix<double, kDim, kDim>::Zero();
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) m(r, c) = normal(rng);
  }
  return m;
}

TEMPLATE_TEST_CASE("ValidateInformation accepts random SPD matrices and rejects singular ones",
                   "[pose_graph]",
                   Pose2,
                   Pose3) {
  using Pose = TestType;
  using Matrix = typename Pose::Matrix;
  constexpr int kDim = Pose::kDim;
  const uint32_t seed = 41;
  INFO("seed " << seed << ", " << Pose::kName);
  std::mt19937 rng(seed);
  for (int i = 0; i < kNumRandomInformationMatrices; ++i) {
    INFO("case " << i);
    // A * A^T + I: symmetric with eigenvalues >= 1.
    const Matrix a = RandomMatrix<kDim>(rng, kDim, kDim);
    const Matrix spd = a * a.transpose() + Matrix::Identity();
    const Status status = ValidateInformation<Pose>(spd);
    INFO("message: " << status.message());
    CHECK(status.ok());
    // Scaled like real information matrices (1/sigma^2 from 1e-4 m to 1e2 rad).
    CHECK(ValidateInformation<Pose>(1e6 * spd).ok());
    CHECK(ValidateInformation<Pose>(1e-4 * spd).ok());

    // A * A^T with A of rank kDim / 2 (6x3, 3x1 columns filled, the rest zero): positive
    // semidefinite but singular.
    const Matrix b = RandomMatrix<kDim>(rng, kDim, kDim / 2);
    const Matrix singular = b * b.transpose();
    const Status singular_status = ValidateInformation<Pose>(singular);
    INFO("singular: " << singular_status.message());
    CHECK(!singular_status.ok());
    CHECK_THAT(singular_status.message(), Contains("not positive definite"));
  }
  // Asymmetry from printed decimals (relative 1e-12) is rounding, not an error.
  Matrix nearly_symmetric = Matrix::Identity() * 100.0;
  nearly_symmetric(0, 1) = 1.0;
  nearly_symmetric(1, 0) = 1.0 + 1e-10;
  CHECK(ValidateInformation<Pose>(nearly_symmetric).ok());
  nearly_symmetric(1, 0) = 1.1;
  CHECK(!ValidateInformation<Pose>(nearly_symmetric).ok());
  // Diagonal, badly scaled but definite (g2o files mix 1e-2 and 1e4).
  Matrix diagonal = Matrix::Identity();
  diagonal.diagonal().setLinSpaced(1e-2, 1e4);
  CHECK(ValidateInformation<Pose>(diagonal).ok());
  // The worst-conditioned information in the shared datasets (Intel, Carlone's copy) has a
  // smallest / largest eigenvalue ratio of 4e-12; a ratio of 1e-17 is rounding of a singular one.
  diagonal.diagonal().setConstant(1e4);
  diagonal(0, 0) = 4e-8;
  CHECK(ValidateInformation<Pose>(diagonal).ok());
  diagonal(0, 0) = 1e-13;
  CHECK(!ValidateInformation<Pose>(diagonal).ok());
}

}  // namespace
}  // namespace irrr
