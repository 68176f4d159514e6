// irrr-listen: hears what irrrd publishes and keeps the latest map and every verdict.
//
//   irrr-listen [--lcm-url URL] [--output MAP.g2o] [--decisions OUT.csv] [--labels LABELS.csv]
//               [--transforms OUT.csv] [--robot R] [--plot MAP.svg] [--idle-exit S]
//               [--steps-csv STEPS.csv] [--status-csv STATUS.csv] [--config FILE]
//
// It assembles each solution (a correction_t with all its verdict and pose chunks) and keeps,
// per session, the newest estimate; keys that no solution has covered yet continue the latest
// estimate along the odometry heard on the keyframe channel (as the daemon's own estimate
// does). It also hears the keyframe and loop channels, for the map's edges. A live one-line
// summary goes to the terminal. It asks the daemon for its whole solution when it starts (a late
// joiner) and again before writing (until one arrives whole, at most --final-wait seconds), so
// that what it writes is the daemon's state even when packets were lost. On SIGINT/SIGTERM, or
// after --idle-exit seconds without a message, it writes:
//  - --output: the map as g2o (odometry and accepted loops as edges); vertex id = key, or
//    robot_id * 1000000000 + key when keys repeat across robots;
//  - --decisions: one row per hypothesis in irrr-batch's CSV format, ordered by (sender,
//    hypothesis_id): edge_index = hypothesis_id, from/to = keys, session_from/to = session ids;
//  - --transforms: per session, the latest map_T_odom (session_transform_t): where the session's
//    odometry frame lies in its component's map frame.
//  - --plot: the map with every verdict, the odometry beside it and the time of each step
//    (clients/common/plots.h).
// While it runs, --steps-csv and --status-csv get one row per step correction and per status_t
// heard, each written as it arrives (a long run can be followed with tail -f; tools/soak plots
// them).
// --robot R keeps only robot R's part, as a robot of a fleet would: its sessions' poses and
// transforms, and the hypotheses with an end in them.
// --labels prints precision and recall against irrr-corrupt's labels. Exit codes follow
// sysexits.h: 64 usage, 65 bad labels, 69 LCM unavailable, 73 output not written, 78 bad
// configuration.

#include <poll.h>
#include <signal.h>
#include <sys/signalfd.h>
#include <sysexits.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <csignal>
#include <fstream>
#include <limits>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include <fmt/core.h>
#include <fmt/ranges.h>
#include <CLI/CLI.hpp>
#include <lcm/lcm-cpp.hpp>

#include "clients/common/graph_files.h"
#include "clients/common/loop_csv.h"
#include "clients/common/plots.h"
#include "daemon/common/irrr_config.h"
#include "daemon/raw_subscription.h"
#include "daemon/wire.h"
#include "irrr/correction_t.hpp"
#include "irrr/keyframe_t.hpp"
#include "irrr/loop_hypothesis_t.hpp"
#include "irrr/solution_request_t.hpp"
#include "irrr/solution_t.hpp"
#include "irrr/status_t.hpp"
#include "irrr/verdicts_t.hpp"

namespace irrr {
namespace {

constexpr int64_t kRobotIdStride = 1000000000;

using SessionName = std::pair<int32_t, int32_t>;
using HypothesisName = std::pair<std::string, int64_t>;

struct SessionState {
  int8_t dim = 0;
  std::map<int64_t, keyframe_t> keyframes;  // heard on the keyframe channel
  std::map<int64_t, pose_t> estimate;       // from solutions
  std::map<int64_t, int64_t> estimate_solution;
  int component = -1;
  session_transform_t transform{};  // the latest (transform_solution > 0)
  int64_t transform_solution = 0;
};

struct HypothesisState {
  bool heard = false;
  loop_hypothesis_t hypothesis;
  bool judged = false;
  verdict_t verdict;
  int64_t verdict_solution = 0;
};

class Listener {
 public:
  // `robot`: keep only that robot's part (-1: everything).
  explicit Listener(int32_t robot) : robot_(robot) {}

