#include "core/outliers.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <set>

namespace irrr {
namespace {

template <class Pose>
Pose RandomMeasurement(double range_m, std::mt19937* rng) {
  std::uniform_real_distribution<double> translation(-range_m, range_m);
  std::uniform_real_distribution<double> angle(-M_PI, M_PI);
  if constexpr (Pose::kDim == 3) {
    return Pose2(translation(*rng), translation(*rng), angle(*rng));
  } else {
    std::normal_distribution<double> normal(0.0, 1.0);
    Eigen::Quaterniond q(normal(*rng), normal(*rng), normal(*rng), normal(*rng));
    q.normalize();
    return Pose3(q, Eigen::Vector3d(translation(*rng), translation(*rng), translation(*rng)));
  }
}

// A pose is (session, position in the session).
struct Place {
  int session;
  int position;
};

}  // namespace

const char* OutlierModeName(OutlierMode mode) {
  switch (mode) {
    case OutlierMode::kRandom:
      return "random";
    case OutlierMode::kLocal:
      return "local";
    case OutlierMode::kRandomGrouped:
      return "random-grouped";
    case OutlierMode::kLocalGrouped:
      return "local-grouped";
    case OutlierMode::kInterSession:
      return "inter-session";
  }
  return "unknown";
}

bool IsGrouped(OutlierMode mode) {
  return mode == OutlierMode::kRandomGrouped || mode == OutlierMode::kLocalGrouped ||
         mode == OutlierMode::kInterSession;
}

template <class Pose>
Status MakeOutliers(const PoseGraph<Pose>& graph,
                    const OutlierOptions& options,
                    std::vector<OutlierLink<Pose>>* outliers) {
  const bool grouped = IsGrouped(options.mode);
  const bool local =
      options.mode == OutlierMode::kLocal || options.mode == OutlierMode::kLocalGrouped;
  const int group = grouped ? std::max(1, options.group_size) : 1;
  if (options.count < 0) return Status::Error("outlier count must be >= 0");
  if (options.mode == OutlierMode::kInterSession && graph.num_sessions() < 2) {
    return Status::Error("inter-session outliers need at least two sessions");
  }
  std::vector<int> sessions;  // sessions long enough to hold a group
  for (int s = 0; s < graph.num_sessions(); ++s) {
    if (static_cast<int>(graph.session(s).vertices.size()) >= group + 2) sessions.push_back(s);
  }
  if (sessions.empty() || (options.mode == OutlierMode::kInterSession && sessions.size() < 2)) {
    return Status::Error("the graph's sessions are too short for these outliers");
  }

  typename Pose::Matrix information = Pose::Matrix::Identity();
  bool found_loop = false;
  for (const Edge<Pose>& e : graph.edges()) {
    if (e.kind == EdgeKind::kLoop) {
      information = e.information;
      found_loop = true;
      break;
    }
  }
  if (!found_loop) {
    for (const Edge<Pose>& e : graph.edges()) {
      if (e.kind == EdgeKind::kOdometry) {
        information = e.information;
        break;
      }
    }
  }

  const std::vector<Pose> dead_reckoning = graph.OdometryEstimate();
  std::mt19937 rng(options.seed);
  auto uniform_int = [&rng](int lo, int hi) {  // inclusive
    return std::uniform_int_distribution<int>(lo, hi)(rng);
  };
  auto random_place = [&](int session) {
    const int length = static_cast<int>(graph.session(session).vertices.size());
    return Place{session, uniform_int(0, length - group)};
  };
  auto vertex_of = [&graph](const Place& p, int offset) {
    return graph.session(p.session).vertices[p.position + offset];
  };

  std::vector<OutlierLink<Pose>> out;
  constexpr int kMaxAttempts = 1000000;
  int attempts = 0;
  while (static_cast<int>(out.size()) < options.count) {
    if (++attempts > kMaxAttempts) {
      return Status::Error("could not place the outliers (graph too small for the options)");
    }
    const int session_a = sessions[uniform_int(0, static_cast<int>(sessions.size()) - 1)];
    int session_b = session_a;
    if (options.mode == OutlierMode::kInterSession) {
      session_b = sessions[uniform_int(0, static_cast<int>(sessions.size()) - 1)];
      if (session_b == session_a) continue;
    } else if (!local) {
      session_b = sessions[uniform_int(0, static_cast<int>(sessions.size()) - 1)];
    }
    const Place a = random_place(session_a);
    Place b = random_place(session_b);
    if (local) {
      // b lies before a, between 2 and local_window poses back.
      const int back = uniform_int(2, std::max(2, options.local_window));
      b.position = a.position - back;
      if (b.position < 0) continue;
    }
    if (session_a == session_b && std::abs(a.position - b.position) < 2 + group) continue;

    // The group's claim: the wrong transform between its two places.
    const Pose claimed = RandomMeasurement<Pose>(options.translation_range_m, &rng);
    const int from0 = vertex_of(a, 0);
    const int to0 = vertex_of(b, 0);
    for (int m = 0; m < group; ++m) {
      const int from = vertex_of(a, m);
      const int to = vertex_of(b, m);
      OutlierLink<Pose> link;
      link.from = from;
      link.to = to;
      // Consistent with odometry: x_from^-1 x_to = (D_from0^-1 D_from)^-1 * claimed *
      // (D_to0^-1 D_to).
      link.measurement = grouped
                             ? (dead_reckoning[from0].Inverse() * dead_reckoning[from]).Inverse() *
                                   claimed * (dead_reckoning[to0].Inverse() * dead_reckoning[to])
                             : claimed;
      link.information = information;
      out.push_back(link);
    }
  }
  outliers->swap(out);
  return Status::Ok();
}

template <class Pose>
Status SplitIntoSessions(const std::vector<int64_t>& session_starts, GraphFile<Pose>* file) {
  GraphFile<Pose> split = *file;
  const std::set<int64_t> starts(session_starts.begin(), session_starts.end());
  for (int64_t start : starts) {
    const auto odometry =
        std::find_if(split.edges.begin(), split.edges.end(), [start](const FileEdge<Pose>& e) {
          return e.from == start - 1 && e.to == start;
        });
    if (odometry == split.edges.end()) {
      return Status::Error("vertex " + std::to_string(start) +
                           " has no odometry edge from its predecessor");
    }
    split.edges.erase(odometry);
  }
  // Re-base: every vertex from a start up to the next start (or a gap in the ids) is expressed in
  // the frame of that start.
  std::vector<FileVertex<Pose>*> by_id;
  for (FileVertex<Pose>& v : split.vertices) by_id.push_back(&v);
  std::sort(by_id.begin(), by_id.end(), [](const FileVertex<Pose>* a, const FileVertex<Pose>* b) {
    return a->id < b->id;
  });
  Pose session_T_world;
  bool rebasing = false;
  int64_t previous = 0;
  for (size_t k = 0; k < by_id.size(); ++k) {
    FileVertex<Pose>& v = *by_id[k];
    if (k > 0 && v.id != previous + 1) rebasing = false;
    if (starts.count(v.id) != 0) {
      session_T_world = v.estimate.Inverse();
      rebasing = true;
    }
    if (rebasing) v.estimate = session_T_world * v.estimate;
    previous = v.id;
  }
  *file = std::move(split);
  return Status::Ok();
}

template Status MakeOutliers<Pose2>(const PoseGraph<Pose2>&,
                                    const OutlierOptions&,
                                    std::vector<OutlierLink<Pose2>>*);
template Status MakeOutliers<Pose3>(const PoseGraph<Pose3>&,
                                    const OutlierOptions&,
                                    std::vector<OutlierLink<Pose3>>*);
template Status SplitIntoSessions<Pose2>(const std::vector<int64_t>&, GraphFile<Pose2>*);
template Status SplitIntoSessions<Pose3>(const std::vector<int64_t>&, GraphFile<Pose3>*);

}  // namespace irrr
