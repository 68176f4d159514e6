#include "clients/common/fleet_simulation.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <random>
#include <unordered_map>
#include <utility>

#include <fmt/core.h>

namespace irrr {
namespace {

// Salts of the random streams, so that each part of the simulation draws from a stream of its own
// and changing one option (the wrong rate, say) leaves the others' draws as they were.
constexpr uint32_t kPathSalt = 0x2545f491u;
constexpr uint32_t kOdometrySalt = 0x9e3779b9u;
constexpr uint32_t kRecognizerSalt = 0x85ebca6bu;
constexpr uint32_t kWrongSalt = 0xc2b2ae35u;

// Placing one wrong link or group: draws of its two runs before the request is called impossible.
constexpr int kMaxPlacementAttempts = 100000;

std::mt19937 Stream(uint32_t seed, uint32_t salt, uint32_t index) {
  std::seed_seq sequence{seed, salt, index};
  return std::mt19937(sequence);
}

double Uniform(double lo, double hi, std::mt19937* rng) {
  return std::uniform_real_distribution<double>(lo, hi)(*rng);
}

int UniformInt(int lo, int hi, std::mt19937* rng) {  // inclusive
  return std::uniform_int_distribution<int>(lo, hi)(*rng);
}

// A measurement of `truth` whose residual at the truth, RelativePoseResidual(z, from, to) =
// ErrorVector(z^-1 * truth), is e ~ N(0, diag(sigma_xy^2, sigma_xy^2, sigma_yaw^2)): z = truth *
// E^-1 with ErrorVector(E) = e. Draws the components one at a time, x, y, yaw, so that the stream
// does not depend on the compiler's order of evaluating arguments.
Pose2 Measured(const Pose2& truth, double sigma_xy_m, double sigma_yaw_rad, std::mt19937* rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  const double x = sigma_xy_m * normal(*rng);
  const double y = sigma_xy_m * normal(*rng);
  const double yaw = sigma_yaw_rad * normal(*rng);
  return truth * Pose2(x, y, yaw).Inverse();
}

typename Pose2::Matrix Information(double sigma_xy_m, double sigma_yaw_rad, double scale) {
  typename Pose2::Matrix information = Pose2::Matrix::Zero();
  information(0, 0) = scale / (sigma_xy_m * sigma_xy_m);
  information(1, 1) = scale / (sigma_xy_m * sigma_xy_m);
  information(2, 2) = scale / (sigma_yaw_rad * sigma_yaw_rad);
  return information;
}

// The same draws as core/outliers.cc's random and aliased claims.
Pose2 RandomClaim(double range_m, std::mt19937* rng) {
  const double x = Uniform(-range_m, range_m, rng);
  const double y = Uniform(-range_m, range_m, rng);
  return Pose2(x, y, Uniform(-M_PI, M_PI, rng));
}

Pose2 AliasedClaim(double radius_m, double max_angle_rad, std::mt19937* rng) {
  Eigen::Vector2d translation;
  do {
    for (int i = 0; i < 2; ++i) translation(i) = Uniform(-1.0, 1.0, rng);
  } while (translation.squaredNorm() > 1.0);
  return Pose2(radius_m * translation, Uniform(-max_angle_rad, max_angle_rad, rng));
}

// The pose `s` metres along a path of constant curvature (1/m; 0: straight) from the identity.
Pose2 Along(double s, double curvature) {
  if (curvature == 0.0) return Pose2(s, 0.0, 0.0);
  const double angle = curvature * s;
  return Pose2(std::sin(angle) / curvature, (1.0 - std::cos(angle)) / curvature, angle);
}

// One robot's path through the city, `num_poses` poses in the world frame, on the centre lines of
// the streets (the lane wander comes later).
std::vector<Pose2> DriveStreets(const FleetSimulationOptions& o, int num_poses, std::mt19937* rng) {
  // Directions: east, north, west, south; left of d is d + 1.
  constexpr std::array<int, 4> kDx = {1, 0, -1, 0};
  constexpr std::array<int, 4> kDy = {0, 1, 0, -1};
  auto inside = [&o](int i, int j) {
    return i >= 0 && i <= o.grid_blocks_x && j >= 0 && j <= o.grid_blocks_y;
  };
  auto heading = [](int d) { return d * M_PI / 2.0; };
  auto direction = [&](int d) { return Eigen::Vector2d(kDx[d], kDy[d]); };
  auto corner = [&o](int i, int j) {
    return Eigen::Vector2d(i * o.block_length_m, j * o.block_length_m);
  };

  int i = UniformInt(0, o.grid_blocks_x, rng);
  int j = UniformInt(0, o.grid_blocks_y, rng);
  std::vector<int> valid;
  for (int d = 0; d < 4; ++d) {
    if (inside(i + kDx[d], j + kDy[d])) valid.push_back(d);
  }
  int d = valid[UniformInt(0, static_cast<int>(valid.size()) - 1, rng)];

  std::vector<Pose2> path;
  path.reserve(num_poses);
  double next_sample_m = 0.0;  // path length from the current piece's start to the next pose
  auto sample = [&](const Pose2& start, double length_m, double curvature) {
    double s = next_sample_m;
    for (; s < length_m && static_cast<int>(path.size()) < num_poses; s += o.pose_spacing_m) {
      path.push_back(start * Along(s, curvature));
    }
    next_sample_m = s - length_m;
  };
  double entry_cut_m = 0.0;  // the block's length the turn onto it took
  while (static_cast<int>(path.size()) < num_poses) {
    const int next_i = i + kDx[d];
    const int next_j = j + kDy[d];
    // The way on at the next intersection: straight, left or right (never back), weighted.
    std::array<double, 3> weight = {o.keep_straight_probability,
                                    0.5 * (1.0 - o.keep_straight_probability),
                                    0.5 * (1.0 - o.keep_straight_probability)};
    const std::array<int, 3> way = {d, (d + 1) % 4, (d + 3) % 4};
    double total = 0.0;
    for (int k = 0; k < 3; ++k) {
      if (!inside(next_i + kDx[way[k]], next_j + kDy[way[k]])) weight[k] = 0.0;
      total += weight[k];
    }
    if (total <= 0.0) {  // keep_straight_probability 1 at the edge of the city: turn either way
      for (int k = 1; k < 3; ++k) {
        weight[k] = inside(next_i + kDx[way[k]], next_j + kDy[way[k]]) ? 1.0 : 0.0;
        total += weight[k];
      }
    }
    double u = Uniform(0.0, total, rng);
    int pick = 0;
    while (pick < 2 && (weight[pick] == 0.0 || u >= weight[pick])) {
      u -= weight[pick];
      ++pick;
    }
    while (weight[pick] == 0.0) pick = (pick + 2) % 3;  // rounding at the end of the range
    const int next_d = way[pick];
    const bool turn = next_d != d;
    const double exit_cut_m = turn ? o.corner_radius_m : 0.0;
    sample(Pose2(corner(i, j) + entry_cut_m * direction(d), heading(d)),
           o.block_length_m - entry_cut_m - exit_cut_m,
           0.0);
    if (turn) {
      const double sign = next_d == (d + 1) % 4 ? 1.0 : -1.0;
      sample(Pose2(corner(next_i, next_j) - o.corner_radius_m * direction(d), heading(d)),
             o.corner_radius_m * M_PI / 2.0,
             sign / o.corner_radius_m);
    }
    entry_cut_m = exit_cut_m;
    i = next_i;
    j = next_j;
    d = next_d;
  }
  return path;
}

// The path with the robot's slow wander about the centre line: a lateral offset that follows a
// first-order autoregressive process (sd lane_wander_m, correlation length
// lane_wander_correlation_m), the heading turned along the offset's change.
void Wander(const FleetSimulationOptions& o, std::vector<Pose2>* path, std::mt19937* rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  const double a = std::exp(-o.pose_spacing_m / o.lane_wander_correlation_m);
  double offset_m = o.lane_wander_m * normal(*rng);
  double previous_m = offset_m;
  for (Pose2& pose : *path) {
    const double yaw_rad = std::atan2(offset_m - previous_m, o.pose_spacing_m);
    pose = pose * Pose2(0.0, offset_m, yaw_rad);
    previous_m = offset_m;
    offset_m = a * offset_m + std::sqrt(1.0 - a * a) * o.lane_wander_m * normal(*rng);
  }
}

// A claim of the recognizer before it is written: `earlier` seen again at `later`.
struct Claim {
  int earlier = -1;  // vertex ids
  int later = -1;
  Pose2 measurement;  // in the written direction (see Written)
  SimulatedLoopKind kind = SimulatedLoopKind::kTrue;
  bool grouped = false;
  int draw_group = -1;  // wrong claims: the group in drawing order
};

// A loop is written (earlier, later), except (i, i+1), which BuildPoseGraph would read as the
// odometry into i+1: (i+1, i).
bool WrittenReversed(int earlier, int later) { return later == earlier + 1; }

// Spatial hash of the poses seen so far, cells of the recognizer's radius: a query looks at the 3
// x 3 cells around a point.
class PlaceGrid {
 public:
  explicit PlaceGrid(double cell_m) : cell_m_(cell_m) {}