  // Handlers (all on the thread that calls lcm.handle()).
  void OnKeyframe(const lcm::ReceiveBuffer* b, const std::string&) {
    keyframe_t m;
    if (!Decode(b, &m) || !Kept(m.robot_id)) return;
    SessionState& s = sessions_[{m.robot_id, m.session_id}];
    s.dim = m.dim;
    s.keyframes[m.key] = m;
  }
  void OnLoop(const lcm::ReceiveBuffer* b, const std::string&) {
    loop_hypothesis_t m;
    if (!Decode(b, &m) || !(Kept(m.robot_from) || Kept(m.robot_to))) return;
    HypothesisState& h = hypotheses_[{m.header.sender, m.hypothesis_id}];
    h.heard = true;
    h.hypothesis = m;
  }
  void OnCorrection(const lcm::ReceiveBuffer* b, const std::string&) {
    correction_t m;
    if (!Decode(b, &m)) return;
    if (m.daemon_start_utime != daemon_start_utime_) {
      if (daemon_start_utime_ != 0) {
        fmt::print("\nirrr-listen: the daemon restarted\n");
        // Its solution ids start again from 1: what we hold is older than anything new.
        pending_.clear();
        for (auto& [name, s] : sessions_) {
          for (auto& [key, id] : s.estimate_solution) id = 0;
        }
        for (auto& [name, h] : hypotheses_) h.verdict_solution = 0;
        latest_solution_ = 0;
      }
      daemon_start_utime_ = m.daemon_start_utime;
    }
    Pending& p = pending_[m.solution_id];
    p.have_correction = true;
    p.correction = m;
    Complete(m.solution_id);
  }
  void OnStatus(const lcm::ReceiveBuffer* b, const std::string&) {
    status_t m;
    if (!Decode(b, &m)) return;
    daemon_keyframes_ = m.n_keyframes;
    if (status_log_ == nullptr) return;
    *status_log_ << fmt::format("{},{},{},{},{},{},{},{},{},{},{},{:.3f},{}\n",
                                NowUtime(),
                                m.start_utime,
                                static_cast<int>(m.state),
                                m.n_keyframes,
                                m.n_hypotheses,
                                m.n_accepted,
                                m.n_rejected,
                                m.n_steps,
                                m.queue_depth,
                                m.n_parked,
                                m.n_errors,
                                m.last_step_latency_ms,
                                m.n_recovered)
                 << std::flush;
  }
  // --steps-csv and --status-csv (nullptr: not written); their header rows are written here.
  void LogTo(std::ostream* steps, std::ostream* status) {
    steps_log_ = steps;
    status_log_ = status;
    if (steps_log_ != nullptr) {
      *steps_log_ << "received_utime,daemon_start_utime,solution_id,step,closed_utime,"
                     "published_utime,latency_ms,decide_ms,solves,deferred,daemon_keyframes\n"
                  << std::flush;
    }
    if (status_log_ != nullptr) {
      *status_log_ << "received_utime,daemon_start_utime,state,keyframes,hypotheses,accepted,"
                      "rejected,steps,queue_depth,parked,errors,last_step_latency_ms,recovered\n"
                   << std::flush;
    }
  }
  void OnVerdicts(const lcm::ReceiveBuffer* b, const std::string&) {
    verdicts_t m;
    if (!Decode(b, &m)) return;
    pending_[m.solution_id].verdicts[m.chunk_index] = m;
    Complete(m.solution_id);
  }
  void OnSolution(const lcm::ReceiveBuffer* b, const std::string&) {
    solution_t m;
    if (!Decode(b, &m)) return;
    pending_[m.solution_id].poses[m.chunk_index] = m;
    Complete(m.solution_id);
  }

  std::string Summary() const {
    std::map<LoopState, int> count;
    for (const auto& [name, h] : hypotheses_) {
      LoopState state = LoopState::kPending;
      if (h.judged) LoopStateFromWire(h.verdict.state, &state);
      ++count[state];
    }
    std::set<int> components;
    for (const auto& [name, s] : sessions_) {
      if (s.component >= 0) components.insert(s.component);
    }
    const int rejected = count[LoopState::kRejectedLinkTest] +
                         count[LoopState::kRejectedClusterTest] +
                         count[LoopState::kRejectedJointTest];
    return fmt::format(
        "solution {} (step {}) | {} session(s) in {} component(s) | {} hypotheses: {} accepted, "
        "{} rejected, {} reversed, {} pending | step latency {:.1f} ms{}",
        latest_solution_,
        latest_step_,
        sessions_.size(),
        components.size(),
        hypotheses_.size(),
        count[LoopState::kAccepted],
        rejected,
        count[LoopState::kReversed],
        count[LoopState::kPending],
        latest_latency_ms_,
        incomplete_ > 0 ? fmt::format(" | {} incomplete solution(s)", incomplete_) : "");
  }

