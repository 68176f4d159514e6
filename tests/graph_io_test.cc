// Reading, writing and building pose graphs from g2o / TORO text: exact values, round trips,
// one error case per kind of malformed input, and the session / loop inference of BuildPoseGraph.

#include "core/graph_io.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <type_traits>
#include <vector>

#include <catch2/catch.hpp>

namespace irrr {
namespace {

template <class Pose>
Status ReadText(const std::string& text,
                GraphFile<Pose>* file,
                FileFormat format = FileFormat::kG2o,
                const ReadOptions& options = ReadOptions()) {
  std::istringstream in(text);
  return ReadGraphFile(in, format, options, file);
}

// Reads text that must fail and returns the message; also checks that the output keeps what it
// held before the call.
template <class Pose = Pose2>
std::string ReadError(const std::string& text,
                      FileFormat format = FileFormat::kG2o,
                      const ReadOptions& options = ReadOptions()) {
  GraphFile<Pose> file;
  file.vertices.push_back(FileVertex<Pose>{12345, Pose(), 77});
  const Status status = ReadText(text, &file, format, options);
  REQUIRE_FALSE(status.ok());
  REQUIRE(file.vertices.size() == 1);
  CHECK(file.vertices[0].id == 12345);
  CHECK(file.vertices[0].line == 77);
  CHECK(file.edges.empty());
  return status.message();
}

std::string DetectError(const std::string& text) {
  std::istringstream in(text);
  FileFormat format = FileFormat::kG2o;
  int dimension = 0;
  const Status status = DetectGraphFile(in, &format, &dimension);
  REQUIRE_FALSE(status.ok());
  return status.message();
}

template <class Pose>
bool SamePose(const Pose& a, const Pose& b) {
  if constexpr (std::is_same_v<Pose, Pose2>) {
    return a.translation() == b.translation() && a.yaw_rad() == b.yaw_rad();
  } else {
    return a.translation() == b.translation() && a.quaternion().coeffs() == b.quaternion().coeffs();
  }
}

template <class Pose>
Pose RandomPose(std::mt19937* rng) {
  std::uniform_real_distribution<double> coordinate(-100.0, 100.0);
  if constexpr (std::is_same_v<Pose, Pose2>) {
    std::uniform_real_distribution<double> yaw(-M_PI, M_PI);
    return Pose2(coordinate(*rng), coordinate(*rng), yaw(*rng));
  } else {
    std::normal_distribution<double> normal;
    Eigen::Quaterniond q(normal(*rng), normal(*rng), normal(*rng), normal(*rng));
    q.normalize();
    return Pose3(q, Eigen::Vector3d(coordinate(*rng), coordinate(*rng), coordinate(*rng)));
  }
}

// Symmetric positive definite: A * A' + n * I, mirrored from the upper triangle so that it is
// exactly what a file (which stores only that triangle) gives back.
template <class Pose>
typename Pose::Matrix RandomInformation(std::mt19937* rng) {
  using Matrix = typename Pose::Matrix;
  std::uniform_real_distribution<double> entry(-1.0, 1.0);
  Matrix a;
  for (int k = 0; k < a.size(); ++k) a(k) = entry(*rng);
  Matrix m = a * a.transpose() + Pose::kDim * Matrix::Identity();
  for (int r = 0; r < Pose::kDim; ++r) {
    for (int c = 0; c < r; ++c) m(r, c) = m(c, r);
  }
  return m;
}

template <class Pose>
GraphFile<Pose> RandomFile(uint32_t seed, bool with_vertices) {
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int64_t> any_id(std::numeric_limits<int64_t>::min(),
                                                std::numeric_limits<int64_t>::max());
  std::set<int64_t> unique;
  while (unique.size() < 20) unique.insert(any_id(rng));
  std::vector<int64_t> ids(unique.begin(), unique.end());
  std::shuffle(ids.begin(), ids.end(), rng);

  GraphFile<Pose> file;
  if (with_vertices) {
    for (const int64_t id : ids)
      file.vertices.push_back(FileVertex<Pose>{id, RandomPose<Pose>(&rng), 0});
  }
  std::uniform_int_distribution<int> pick(0, static_cast<int>(ids.size()) - 1);
  for (int k = 0; k < 40; ++k) {
    const int from = pick(rng);
    int to = pick(rng);
    while (to == from) to = pick(rng);
    FileEdge<Pose> edge;
    edge.from = ids[from];
    edge.to = ids[to];
    edge.measurement = RandomPose<Pose>(&rng);
    edge.information = RandomInformation<Pose>(&rng);
    file.edges.push_back(edge);
  }
  return file;
}

template <class Pose>
void CheckRoundTrip(FileFormat format, uint32_t seed, bool with_vertices) {
  const GraphFile<Pose> original = RandomFile<Pose>(seed, with_vertices);
  std::ostringstream first;
  REQUIRE(WriteGraphFile(first, format, original).ok());

  GraphFile<Pose> read;
  const Status status = ReadText(first.str(), &read, format);
  INFO(status.message());
  REQUIRE(status.ok());
  REQUIRE(read.vertices.size() == original.vertices.size());
  REQUIRE(read.edges.size() == original.edges.size());
  for (size_t k = 0; k < read.vertices.size(); ++k) {
    CHECK(read.vertices[k].id == original.vertices[k].id);
    CHECK(read.vertices[k].line == static_cast<int>(k) + 1);
    CHECK(SamePose(read.vertices[k].estimate, original.vertices[k].estimate));
  }
  for (size_t k = 0; k < read.edges.size(); ++k) {
    CHECK(read.edges[k].from == original.edges[k].from);
    CHECK(read.edges[k].to == original.edges[k].to);
    CHECK(SamePose(read.edges[k].measurement, original.edges[k].measurement));
    CHECK(read.edges[k].information == original.edges[k].information);
  }

  std::ostringstream second;
  REQUIRE(WriteGraphFile(second, format, read).ok());
  CHECK(second.str() == first.str());
}

template <class Pose>
FileEdge<Pose> MakeEdge(int64_t from, int64_t to, const Pose& measurement, int line) {
  FileEdge<Pose> edge;
  edge.from = from;
  edge.to = to;
  edge.measurement = measurement;
  edge.line = line;
  return edge;
}

const char* const kEdgeInformation2 = " 10 0 0 10 0 10";  // g2o upper triangle of 10 * I

TEST_CASE("A small g2o 2D file reads with its exact values and full information", "[graph_io]") {
  const std::string text =
      "# a comment\n"
      "VERTEX_SE2 0 0 0 0\n"
      "  VERTEX_SE2 1 1.5 -2 0.25\n"
      "FIX 0\n"
      "\n"
      "EDGE_SE2 0 1 1.5 -2.5 0.125 10 1 2 20 3 30\n"
      "VERTEX_SE2 6989586621679009792 3 4 4.0\n";
  GraphFile<Pose2> file;
  const Status status = ReadText(text, &file);
  INFO(status.message());
  REQUIRE(status.ok());

  REQUIRE(file.vertices.size() == 3);
  CHECK(file.vertices[1].id == 1);
  CHECK(file.vertices[1].line == 3);
  CHECK(file.vertices[1].estimate.translation() == Eigen::Vector2d(1.5, -2.0));
  CHECK(file.vertices[1].estimate.yaw_rad() == 0.25);
  CHECK(file.vertices[2].id == 6989586621679009792);
  CHECK(file.vertices[2].estimate.yaw_rad() == Approx(4.0 - 2.0 * M_PI));  // wrapped

  REQUIRE(file.edges.size() == 1);
  const FileEdge<Pose2>& edge = file.edges[0];
  CHECK(edge.from == 0);
  CHECK(edge.to == 1);
  CHECK(edge.line == 6);
  CHECK(edge.measurement.translation() == Eigen::Vector2d(1.5, -2.5));
  CHECK(edge.measurement.yaw_rad() == 0.125);
  Eigen::Matrix3d expected;
  expected << 10, 1, 2,  //
      1, 20, 3,          //
      2, 3, 30;
  CHECK(edge.information == expected);
}

TEST_CASE("A g2o 3D file reads quaternions as qx qy qz qw and 21 information entries",
          "[graph_io]") {
  // Entry k (0-based, upper triangle row by row) is 100 + k on the diagonal and k / 100 off it.
  std::ostringstream information;
  int k = 0;
  for (int r = 0; r < 6; ++r) {
    for (int c = r; c < 6; ++c, ++k) information << ' ' << (r == c ? 100.0 + k : k / 100.0);
  }
  const std::string text =
      "VERTEX_SE3:QUAT 0 1 2 3 0.5 -0.5 0.5 0.5\n"
      "VERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n"
      "EDGE_SE3:QUAT 0 1 4 5 6 0.1 0.2 0.3 0.9273618495495703" +
      information.str() + "\n";
  GraphFile<Pose3> file;
  const Status status = ReadText(text, &file);
  INFO(status.message());
  REQUIRE(status.ok());

  REQUIRE(file.vertices.size() == 2);
  const Eigen::Quaterniond& q0 = file.vertices[0].estimate.quaternion();
  CHECK(file.vertices[0].estimate.translation() == Eigen::Vector3d(1, 2, 3));
  CHECK(q0.x() == 0.5);
  CHECK(q0.y() == -0.5);
  CHECK(q0.z() == 0.5);
  CHECK(q0.w() == 0.5);

  REQUIRE(file.edges.size() == 1);
  const FileEdge<Pose3>& edge = file.edges[0];
  CHECK(edge.measurement.translation() == Eigen::Vector3d(4, 5, 6));
  const Eigen::Quaterniond& q = edge.measurement.quaternion();
  CHECK(q.x() == Approx(0.1).epsilon(1e-12));
  CHECK(q.y() == Approx(0.2).epsilon(1e-12));
  CHECK(q.z() == Approx(0.3).epsilon(1e-12));
  CHECK(q.w() == Approx(0.9273618495495703).epsilon(1e-12));

  const Pose3::Matrix& m = edge.information;
  CHECK(m(0, 0) == 100.0);
  CHECK(m(0, 1) == 0.01);
  CHECK(m(1, 0) == 0.01);
  CHECK(m(0, 5) == 0.05);
  CHECK(m(1, 1) == 106.0);  // entry #7 (0-based 6) opens row 1
  CHECK(m(1, 2) == 0.07);
  CHECK(m(2, 5) == 0.14);
  CHECK(m(5, 2) == 0.14);
  CHECK(m(4, 5) == 0.19);
  CHECK(m(5, 5) == 120.0);
  CHECK(m == m.transpose());
}

TEST_CASE("TORO information order xx xy yy tt xt yt maps to x, y, theta", "[graph_io]") {
  const std::string text = "VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 100 2 300 400 5 6\n";
  GraphFile<Pose2> file;
  const Status status = ReadText(text, &file, FileFormat::kToro);
  INFO(status.message());
  REQUIRE(status.ok());
  REQUIRE(file.edges.size() == 1);
  Eigen::Matrix3d expected;
  expected << 100, 2, 5,  //
      2, 300, 6,          //
      5, 6, 400;
  CHECK(file.edges[0].information == expected);

  std::ostringstream out;
  REQUIRE(WriteGraphFile(out, FileFormat::kToro, file).ok());
  CHECK(out.str() == "VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\nEDGE2 0 1 1 0 0 100 2 300 400 5 6\n");
}

TEST_CASE("Random graphs survive write -> read exactly and write -> read -> write byte for byte",
          "[graph_io]") {
  const bool with_vertices = GENERATE(true, false);
  const uint32_t seed = GENERATE(1u, 2u, 3u);
  INFO("seed " << seed << (with_vertices ? ", with vertices" : ", edges only"));
  SECTION("g2o 2D") { CheckRoundTrip<Pose2>(FileFormat::kG2o, seed, with_vertices); }
  SECTION("g2o 3D") { CheckRoundTrip<Pose3>(FileFormat::kG2o, seed, with_vertices); }
  SECTION("TORO 2D") { CheckRoundTrip<Pose2>(FileFormat::kToro, seed, with_vertices); }
}

TEST_CASE("A quaternion slightly off unit norm is accepted and normalized", "[graph_io]") {
  GraphFile<Pose3> file;
  REQUIRE(ReadText("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1.0005\n", &file).ok());
  CHECK(file.vertices[0].estimate.quaternion().w() == 1.0);
}

TEST_CASE("Malformed input fails naming the line and leaves the output untouched", "[graph_io]") {
  const std::string v01 = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n";
  using Catch::Matchers::Contains;

  SECTION("unknown tag") {
    CHECK_THAT(ReadError(v01 + "EQUIV 0 1\n"),
               Contains("line 3: ") && Contains("unknown tag") && Contains("EQUIV"));
  }
  SECTION("unknown tag skipped when asked") {
    ReadOptions options;
    options.skip_unknown_tags = true;
    GraphFile<Pose2> file;
    REQUIRE(ReadText(v01 + "EQUIV 0 1\nVERTEX_XY 5 1 2\n", &file, FileFormat::kG2o, options).ok());
    CHECK(file.vertices.size() == 2);
    CHECK(file.edges.empty());
  }
  SECTION("too few numbers") {
    CHECK_THAT(ReadError(v01 + "EDGE_SE2 0 1 1 0 0 1 0 0 1\n"),
               Contains("line 3: EDGE_SE2 expects 11 numbers after the tag, found 9"));
  }
  SECTION("too many numbers") {
    CHECK_THAT(ReadError("VERTEX_SE2 0 0 0 0 7\n"),
               Contains("line 1: VERTEX_SE2 expects 4 numbers after the tag, found 5"));
  }
  SECTION("non-numeric token") {
    CHECK_THAT(ReadError(v01 + "VERTEX_SE2 2 1.5x 0 0\n"),
               Contains("line 3: ") && Contains("'1.5x' is not a number"));
  }
  SECTION("non-integer id") {
    CHECK_THAT(ReadError("VERTEX_SE2 1.5 0 0 0\n"),
               Contains("line 1: ") && Contains("'1.5' is not a 64-bit integer id"));
  }
  SECTION("id beyond 64 bits") {
    CHECK_THAT(ReadError("VERTEX_SE2 9223372036854775808 0 0 0\n"),
               Contains("line 1: ") && Contains("out of range"));
  }
  SECTION("FIX without an integer") {
    CHECK_THAT(ReadError(v01 + "FIX zero\n"), Contains("line 3: FIX") && Contains("'zero'"));
  }
  SECTION("NaN in a measurement") {
    CHECK_THAT(ReadError(v01 + "EDGE_SE2 0 1 nan 0 0" + kEdgeInformation2 + "\n"),
               Contains("line 3: EDGE_SE2 0 1: measurement has a non-finite number 'nan'"));
  }
  SECTION("inf in information") {
    CHECK_THAT(ReadError(v01 + "EDGE_SE2 0 1 1 0 0 10 0 0 inf 0 10\n"),
               Contains("line 3: EDGE_SE2 0 1: information has a non-finite number 'inf'"));
  }
  SECTION("non-unit quaternion") {
    CHECK_THAT(ReadError<Pose3>("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1.01\n"),
               Contains("line 1: ") && Contains("quaternion norm 1.01 is not 1"));
  }
  SECTION("information not positive definite") {
    CHECK_THAT(ReadError(v01 + "EDGE_SE2 0 1 1 0 0 10 0 0 -2 0 10\n"),
               Contains("line 3: ") && Contains("not positive definite") &&
                   Contains("smallest eigenvalue -2"));
  }
  SECTION("duplicate vertex id") {
    CHECK_THAT(ReadError("# header\nVERTEX_SE2 7 0 0 0\nVERTEX_SE2 7 1 0 0\n"),
               Contains("line 3: duplicate vertex id 7 (first on line 2)"));
  }
  SECTION("edge to an undeclared vertex") {
    CHECK_THAT(
        ReadError(v01 + "EDGE_SE2 5 99 1 0 0" + kEdgeInformation2 + "\n" + "VERTEX_SE2 5 0 0 0\n"),
        Contains("line 3: edge 5 -> 99: vertex 99 is not declared"));
  }
  SECTION("self-loop") {
    CHECK_THAT(ReadError("VERTEX_SE2 4 0 0 0\nEDGE_SE2 4 4 1 0 0" + std::string(kEdgeInformation2)),
               Contains("line 2: EDGE_SE2 4 4: self-loop"));
  }
  SECTION("3D tag while reading 2D") {
    CHECK_THAT(ReadError(v01 + "VERTEX_SE3:QUAT 2 0 0 0 0 0 0 1\n"),
               Contains("line 3: VERTEX_SE3:QUAT is a g2o 3D tag"));
  }
  SECTION("g2o tag while reading TORO") {
    CHECK_THAT(ReadError(v01, FileFormat::kToro), Contains("line 1: VERTEX_SE2 is a g2o 2D tag"));
  }
  SECTION("TORO requested for 3D") {
    CHECK_THAT(ReadError<Pose3>("VERTEX2 0 0 0 0\n", FileFormat::kToro),
               Contains("TORO") && Contains("2D"));
    GraphFile<Pose3> file;
    file.vertices.push_back(FileVertex<Pose3>{1, Pose3(), 0});
    std::ostringstream out;
    const Status status = WriteGraphFile(out, FileFormat::kToro, file);
    CHECK_FALSE(status.ok());
    CHECK_THAT(status.message(), Contains("TORO"));
    CHECK(out.str().empty());
  }
  SECTION("empty input for DetectGraphFile") {
    CHECK_THAT(DetectError(""), Contains("empty"));
    CHECK_THAT(DetectError("# only a comment\n\n"), Contains("empty"));
  }
  SECTION("unknown first tag for DetectGraphFile") {
    CHECK_THAT(DetectError("# comment\nEDGE3 0 1 0 0 0 0 0 0\n"),
               Contains("line 2: unknown tag 'EDGE3'"));
  }
}

TEST_CASE("skip_invalid_edges leaves out each invalid edge line, names it, and keeps the rest",
          "[graph_io]") {
  using Catch::Matchers::Contains;
  const std::string info = kEdgeInformation2;
  const std::string text = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nVERTEX_SE2 2 2 0 0\n" +
                           ("EDGE_SE2 0 1 1 0 0" + info + "\n") +       // line 4: kept
                           ("EDGE_SE2 1 1 0.1 0 0" + info + "\n") +     // 5: self-loop
                           "EDGE_SE2 1 2 1 0 0 10 0 0 -2 0 10\n" +      // 6: not positive definite
                           ("EDGE_SE2 2 7 1 0 0" + info + "\n") +       // 7: vertex 7 undeclared
                           ("EDGE_SE2 1 2 nan 0 0" + info + "\n") +     // 8: non-finite
                           ("EDGE_SE2 1 2 0.9 0.1 0.2" + info + "\n");  // 9: kept
  ReadOptions options;
  options.skip_invalid_edges = true;
  GraphFile<Pose2> file;
  REQUIRE(ReadText(text, &file, FileFormat::kG2o, options).ok());
  REQUIRE(file.edges.size() == 2);
  CHECK(file.edges[0].line == 4);
  CHECK(file.edges[1].line == 9);
  CHECK(file.edges[1].measurement.translation().x() == 0.9);
  REQUIRE(file.skipped.size() == 4);
  CHECK(file.skipped[0].line == 5);
  CHECK_THAT(file.skipped[0].message, Contains("line 5: EDGE_SE2 1 1: self-loop"));
  CHECK(file.skipped[1].line == 6);
  CHECK_THAT(file.skipped[1].message, Contains("line 6: ") && Contains("not positive definite"));
  CHECK(file.skipped[2].line == 7);
  CHECK_THAT(file.skipped[2].message, Contains("line 7: edge 2 -> 7: vertex 7 is not declared"));
  CHECK(file.skipped[3].line == 8);
  CHECK_THAT(file.skipped[3].message, Contains("line 8: ") && Contains("non-finite number 'nan'"));

  // Without the option the first of them is the error, as before.
  CHECK_THAT(ReadError(text), Contains("line 5: EDGE_SE2 1 1: self-loop"));
  // Only edges are skipped: a malformed line or a bad vertex still fails the read.
  CHECK_THAT(ReadError(text + "EDGE_SE2 0 1 1 0 0\n", FileFormat::kG2o, options),
             Contains("line 10: EDGE_SE2 expects 11 numbers"));
  CHECK_THAT(ReadError(text + "VERTEX_SE2 3 nan 0 0\n", FileFormat::kG2o, options),
             Contains("line 10: VERTEX_SE2 3: estimate has a non-finite number 'nan'"));
}

TEST_CASE("DetectGraphFile recognizes each format after comments", "[graph_io]") {
  struct Case {
    const char* text;
    FileFormat format;
    int dimension;
  };
  const Case c =
      GENERATE(Case{"# g2o\n\nFIX 0\nVERTEX_SE2 0 0 0 0\n", FileFormat::kG2o, 2},
               Case{"  # edges only\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\n", FileFormat::kG2o, 2},
               Case{"#\nVERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n", FileFormat::kG2o, 3},
               Case{"# space\nEDGE_SE3:QUAT 0 1\n", FileFormat::kG2o, 3},
               Case{"#SEQUENTIAL EDGES\r\nVERTEX2 0 0 0 0\r\n", FileFormat::kToro, 2},
               Case{"\n\nEDGE2 1 0 1 0 0 1 0 1 1 0 0\n", FileFormat::kToro, 2});
  INFO(c.text);
  std::istringstream in(c.text);
  FileFormat format = c.format == FileFormat::kG2o ? FileFormat::kToro : FileFormat::kG2o;
  int dimension = 0;
  REQUIRE(DetectGraphFile(in, &format, &dimension).ok());
  CHECK(format == c.format);
  CHECK(dimension == c.dimension);
}

TEST_CASE("BuildPoseGraph starts a session at every missing odometry edge", "[graph_io]") {
  // Vertices 100..109 declared out of order; odometry (104, 105) is missing.
  GraphFile<Pose2> file;
  for (const int64_t id : {105, 100, 101, 102, 103, 104, 109, 106, 107, 108}) {
    file.vertices.push_back(FileVertex<Pose2>{id, Pose2(static_cast<double>(id), 0, 0), 0});
  }
  for (int64_t id = 100; id < 109; ++id) {
    if (id != 104) file.edges.push_back(MakeEdge(id, id + 1, Pose2(1, 0, 0), 0));
  }
  PoseGraph<Pose2> graph;
  std::vector<int> edge_of;
  const Status status = BuildPoseGraph(file, &graph, &edge_of);
  INFO(status.message());
  REQUIRE(status.ok());

  REQUIRE(graph.num_vertices() == 10);
  REQUIRE(graph.num_sessions() == 2);
  CHECK(graph.session(0).id == 0);
  CHECK(graph.session(1).id == 1);
  for (int s = 0; s < 2; ++s) {
    REQUIRE(graph.session(s).vertices.size() == 5);
    for (int k = 0; k < 5; ++k) {
      const Vertex& v = graph.vertex(graph.session(s).vertices[k]);
      CHECK(v.id == 100 + 5 * s + k);
      CHECK(v.session == s);
      CHECK(v.stamp == 5.0 * s + k);  // the ordinal in id order
      CHECK(graph.initial_estimate()[graph.session(s).vertices[k]].translation().x() == v.id);
    }
  }
  CHECK(graph.num_edges() == 8);
  for (const Edge<Pose2>& e : graph.edges()) CHECK(e.kind == EdgeKind::kOdometry);
}

TEST_CASE("BuildPoseGraph turns duplicate and reversed odometry into loops in file order",
          "[graph_io]") {
  GraphFile<Pose2> file;
  for (int64_t id = 0; id < 10; ++id) file.vertices.push_back(FileVertex<Pose2>{id, Pose2(), 0});
  file.edges.push_back(MakeEdge<Pose2>(2, 8, Pose2(0, 0, 0.5), 1));  // loop before the odometry
  for (int64_t id = 8; id >= 0; --id) {                              // odometry in reverse order
    file.edges.push_back(MakeEdge(id, id + 1, Pose2(1, 0, 0), 0));
  }
  file.edges.push_back(MakeEdge<Pose2>(3, 4, Pose2(2, 0, 0), 2));   // second (3, 4): a loop
  file.edges.push_back(MakeEdge<Pose2>(7, 6, Pose2(-1, 0, 0), 3));  // reversed: a loop
  file.edges.push_back(MakeEdge<Pose2>(9, 0, Pose2(0, 1, 0), 4));

  PoseGraph<Pose2> graph;
  std::vector<int> edge_of;
  const Status status = BuildPoseGraph(file, &graph, &edge_of);
  INFO(status.message());
  REQUIRE(status.ok());
  REQUIRE(graph.num_sessions() == 1);
  REQUIRE(graph.num_edges() == 13);

  // Odometry edges are created with their poses: vertex i's odometry is graph edge i - 1.
  const std::vector<int> expected = {9, 8, 7, 6, 5, 4, 3, 2, 1, 0, 10, 11, 12};
  CHECK(edge_of == expected);
  for (int k = 1; k <= 9; ++k) CHECK(graph.edge(edge_of[k]).kind == EdgeKind::kOdometry);

  const int64_t loops[4][2] = {{2, 8}, {3, 4}, {7, 6}, {9, 0}};
  for (int k = 0; k < 4; ++k) {
    const Edge<Pose2>& e = graph.edge(9 + k);
    CHECK(e.kind == EdgeKind::kLoop);
    CHECK(graph.vertex(e.from).id == loops[k][0]);
    CHECK(graph.vertex(e.to).id == loops[k][1]);
  }
  // File edge 6 is the first (3, 4), the odometry; file edge 10 the second, a loop.
  CHECK(graph.edge(edge_of[6]).kind == EdgeKind::kOdometry);
  CHECK(graph.edge(edge_of[6]).measurement.translation().x() == 1.0);
  CHECK(graph.edge(edge_of[10]).measurement.translation().x() == 2.0);
}

TEST_CASE("BuildPoseGraph chains an edges-only file from the identity per session", "[graph_io]") {
  std::mt19937 rng(7);
  const Pose3 m01 = RandomPose<Pose3>(&rng);
  const Pose3 m12 = RandomPose<Pose3>(&rng);
  const Pose3 m23 = RandomPose<Pose3>(&rng);
  const Pose3 m_10_11 = RandomPose<Pose3>(&rng);
  GraphFile<Pose3> file;
  file.edges.push_back(MakeEdge<Pose3>(3, 10, RandomPose<Pose3>(&rng), 1));
  file.edges.push_back(MakeEdge(2, 3, m23, 2));
  file.edges.push_back(MakeEdge(0, 1, m01, 3));
  file.edges.push_back(MakeEdge(10, 11, m_10_11, 4));
  file.edges.push_back(MakeEdge(1, 2, m12, 5));

  PoseGraph<Pose3> graph;
  std::vector<int> edge_of;
  const Status status = BuildPoseGraph(file, &graph, &edge_of);
  INFO(status.message());
  REQUIRE(status.ok());
  REQUIRE(graph.num_vertices() == 6);
  REQUIRE(graph.num_sessions() == 2);
  CHECK(edge_of == std::vector<int>{4, 2, 0, 3, 1});

  const std::vector<Pose3>& estimate = graph.initial_estimate();
  const auto near = [](const Pose3& a, const Pose3& b) {
    return (a.translation() - b.translation()).norm() < 1e-9 &&
           a.quaternion().angularDistance(b.quaternion()) < 1e-12;
  };
  CHECK(near(estimate[graph.FindVertex(0)], Pose3()));
  CHECK(near(estimate[graph.FindVertex(3)], m01 * m12 * m23));
  CHECK(near(estimate[graph.FindVertex(10)], Pose3()));
  CHECK(near(estimate[graph.FindVertex(11)], m_10_11));
  CHECK(graph.vertex(graph.FindVertex(10)).stamp == 4.0);
}

TEST_CASE("BuildPoseGraph errors name the line and leave the graph empty", "[graph_io]") {
  GraphFile<Pose2> file;
  for (int64_t id = 0; id < 4; ++id) {
    file.vertices.push_back(FileVertex<Pose2>{id, Pose2(), static_cast<int>(id) + 1});
  }
  for (int64_t id = 0; id < 3; ++id) {
    file.edges.push_back(MakeEdge(id, id + 1, Pose2(1, 0, 0), static_cast<int>(id) + 5));
  }
  using Catch::Matchers::Contains;
  std::string expected;
  SECTION("bad odometry information") {
    file.edges[1].information(1, 1) = -2.0;
    expected = "line 6: ";
  }
  SECTION("self-loop") {
    file.edges.push_back(MakeEdge<Pose2>(2, 2, Pose2(), 9));
    expected = "line 9: ";
  }
  SECTION("bad loop information") {
    file.edges.push_back(MakeEdge<Pose2>(3, 0, Pose2(), 9));
    file.edges.back().information(0, 0) = 0.0;
    expected = "line 9: ";
  }
  SECTION("undeclared endpoint") {
    file.edges.push_back(MakeEdge<Pose2>(3, 42, Pose2(), 9));
    expected = "line 9: edge 3 -> 42: vertex 42 is not declared";
  }
  SECTION("duplicate vertex") {
    file.vertices.push_back(FileVertex<Pose2>{2, Pose2(), 9});
    expected = "line 9: duplicate vertex id 2 (first on line 3)";
  }
  PoseGraph<Pose2> graph;
  std::vector<int> edge_of = {-7};
  const Status status = BuildPoseGraph(file, &graph, &edge_of);
  REQUIRE_FALSE(status.ok());
  CHECK_THAT(status.message(), Catch::Matchers::StartsWith(expected));
  CHECK(graph.num_vertices() == 0);
  CHECK(graph.num_edges() == 0);
  CHECK(graph.num_sessions() == 0);
  CHECK(edge_of == std::vector<int>{-7});
}

TEST_CASE("WithEstimate replaces vertex estimates and adds vertices to edges-only files",
          "[graph_io]") {
  SECTION("edges-only file gains vertices in id order") {
    GraphFile<Pose2> file;
    file.edges.push_back(MakeEdge<Pose2>(5, 6, Pose2(1, 0, 0), 1));
    file.edges.push_back(MakeEdge<Pose2>(2, 5, Pose2(1, 0, 0), 2));
    PoseGraph<Pose2> graph;
    std::vector<int> edge_of;
    REQUIRE(BuildPoseGraph(file, &graph, &edge_of).ok());
    std::vector<Pose2> estimate;
    for (int v = 0; v < graph.num_vertices(); ++v) {
      estimate.push_back(Pose2(static_cast<double>(graph.vertex(v).id), 0.5, 0.25));
    }
    const GraphFile<Pose2> out = WithEstimate(file, graph, estimate);
    REQUIRE(out.vertices.size() == 3);
    const int64_t ids[] = {2, 5, 6};
    for (int k = 0; k < 3; ++k) {
      CHECK(out.vertices[k].id == ids[k]);
      CHECK(out.vertices[k].line == 0);
      CHECK(SamePose(out.vertices[k].estimate, Pose2(static_cast<double>(ids[k]), 0.5, 0.25)));
    }
    REQUIRE(out.edges.size() == 2);
    CHECK(out.edges[1].from == 2);
  }
  SECTION("a file's own vertex records keep their order and lines") {
    GraphFile<Pose2> file;
    REQUIRE(ReadText("VERTEX_SE2 9 0 0 0\nVERTEX_SE2 8 0 0 0\nEDGE_SE2 8 9 1 0 0" +
                         std::string(kEdgeInformation2) + "\n",
                     &file)
                .ok());
    PoseGraph<Pose2> graph;
    std::vector<int> edge_of;
    REQUIRE(BuildPoseGraph(file, &graph, &edge_of).ok());
    std::vector<Pose2> estimate(2);
    estimate[graph.FindVertex(9)] = Pose2(3, 4, 0.5);
    const GraphFile<Pose2> out = WithEstimate(file, graph, estimate);
    REQUIRE(out.vertices.size() == 2);
    CHECK(out.vertices[0].id == 9);
    CHECK(out.vertices[0].line == 1);
    CHECK(SamePose(out.vertices[0].estimate, Pose2(3, 4, 0.5)));
    CHECK(out.vertices[1].id == 8);
    CHECK(SamePose(out.vertices[1].estimate, Pose2()));
  }
}

}  // namespace
}  // namespace irrr