  void Insert(const Eigen::Vector2d& p, int vertex) {
    cells_[Key(Cell(p.x()), Cell(p.y()))].push_back(vertex);
  }

  template <class Visit>
  void Near(const Eigen::Vector2d& p, Visit visit) const {
    const int64_t cx = Cell(p.x());
    const int64_t cy = Cell(p.y());
    for (int64_t x = cx - 1; x <= cx + 1; ++x) {
      for (int64_t y = cy - 1; y <= cy + 1; ++y) {
        const auto it = cells_.find(Key(x, y));
        if (it == cells_.end()) continue;
        for (int vertex : it->second) visit(vertex);
      }
    }
  }

 private:
  int64_t Cell(double coordinate) const {
    return static_cast<int64_t>(std::floor(coordinate / cell_m_));
  }
  // The two cell indices' low 32 bits side by side (unsigned: cells left of or below the origin
  // have negative indices).
  static uint64_t Key(int64_t x, int64_t y) {
    return (static_cast<uint64_t>(x) << 32) ^ (static_cast<uint64_t>(y) & 0xffffffffULL);
  }

  double cell_m_;
  std::unordered_map<uint64_t, std::vector<int>> cells_;
};

bool Finite(double x) { return std::isfinite(x); }

}  // namespace

Status FleetSimulationOptions::Validate() const {
  auto at_least = [](const char* name, int value, int low) {
    return value >= low ? Status::Ok()
                        : Status::Error(fmt::format("{} must be >= {}, got {}", name, low, value));
  };
  auto positive = [](const char* name, double value) {
    return Finite(value) && value > 0.0
               ? Status::Ok()
               : Status::Error(fmt::format("{} must be finite and > 0, got {}", name, value));
  };
  auto probability = [](const char* name, double value) {
    return value >= 0.0 && value <= 1.0
               ? Status::Ok()
               : Status::Error(fmt::format("{} must be in [0, 1], got {}", name, value));
  };
  for (const Status& s : {at_least("robots", robots, 1),
                          at_least("sessions per robot", sessions_per_robot, 1),
                          at_least("grid blocks (x)", grid_blocks_x, 1),
                          at_least("grid blocks (y)", grid_blocks_y, 1),
                          at_least("minimum loop gap", min_loop_gap, 2),
                          at_least("group size", group_size, 1),
                          positive("block length", block_length_m),
                          positive("pose spacing", pose_spacing_m),
                          positive("corner radius", corner_radius_m),
                          positive("lane wander correlation length", lane_wander_correlation_m),
                          positive("odometry sigma (x, y)", odometry_sigma_xy_m),
                          positive("odometry sigma (yaw)", odometry_sigma_yaw_rad),
                          positive("loop sigma (x, y)", loop_sigma_xy_m),
                          positive("loop sigma (yaw)", loop_sigma_yaw_rad),
                          positive("information scale", information_scale),
                          positive("match radius", match_radius_m),
                          positive("match heading", match_heading_rad),
                          positive("random translation", random_translation_m),
                          probability("keep-straight probability", keep_straight_probability),
                          probability("recognition rate", recognition_rate),
                          probability("wrong grouped fraction", wrong_grouped_fraction),
                          probability("wrong aliased fraction", wrong_aliased_fraction)}) {
    if (!s.ok()) return s;
  }
  const int64_t min_poses = 2LL * robots * sessions_per_robot;
  if (poses < min_poses) {
    return Status::Error(fmt::format(
        "poses must be >= {} (2 per session of every robot), got {}", min_poses, poses));
  }
  if (!(lane_wander_m >= 0.0) || !Finite(lane_wander_m)) {
    return Status::Error(fmt::format("lane wander must be finite and >= 0, got {}", lane_wander_m));
  }
  if (corner_radius_m > 0.5 * block_length_m) {
    return Status::Error(
        fmt::format("corner radius must be at most half the block length ({}), got {}",
                    0.5 * block_length_m,
                    corner_radius_m));
  }
  if (!(wrong_rate >= 0.0 && wrong_rate < 1.0)) {
    return Status::Error(fmt::format("wrong rate must be in [0, 1), got {}", wrong_rate));
  }
  if (!(aliased_translation_m >= 0.0) || !Finite(aliased_translation_m)) {
    return Status::Error(
        fmt::format("aliased translation must be finite and >= 0, got {}", aliased_translation_m));
  }
  if (!(aliased_rotation_rad >= 0.0 && aliased_rotation_rad <= M_PI)) {
    return Status::Error(
        fmt::format("aliased rotation must be in [0, pi], got {}", aliased_rotation_rad));
  }
  if (!(wrong_min_distance_m >= 0.0) || !Finite(wrong_min_distance_m)) {
    return Status::Error(fmt::format("wrong-loop minimum distance must be finite and >= 0, got {}",
                                     wrong_min_distance_m));
  }
  return Status::Ok();
}

const char* SimulatedLoopKindName(SimulatedLoopKind kind) {
  switch (kind) {
    case SimulatedLoopKind::kTrue:
      return "true";
    case SimulatedLoopKind::kRandom:
      return "random";
    case SimulatedLoopKind::kAliased:
      return "aliased";
  }
  return "unknown";
}

Status SimulateFleet(const FleetSimulationOptions& o, FleetSimulation* simulation) {
  if (Status s = o.Validate(); !s.ok()) return s;

  // Vertex ids: robot by robot, each robot's sessions in turn.
  const int num_vertices = o.poses;
  std::vector<int> first_vertex(o.robots + 1, 0);
  for (int r = 0; r < o.robots; ++r) {
    const int count = o.poses / o.robots + (r < o.poses % o.robots ? 1 : 0);
    first_vertex[r + 1] = first_vertex[r] + count;
  }
  std::vector<int> robot_of(num_vertices);
  std::vector<int> step_of(num_vertices);
  std::vector<int> session_of(num_vertices);
  std::vector<bool> session_start(num_vertices, false);
  std::vector<int32_t> robot_of_session;
  for (int r = 0; r < o.robots; ++r) {
    const int count = first_vertex[r + 1] - first_vertex[r];
    int v = first_vertex[r];
    for (int s = 0; s < o.sessions_per_robot; ++s) {
      const int length = count / o.sessions_per_robot + (s < count % o.sessions_per_robot ? 1 : 0);
      session_start[v] = true;
      for (int k = 0; k < length; ++k, ++v) {
        robot_of[v] = r;
        step_of[v] = v - first_vertex[r];
        session_of[v] = static_cast<int>(robot_of_session.size());
      }
      robot_of_session.push_back(r);
    }
  }

  // Ground truth, odometry and each session's dead reckoning.
  std::vector<Pose2> truth(num_vertices);
  std::vector<Pose2> odometry(num_vertices);  // into each vertex that is no session's first
  std::vector<Pose2> dead_reckoning(num_vertices);
  for (int r = 0; r < o.robots; ++r) {
    std::mt19937 path_rng = Stream(o.seed, kPathSalt, static_cast<uint32_t>(r));
    std::vector<Pose2> path = DriveStreets(o, first_vertex[r + 1] - first_vertex[r], &path_rng);
    Wander(o, &path, &path_rng);
    std::copy(path.begin(), path.end(), truth.begin() + first_vertex[r]);
    std::mt19937 odometry_rng = Stream(o.seed, kOdometrySalt, static_cast<uint32_t>(r));
    for (int v = first_vertex[r]; v < first_vertex[r + 1]; ++v) {
      if (session_start[v]) continue;  // dead_reckoning[v] is the identity
      odometry[v] = Measured(truth[v - 1].Inverse() * truth[v],
                             o.odometry_sigma_xy_m,
                             o.odometry_sigma_yaw_rad,
                             &odometry_rng);
      dead_reckoning[v] = dead_reckoning[v - 1] * odometry[v];
    }
  }

  // Whether the robot at `later` may claim `earlier`: a place of its own robot before it (in its
  // own session min_loop_gap poses before at least), or of a robot with a lower id at the same
  // step or before (see the header: then irrr-inject sends it from the robot that recognised it).
  auto may_claim = [&](int earlier, int later) {
    if (robot_of[earlier] == robot_of[later]) {
      return earlier < later &&
             (session_of[earlier] != session_of[later] || later - earlier >= o.min_loop_gap);
    }
    return robot_of[earlier] < robot_of[later] && step_of[earlier] <= step_of[later];
  };
  auto written = [&](int earlier, int later, const Pose2& earlier_T_later) {
    return WrittenReversed(earlier, later) ? earlier_T_later.Inverse() : earlier_T_later;
  };

  // The true claims, step by step, each robot in turn within a step: at a robot's pose the grid
  // holds every pose taken before it in that order.
  std::vector<Claim> claims;
  {
    std::mt19937 rng = Stream(o.seed, kRecognizerSalt, 0);
    PlaceGrid grid(o.match_radius_m);
    std::vector<int> candidates;
    const int max_steps = first_vertex[1] - first_vertex[0];
    for (int step = 0; step < max_steps; ++step) {
      for (int r = 0; r < o.robots; ++r) {
        const int v = first_vertex[r] + step;
        if (v >= first_vertex[r + 1]) continue;
        const Pose2& here = truth[v];
        candidates.clear();
        grid.Near(here.translation(), [&](int u) {
          if ((truth[u].translation() - here.translation()).norm() <= o.match_radius_m &&
              std::abs(NormalizeAngle(truth[u].yaw_rad() - here.yaw_rad())) <=
                  o.match_heading_rad &&
              may_claim(u, v)) {
            candidates.push_back(u);
          }
        });
        // Always one draw, so that the stream does not depend on whether there were candidates.
        const bool recognised = Uniform(0.0, 1.0, &rng) < o.recognition_rate;
        if (recognised && !candidates.empty()) {
          // By vertex id, so that the pick depends on the candidates, not on the grid's cells.
          std::sort(candidates.begin(), candidates.end());
          const int earlier =
              candidates[UniformInt(0, static_cast<int>(candidates.size()) - 1, &rng)];
          const int from = WrittenReversed(earlier, v) ? v : earlier;
          const int to = WrittenReversed(earlier, v) ? earlier : v;
          Claim claim;
          claim.earlier = earlier;
          claim.later = v;
          claim.measurement = Measured(
              truth[from].Inverse() * truth[to], o.loop_sigma_xy_m, o.loop_sigma_yaw_rad, &rng);
          claims.push_back(claim);
        }
        grid.Insert(here.translation(), v);
      }
    }
  }
  const int num_true = static_cast<int>(claims.size());

  // The wrong claims: wrong_rate of all hypotheses, lone and grouped, random and aliased.
  int draw_group = 0;  // groups drawn so far (a lone link is a group of its own)
  {
    const int num_wrong =
        static_cast<int>(std::lround(num_true * o.wrong_rate / (1.0 - o.wrong_rate)));
    const int num_groups =
        static_cast<int>(std::lround(num_wrong * o.wrong_grouped_fraction / o.group_size));
    const int num_lone = std::max(0, num_wrong - num_groups * o.group_size);
    const int num_aliased_lone = static_cast<int>(std::lround(num_lone * o.wrong_aliased_fraction));
    const int num_aliased_groups =
        static_cast<int>(std::lround(num_groups * o.wrong_aliased_fraction));
    std::mt19937 rng = Stream(o.seed, kWrongSalt, 0);
    // A run of `size` consecutive poses of one session starting at v.
    auto run_fits = [&](int v, int size) {
      return v + size <= num_vertices && session_of[v + size - 1] == session_of[v];
    };
    auto draw = [&](int size, SimulatedLoopKind kind, bool grouped) -> Status {
      for (int attempt = 0; attempt < kMaxPlacementAttempts; ++attempt) {
        const int later = UniformInt(0, num_vertices - 1, &rng);
        const int earlier = UniformInt(0, num_vertices - 1, &rng);
        if (!run_fits(later, size) || !run_fits(earlier, size)) continue;
        bool ok = true;
        for (int m = 0; m < size && ok; ++m) {
          ok = may_claim(earlier + m, later + m) &&
               (truth[earlier + m].translation() - truth[later + m].translation()).norm() >
                   o.wrong_min_distance_m;
        }
        if (!ok) continue;
        const Pose2 claimed =
            kind == SimulatedLoopKind::kAliased
                ? AliasedClaim(o.aliased_translation_m, o.aliased_rotation_rad, &rng)
                : RandomClaim(o.random_translation_m, &rng);
        for (int m = 0; m < size; ++m) {
          // Consistent with the dead reckoning: x_earlier^-1 x_later = (D_e0^-1 D_em)^-1 *
          // claimed * (D_l0^-1 D_lm), as core/outliers.cc's groups.
          const Pose2 earlier_T_later =
              (dead_reckoning[earlier].Inverse() * dead_reckoning[earlier + m]).Inverse() *
              claimed * (dead_reckoning[later].Inverse() * dead_reckoning[later + m]);
          Claim claim;
          claim.earlier = earlier + m;
          claim.later = later + m;
          claim.measurement = written(earlier + m, later + m, earlier_T_later);
          claim.kind = kind;
          claim.grouped = grouped;
          claim.draw_group = draw_group;
          claims.push_back(claim);
        }
        ++draw_group;
        return Status::Ok();
      }
      return Status::Error(fmt::format(
          "could not place {} wrong loop(s) between poses more than {} m apart that the fleet "
          "could claim (a city or a run too small for the wrong loops asked for)",
          size,
          o.wrong_min_distance_m));
    };
    for (int k = 0; k < num_lone; ++k) {
      const SimulatedLoopKind kind =
          k < num_aliased_lone ? SimulatedLoopKind::kAliased : SimulatedLoopKind::kRandom;
      if (Status s = draw(1, kind, false); !s.ok()) return s;
    }
    for (int k = 0; k < num_groups; ++k) {
      const SimulatedLoopKind kind =
          k < num_aliased_groups ? SimulatedLoopKind::kAliased : SimulatedLoopKind::kRandom;
      if (Status s = draw(o.group_size, kind, true); !s.ok()) return s;
    }
  }

  // The file, in arrival order: each pose's odometry, then the claims whose later pose it is.
  FleetSimulation out;
  out.file.vertices.resize(num_vertices);
  for (int v = 0; v < num_vertices; ++v) {
    out.file.vertices[v].id = v;
    out.file.vertices[v].estimate = dead_reckoning[v];
  }
  std::vector<std::vector<int>> claims_at(num_vertices);
  for (size_t k = 0; k < claims.size(); ++k) {
    claims_at[claims[k].later].push_back(static_cast<int>(k));
  }
  const Pose2::Matrix odometry_information =
      Information(o.odometry_sigma_xy_m, o.odometry_sigma_yaw_rad, o.information_scale);
  const Pose2::Matrix loop_information =
      Information(o.loop_sigma_xy_m, o.loop_sigma_yaw_rad, o.information_scale);
  out.file.edges.reserve(num_vertices + claims.size());
  std::vector<int> group_of_draw_group(draw_group, -1);  // numbered in file order
  int num_groups_written = 0;
  FleetSimulationCounts& counts = out.counts;
  for (int v = 0; v < num_vertices; ++v) {
    if (!session_start[v]) {
      FileEdge<Pose2> edge;
      edge.from = v - 1;
      edge.to = v;
      edge.measurement = odometry[v];
      edge.information = odometry_information;
      out.file.edges.push_back(edge);
      ++counts.odometry;
    }
    for (int k : claims_at[v]) {
      const Claim& claim = claims[k];
      const bool reversed = WrittenReversed(claim.earlier, claim.later);
      FileEdge<Pose2> edge;
      edge.from = reversed ? claim.later : claim.earlier;
      edge.to = reversed ? claim.earlier : claim.later;
      edge.measurement = claim.measurement;
      edge.information = loop_information;
      SimulatedLoop loop;
      loop.edge_index = static_cast<int>(out.file.edges.size());
      loop.kind = claim.kind;
      loop.grouped = claim.grouped;
      loop.inter_robot = robot_of[claim.earlier] != robot_of[claim.later];
      if (claim.kind != SimulatedLoopKind::kTrue) {
        int& group = group_of_draw_group[claim.draw_group];
        if (group < 0) group = num_groups_written++;
        loop.group = group;
      }
      out.file.edges.push_back(edge);
      out.loops.push_back(loop);
      LabelRow row;
      row.edge_index = loop.edge_index;
      row.from = edge.from;
      row.to = edge.to;
      row.outlier = claim.kind != SimulatedLoopKind::kTrue;
      row.group = loop.group;
      out.labels.push_back(row);
      switch (claim.kind) {
        case SimulatedLoopKind::kTrue:
          ++(loop.inter_robot ? counts.true_inter_robot : counts.true_intra_robot);
          break;
        case SimulatedLoopKind::kRandom:
          ++(claim.grouped ? counts.random_grouped : counts.random_lone);
          break;
        case SimulatedLoopKind::kAliased:
          ++(claim.grouped ? counts.aliased_grouped : counts.aliased_lone);
          break;
      }
    }
  }
  counts.poses = num_vertices;
  counts.robots = o.robots;
  counts.sessions = static_cast<int>(robot_of_session.size());
  counts.random_groups = counts.random_grouped / o.group_size;
  counts.aliased_groups = counts.aliased_grouped / o.group_size;
  out.ground_truth = std::move(truth);
  out.robot_of_session = std::move(robot_of_session);
  out.robot_of_vertex = std::move(robot_of);
  out.step_of_vertex = std::move(step_of);
  *simulation = std::move(out);
  return Status::Ok();
}

std::string FormatFleetSummary(const FleetSimulationCounts& c) {
  return fmt::format(
      "{} poses, {} robots, {} sessions, {} odometry edges; {} true loops ({} intra-robot, {} "
      "inter-robot); {} wrong loops ({} random, {} aliased, {} random in {} group(s), {} "
      "aliased in {} group(s))",
      c.poses,
      c.robots,
      c.sessions,
      c.odometry,
      c.true_loops(),
      c.true_intra_robot,
      c.true_inter_robot,
      c.wrong_loops(),
      c.random_lone,
      c.aliased_lone,
      c.random_grouped,
      c.random_groups,
      c.aliased_grouped,
      c.aliased_groups);
}

std::string RobotsList(const std::vector<int32_t>& robot_of_session) {
  std::string list;
  for (size_t s = 0; s < robot_of_session.size(); ++s) {
    list += (s == 0 ? "" : ",") + std::to_string(robot_of_session[s]);
  }
  return list;
}

Status WriteGroundTruth(std::ostream& out, const std::vector<Pose2>& ground_truth) {
  for (const Pose2& pose : ground_truth) {
    out << fmt::format("{:.17g} {:.17g} {:.17g}\n",
                       pose.translation().x(),
                       pose.translation().y(),
                       pose.yaw_rad());
  }
  if (!out) return Status::Error("write failed");
  return Status::Ok();
}

}  // namespace irrr