  bool HasDimension(int8_t dim) const {
    for (const auto& [name, s] : sessions_) {
      if (s.dim == dim) return true;
    }
    return false;
  }

  std::vector<DecisionRow> DecisionRows() const {
    std::vector<DecisionRow> rows;
    for (const auto& [name, h] : hypotheses_) {
      DecisionRow row;
      row.edge_index = static_cast<int>(name.second);
      if (h.judged) {
        const verdict_t& v = h.verdict;
        row.from = v.key_from;
        row.to = v.key_to;
        row.session_from = v.session_from;
        row.session_to = v.session_to;
        LoopStateFromWire(v.state, &row.decision.state);
        row.decision.cluster = v.cluster;
        row.decision.step = v.step;
        row.decision.chi2 = v.chi2;
        row.decision.threshold = v.threshold;
      } else {
        row.from = h.hypothesis.key_from;
        row.to = h.hypothesis.key_to;
        row.session_from = h.hypothesis.session_from;
        row.session_to = h.hypothesis.session_to;
      }
      rows.push_back(row);
    }
    return rows;
  }

  // The map for plots.h: each session at its estimate (`initial`: at the odometry poses its
  // keyframes carried), every hypothesis heard between two known keys with its verdict.
  template <class Pose>
  MapPlot Plot(const std::string& title, bool initial) const {
    MapPlot plot;
    plot.title = title;
    plot.three_d = Pose::kTranslationDim == 3;
    std::map<std::pair<SessionName, int64_t>, PlotPoint> where;
    for (const auto& [name, s] : sessions_) {
      if (s.dim != WireDim<Pose>()) continue;
      plot.session_names.push_back(fmt::format("robot {} session {}", name.first, name.second));
      std::vector<PlotPoint> path;
      for (const auto& [key, pose] : SessionPoses<Pose>(s, initial)) {
        path.push_back(ToPlotPoint(pose));
        where[{name, key}] = path.back();
      }
      plot.sessions.push_back(std::move(path));
    }
    for (const auto& [name, h] : hypotheses_) {
      const auto from =
          where.find({{h.hypothesis.robot_from, h.hypothesis.session_from}, h.hypothesis.key_from});
      const auto to =
          where.find({{h.hypothesis.robot_to, h.hypothesis.session_to}, h.hypothesis.key_to});
      if (!h.heard || from == where.end() || to == where.end()) continue;
      PlotLoop loop;
      loop.from = from->second;
      loop.to = to->second;
      if (h.judged && !initial) LoopStateFromWire(h.verdict.state, &loop.state);
      plot.loops.push_back(loop);
    }
    return plot;
  }

  const std::vector<double>& step_decide_ms() const { return decide_ms_; }

  // The map as a graph file: every keyframe heard (or estimated), odometry and accepted loops.
  template <class Pose>
  GraphFile<Pose> Map() const {
    std::set<int64_t> keys;
    bool repeated = false;
    for (const auto& [name, s] : sessions_) {
      for (const auto& [key, unused] : s.estimate) repeated |= !keys.insert(key).second;
      for (const auto& [key, unused] : s.keyframes) {
        if (s.estimate.count(key) == 0) repeated |= !keys.insert(key).second;
      }
    }
    auto id_of = [&](int32_t robot, int64_t key) {
      return repeated ? int64_t{robot} * kRobotIdStride + key : key;
    };
    GraphFile<Pose> file;
    for (const auto& [name, s] : sessions_) {
      if (s.dim != WireDim<Pose>()) continue;
      const std::map<int64_t, Pose> poses = SessionPoses<Pose>(s, /*odometry=*/false);
      for (const auto& [key, pose] : poses) {
        file.vertices.push_back({id_of(name.first, key), pose, 0});
        const auto heard = s.keyframes.find(key);
        if (heard != s.keyframes.end() && heard->second.has_odom_edge &&
            poses.count(key - 1) != 0) {
          FileEdge<Pose> edge;
          edge.from = id_of(name.first, key - 1);
          edge.to = id_of(name.first, key);
          PoseFromWire(heard->second.odom_delta, "odom_delta", &edge.measurement);
          InformationFromWire<Pose>(heard->second.information, "information", &edge.information);
          file.edges.push_back(edge);
        }
      }
    }
    for (const auto& [name, h] : hypotheses_) {
      if (!h.heard || !h.judged || h.verdict.state != verdict_t::ACCEPTED ||
          h.hypothesis.dim != WireDim<Pose>() ||
          sessions_.count({h.hypothesis.robot_from, h.hypothesis.session_from}) == 0 ||
          sessions_.count({h.hypothesis.robot_to, h.hypothesis.session_to}) == 0) {
        continue;  // not judged, not trusted, or to another robot's map (--robot)
      }
      FileEdge<Pose> edge;
      edge.from = id_of(h.hypothesis.robot_from, h.hypothesis.key_from);
      edge.to = id_of(h.hypothesis.robot_to, h.hypothesis.key_to);
      PoseFromWire(h.hypothesis.measurement, "measurement", &edge.measurement);
      InformationFromWire<Pose>(h.hypothesis.information, "information", &edge.information);
      file.edges.push_back(edge);
    }
    return file;
  }

  // "robot_id,session_id,component,latest_key,x,y,z,qw,qx,qy,qz": the latest transform of each
  // session a correction has placed.
  Status WriteTransforms(std::ostream& out) const {
    out << "robot_id,session_id,component,latest_key,x,y,z,qw,qx,qy,qz\n";
    for (const auto& [name, s] : sessions_) {
      if (s.transform_solution == 0) continue;
      const pose_t& p = s.transform.map_T_odom;
      out << fmt::format("{},{},{},{},{:.17g},{:.17g},{:.17g},{:.17g},{:.17g},{:.17g},{:.17g}\n",
                         name.first,
                         name.second,
                         s.transform.component,
                         s.transform.latest_key,
                         p.t[0],
                         p.t[1],
                         p.t[2],
                         p.q[0],
                         p.q[1],
                         p.q[2],
                         p.q[3]);
    }
    return out ? Status::Ok() : Status::Error("write failed");
  }

  int64_t latest_solution() const { return latest_solution_; }

  // A session's poses by key: the estimate (`odometry`: the keyframes' odometry poses); keys
  // beyond the solutions continue the estimate along odometry, as the daemon's do, and a session
  // no solution covered starts at the identity (its own frame).
  template <class Pose>
  static std::map<int64_t, Pose> SessionPoses(const SessionState& s, bool odometry) {
    std::map<int64_t, Pose> poses;
    if (odometry) {
      for (const auto& [key, keyframe] : s.keyframes) {
        PoseFromWire(keyframe.odom_pose, "odom_pose", &poses[key]);
      }
      return poses;
    }
    std::set<int64_t> keys;
    for (const auto& [key, unused] : s.estimate) keys.insert(key);
    for (const auto& [key, unused] : s.keyframes) keys.insert(key);
    Pose previous;
    bool have_previous = false;
    for (int64_t key : keys) {
      Pose pose;
      const auto estimated = s.estimate.find(key);
      const auto heard = s.keyframes.find(key);
      if (estimated != s.estimate.end()) {
        PoseFromWire(estimated->second, "pose", &pose);
      } else if (have_previous && heard != s.keyframes.end() && heard->second.has_odom_edge) {
        Pose delta;
        PoseFromWire(heard->second.odom_delta, "odom_delta", &delta);
        pose = previous * delta;
      }
      previous = pose;
      have_previous = true;
      poses[key] = pose;
    }
    return poses;
  }
  // Complete solutions (every pose and verdict, the answer to a solution_request_t) assembled.
  int complete_solutions() const { return complete_solutions_; }
  const std::vector<double>& latencies_ms() const { return latencies_ms_; }
  const std::vector<double>& decide_ms() const { return decide_ms_; }

 private:
  struct Pending {
    bool have_correction = false;
    correction_t correction;
    std::map<int, verdicts_t> verdicts;
    std::map<int, solution_t> poses;
  };

  bool Kept(int32_t robot) const { return robot_ < 0 || robot == robot_; }

  template <class Message>
  static bool Decode(const lcm::ReceiveBuffer* b, Message* m) {
    return DecodeMessage(b->data, static_cast<int>(b->data_size), m);
  }

  void Complete(int64_t id) {
    auto it = pending_.find(id);
    Pending& p = it->second;
    if (!p.have_correction || static_cast<int>(p.verdicts.size()) < p.correction.n_verdict_chunks ||
        static_cast<int>(p.poses.size()) < p.correction.n_pose_chunks) {
      return;
    }
    const correction_t& c = p.correction;
    for (const session_transform_t& t : c.sessions) {
      if (!Kept(t.robot_id)) continue;
      SessionState& s = sessions_[{t.robot_id, t.session_id}];
      s.component = t.component;
      if (s.transform_solution <= id) {
        s.transform_solution = id;
        s.transform = t;
      }
    }
    for (const auto& [index, chunk] : p.poses) {
      if (!Kept(chunk.robot_id)) continue;
      SessionState& s = sessions_[{chunk.robot_id, chunk.session_id}];
      for (int k = 0; k < chunk.n_poses; ++k) {
        const int64_t key = chunk.first_key + k;
        int64_t& from = s.estimate_solution[key];
        if (from > id) continue;  // a newer solution already placed this key
        from = id;
        s.estimate[key] = chunk.poses[k];
      }
    }
    for (const auto& [index, chunk] : p.verdicts) {
      for (const verdict_t& v : chunk.verdicts) {
        if (!(Kept(v.robot_from) || Kept(v.robot_to))) continue;
        HypothesisState& h = hypotheses_[{v.sender, v.hypothesis_id}];
        if (h.verdict_solution > id) continue;
        h.verdict_solution = id;
        h.verdict = v;
        h.judged = true;
      }
    }
    latest_solution_ = std::max(latest_solution_, id);
    if (c.complete) ++complete_solutions_;
    if (c.step >= 0) {  // a step's correction (step -1: a full one, poses and statistics)
      latest_step_ = std::max(latest_step_, c.step);
      latest_latency_ms_ = 1e-3 * static_cast<double>(c.published_utime - c.closed_utime);
      latencies_ms_.push_back(latest_latency_ms_);
      decide_ms_.push_back(c.decide_ms);
      if (steps_log_ != nullptr) {
        *steps_log_ << fmt::format("{},{},{},{},{},{},{:.3f},{:.3f},{},{},{}\n",
                                   NowUtime(),
                                   c.daemon_start_utime,
                                   id,
                                   c.step,
                                   c.closed_utime,
                                   c.published_utime,
                                   latest_latency_ms_,
                                   c.decide_ms,
                                   c.solves,
                                   c.deferred,
                                   daemon_keyframes_)
                    << std::flush;
      }
    }
    pending_.erase(it);
    // Solutions far behind the newest complete one will not complete any more.
    constexpr int64_t kKeepIncomplete = 100;
    while (!pending_.empty() && pending_.begin()->first < latest_solution_ - kKeepIncomplete) {
      pending_.erase(pending_.begin());
      ++incomplete_;
    }
  }

  const int32_t robot_;
  std::map<SessionName, SessionState> sessions_;
  std::map<HypothesisName, HypothesisState> hypotheses_;
  std::map<int64_t, Pending> pending_;
  int64_t daemon_start_utime_ = 0;
  int64_t latest_solution_ = 0;
  int latest_step_ = -1;
  double latest_latency_ms_ = 0.0;
  int incomplete_ = 0;
  int complete_solutions_ = 0;
  std::vector<double> latencies_ms_;
  std::vector<double> decide_ms_;
  int64_t daemon_keyframes_ = 0;  // the latest status_t's n_keyframes
  std::ostream* steps_log_ = nullptr;
  std::ostream* status_log_ = nullptr;
};

struct Arguments {
  std::string lcm_url;
  std::string output;
  std::string decisions;
  std::string transforms;
  std::string plot;
  int32_t robot = -1;
  double idle_exit_s = 0.0;
  double final_wait_s = 5.0;
  std::string config;
  std::string labels;
  std::string steps_csv;
  std::string status_csv;
};

// "<what> over N steps: p50 .. ms, p90 .., p99 .., max .." (nothing for no steps).
void PrintPercentiles(const std::string& what, std::vector<double> values_ms) {
  if (values_ms.empty()) return;
  std::sort(values_ms.begin(), values_ms.end());
  auto at = [&](double q) {
    const size_t rank = static_cast<size_t>(std::ceil(q * values_ms.size()));
    return values_ms[std::min(values_ms.size(), std::max<size_t>(rank, 1)) - 1];
  };
  fmt::print("{} over {} steps: p50 {:.1f} ms, p90 {:.1f} ms, p99 {:.1f} ms, max {:.1f} ms\n",
             what,
             values_ms.size(),
             at(0.50),
             at(0.90),
             at(0.99),
             values_ms.back());
}

template <class Pose>
Status WriteMap(const Listener& listener, const std::string& path) {
  const GraphFile<Pose> map = listener.Map<Pose>();
  return WriteFileAtomically(
      path, [&](std::ostream& out) { return WriteGraphFile(out, FormatForPath(path), map); });
}

// The map with every verdict, the keyframes' odometry beside it, and the time of each step
// (plots.h; SE(3) when the daemon had SE(3) sessions).
template <class Pose>
Status WritePlots(const std::string& path,
                  const Listener& listener,
                  std::vector<std::string>* written) {
  const PlotFiles files = PlotFilesFor(path);
  const MapPlot map = listener.Plot<Pose>("irrrd's map", /*initial=*/false);
  const MapPlot odometry = listener.Plot<Pose>("odometry", /*initial=*/true);
  const std::pair<std::string, std::string> plots[] = {
      {files.map, MapSvg(map)},
      {files.before_after, BeforeAfterSvg(odometry, map)},
      {files.steps, StepTimeSvg("irrrd: time to decide each step", listener.step_decide_ms())},
  };
  for (const auto& [file, svg] : plots) {
    if (Status s = WritePlot(file, svg); !s.ok()) return s;
    written->push_back(file);
  }
  return Status::Ok();
}

int WriteOutputs(const Arguments& args, const Listener& listener) {
  int code = EX_OK;
  if (!args.labels.empty()) {
    std::ifstream in(args.labels);
    std::vector<LabelRow> labels;
    Scores scores;
    Status s = in ? ReadLabelsCsv(in, &labels) : Status::Error("cannot open");
    if (s.ok()) s = ScoreDecisions(labels, listener.DecisionRows(), &scores);
    if (s.ok()) {
      fmt::print("scores    against {}: {}\n", args.labels, FormatScores(scores));
    } else {
      fmt::print(stderr, "irrr-listen: {}: {}\n", args.labels, s.message());
      code = EX_DATAERR;
    }
  }
  if (!args.decisions.empty()) {
    const std::vector<DecisionRow> rows = listener.DecisionRows();
    if (Status s = WriteFileAtomically(
            args.decisions, [&](std::ostream& out) { return WriteDecisionsCsv(out, rows); });
        !s.ok()) {
      fmt::print(stderr, "irrr-listen: {}\n", s.message());
      code = EX_CANTCREAT;
    } else {
      fmt::print("decisions {} ({} hypotheses)\n", args.decisions, rows.size());
    }
  }
  if (!args.transforms.empty()) {
    if (Status s = WriteFileAtomically(
            args.transforms, [&](std::ostream& out) { return listener.WriteTransforms(out); });
        !s.ok()) {
      fmt::print(stderr, "irrr-listen: {}\n", s.message());
      code = EX_CANTCREAT;
    } else {
      fmt::print("transforms {}\n", args.transforms);
    }
  }
  if (!args.plot.empty()) {
    const bool se3 = listener.HasDimension(keyframe_t::DIM_SE3);
    std::vector<std::string> written;
    if (Status s = se3 ? WritePlots<Pose3>(args.plot, listener, &written)
                       : WritePlots<Pose2>(args.plot, listener, &written);
        !s.ok()) {
      fmt::print(stderr, "irrr-listen: {}\n", s.message());
      code = EX_CANTCREAT;
    } else {
      fmt::print("plots     {}\n", fmt::join(written, ", "));
    }
  }
  if (!args.output.empty()) {
    const bool se2 = listener.HasDimension(keyframe_t::DIM_SE2);
    const bool se3 = listener.HasDimension(keyframe_t::DIM_SE3);
    Status s = Status::Ok();
    if (se2 && se3) {
      s = Status::Error(args.output + ": SE(2) and SE(3) sessions cannot share one file");
    } else {
      s = se3 ? WriteMap<Pose3>(listener, args.output) : WriteMap<Pose2>(listener, args.output);
    }
    if (!s.ok()) {
      fmt::print(stderr, "irrr-listen: {}\n", s.message());
      code = EX_CANTCREAT;
    } else {
      fmt::print("output    {}\n", args.output);
    }
  }
  return code;
}

int Run(Arguments args) {
  DaemonOptions daemon;
  if (Status s = LoadClientConfig(args.config, &daemon, &args.lcm_url); !s.ok()) {
    fmt::print(stderr, "irrr-listen: {}\n", s.message());
    return EX_CONFIG;
  }
  const DaemonChannels& channels = daemon.channels;
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  // A shell starts background jobs with SIGINT ignored, and an ignored signal never reaches a
  // signalfd: take the default disposition back before blocking.
  for (int signal_number : {SIGTERM, SIGINT, SIGHUP}) {
    if (sigismember(&signals, signal_number)) std::signal(signal_number, SIG_DFL);
  }
  sigprocmask(SIG_BLOCK, &signals, nullptr);
  const int signal_fd = signalfd(-1, &signals, SFD_CLOEXEC);

  lcm::LCM lcm(args.lcm_url);
  if (!lcm.good()) {
    fmt::print(stderr, "irrr-listen: cannot open LCM at \"{}\"\n", args.lcm_url);
    return EX_UNAVAILABLE;
  }
  Listener listener(args.robot);
  std::ofstream steps_log;
  std::ofstream status_log;
  for (auto [path, log] :
       {std::pair{&args.steps_csv, &steps_log}, {&args.status_csv, &status_log}}) {
    if (path->empty()) continue;
    log->open(*path);
    if (!*log) {
      fmt::print(stderr, "irrr-listen: cannot write {}\n", *path);
      return EX_CANTCREAT;
    }
  }
  listener.LogTo(args.steps_csv.empty() ? nullptr : &steps_log,
                 args.status_csv.empty() ? nullptr : &status_log);
  // LCM drops what a subscription has queued beyond its capacity (default 30 messages).
  constexpr int kLcmQueueCapacity = 100000;
  using Handler = void (Listener::*)(const lcm::ReceiveBuffer*, const std::string&);
  const std::pair<std::string, Handler> handlers[] = {
      {channels.keyframe, &Listener::OnKeyframe},
      {channels.loop, &Listener::OnLoop},
      {channels.correction, &Listener::OnCorrection},
      {channels.verdicts, &Listener::OnVerdicts},
      {channels.solution, &Listener::OnSolution},
      {channels.status, &Listener::OnStatus},
  };
  // The status is heard only for the CSVs: a heartbeat must not keep --idle-exit from firing.
  const bool hear_status = !args.steps_csv.empty() || !args.status_csv.empty();
  std::vector<std::unique_ptr<RawSubscription>> subscriptions;
  for (const auto& [channel, handler] : handlers) {
    if (channel == channels.status && !hear_status) continue;
    subscriptions.push_back(std::make_unique<RawSubscription>(
        &lcm,
        channel,
        [&listener, handler = handler](const lcm::ReceiveBuffer& b, const std::string& c) {
          (listener.*handler)(&b, c);
        },
        kLcmQueueCapacity));
  }

  // The daemon's whole solution: asked for at start (it may have been running for a while) and
  // before writing (packets may have been lost).
  int64_t requests = 0;
  auto request_solution = [&](const char* reason) {
    solution_request_t request{};
    request.header = {NowUtime(), requests++, "irrr-listen"};
    request.reason = reason;
    const std::vector<uint8_t> bytes = EncodeMessage(request);
    lcm.publish(channels.solution_request, bytes.data(), static_cast<unsigned>(bytes.size()));
  };
  request_solution("irrr-listen started");

  const bool tty = isatty(STDOUT_FILENO) != 0;
  using Clock = std::chrono::steady_clock;
  auto last_message = Clock::now();
  bool heard = false;
  int64_t shown_solution = -1;
  auto shown = Clock::now();
  for (;;) {
    pollfd fds[2] = {{lcm.getFileno(), POLLIN, 0}, {signal_fd, POLLIN, 0}};
    poll(fds, 2, 100);
    if (fds[1].revents & POLLIN) break;
    if (fds[0].revents & POLLIN) {
      lcm.handle();
      last_message = Clock::now();
      heard = true;
    }
    const auto now = Clock::now();
    if (listener.latest_solution() != shown_solution &&
        now - shown > std::chrono::milliseconds(tty ? 100 : 5000)) {
      fmt::print("{}{}{}", tty ? "\r" : "", listener.Summary(), tty ? "\033[K" : "\n");
      std::fflush(stdout);
      shown_solution = listener.latest_solution();
      shown = now;
    }
    if (args.idle_exit_s > 0 && heard &&
        now - last_message > std::chrono::duration<double>(args.idle_exit_s)) {
      break;
    }
  }
  while (lcm.handleTimeout(0) > 0) {
  }
  if (heard && args.final_wait_s > 0) {
    // Ask again until a complete solution arrives (each try may lose a chunk).
    const int before = listener.complete_solutions();
    const auto give_up = Clock::now() + std::chrono::duration<double>(args.final_wait_s);
    auto asked = Clock::now() - std::chrono::seconds(1);
    while (listener.complete_solutions() == before && Clock::now() < give_up) {
      if (Clock::now() - asked > std::chrono::milliseconds(300)) {
        request_solution("irrr-listen writing its outputs");
        asked = Clock::now();
      }
      lcm.handleTimeout(20);
    }
    if (listener.complete_solutions() == before) {
      fmt::print(stderr,
                 "\nirrr-listen: no complete solution from the daemon within {} s: writing what "
                 "was heard\n",
                 args.final_wait_s);
    }
  }
  fmt::print("{}{}\n", tty ? "\r" : "", listener.Summary());
  PrintPercentiles("latency   step (cluster closed -> correction published)",
                   listener.latencies_ms());
  PrintPercentiles("decide    step (deciding and optimizing, without queueing)",
                   listener.decide_ms());
  return WriteOutputs(args, listener);
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  irrr::Arguments args;
  CLI::App app{"irrr-listen: keep irrrd's latest map and verdicts, write them on exit"};
  app.add_option(
      "--lcm-url",
      args.lcm_url,
      "LCM URL (default: the --config file's daemon.lcm_url, else LCM_DEFAULT_URL or LCM's)");
  app.add_option("--output", args.output, "write the map here on exit (g2o; TORO for *.graph)");
  app.add_option("--decisions", args.decisions, "write the decisions CSV here on exit");
  app.add_option(
      "--transforms", args.transforms, "write each session's latest map_T_odom (CSV) here on exit");
  app.add_option("--plot",
                 args.plot,
                 "on exit, draw the map with every verdict here (SVG, or PNG with rsvg-convert), "
                 "and beside it the odometry and the time per step");
  app.add_option("--robot",
                 args.robot,
                 "keep only this robot's sessions and the hypotheses that touch them")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--idle-exit",
                 args.idle_exit_s,
                 "exit this many seconds after the last message (0: only on SIGINT/SIGTERM)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--final-wait",
                 args.final_wait_s,
                 "before writing, ask the daemon for its whole solution and wait this many seconds "
                 "for it (0: do not ask)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--config", args.config, "the daemon's JSON configuration (for channel names)");
  app.add_option("--labels",
                 args.labels,
                 "irrr-corrupt's labels (single robot: edge_index = hypothesis_id): print "
                 "precision and recall on exit");
  app.add_option("--steps-csv",
                 args.steps_csv,
                 "while running, write one row per step correction here (latency, decide time, the "
                 "daemon's keyframes by then)");
  app.add_option("--status-csv",
                 args.status_csv,
                 "while running, write one row per status_t heard here (counts, queue depth, "
                 "latest step latency)");
  app.footer(
      "Exit codes: 0 ok, 64 usage, 65 bad labels, 69 LCM unavailable, 73 output not "
      "written, 78 bad configuration.");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? EX_OK : EX_USAGE;
  }
  return irrr::Run(args);
}
