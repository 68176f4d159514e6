#ifndef IRRR_CLIENTS_COMMON_PROGRESS_LINE_H_
#define IRRR_CLIENTS_COMMON_PROGRESS_LINE_H_

// One line of progress for the tools' long runs (irrr-inject, irrr-batch, the benchmarks), drawn
// in place on stderr (carriage return, then the text, then erase-to-end-of-line) when stderr is a
// terminal, and nothing at all when it is not: logs, pipes and the tests see exactly what they saw
// before. The tools' results still go to stdout. Core prints nothing: the tools feed these from
// their own loops (a graph replayed event by event, RunStep called by the tool).

#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdio>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
#include <utility>

#include <fmt/core.h>

#include "core/irrr.h"
#include "core/pose_graph.h"

namespace irrr {

class ProgressLine {
 public:
  // At most this often a redraw (Update); faster ones are skipped.
  static constexpr std::chrono::milliseconds kRedrawPeriod{100};

  // Draws on `stream` when it is a terminal (isatty of its descriptor).
  explicit ProgressLine(std::FILE* stream = stderr);
  // Draws on `stream` when `enabled`, terminal or not (for tests).
  ProgressLine(std::FILE* stream, bool enabled);
  // Erases what is left drawn (Clear).
  ~ProgressLine();
  ProgressLine(const ProgressLine&) = delete;
  ProgressLine& operator=(const ProgressLine&) = delete;

  bool enabled() const { return enabled_; }
  // Whether Update would draw now: enabled, and kRedrawPeriod passed since the last drawing.
  bool Due() const;
  // Draws `text` over the line if Due() or `force`; otherwise nothing.
  void Update(const std::string& text, bool force = false);
  // Draws `text` and ends the line with a newline, so that it stays (enabled only).
  void Finish(const std::string& text);
  // Erases the line if something is drawn on it (enabled only).
  void Clear();

 private:
  std::FILE* stream_;
  bool enabled_;
  bool drawn_ = false;
  std::chrono::steady_clock::time_point last_{};
};

// "[#####.........]": `done` of `total` as `width` characters between brackets (total 0: full).
std::string ProgressBar(size_t done, size_t total, int width);

// Seconds as "12.3 s" below a minute, "4 min 05 s" above.
std::string FormatElapsed(double seconds);

// For work that reports nothing while it runs (one batch RRR call, one solve): redraws
// "<label>, <elapsed>" on `line` once a second from a thread of its own, until destroyed (which
// clears the line). No thread when the line is disabled. `line` is not used by anyone else
// meanwhile.
class ElapsedTicker {
 public:
  ElapsedTicker(std::string label, ProgressLine* line);
  ~ElapsedTicker();
  ElapsedTicker(const ElapsedTicker&) = delete;
  ElapsedTicker& operator=(const ElapsedTicker&) = delete;

 private:
  std::string label_;
  ProgressLine* line_;
  std::mutex mutex_;
  std::condition_variable stop_changed_;
  bool stop_ = false;
  std::thread thread_;
};

// The progress of a pose graph replayed through an Irrr in arrival order (ArrivalOrder), as a
// tool replays it: poses and hypotheses fed so far of the graph's, steps run, loops accepted and
// rejected (or reversed) so far, and the time since construction:
//   "iRRR: pose 1200/3500, 340/1100 hypotheses, 87 steps, 300 accepted, 12 rejected, 34.2 s"
// Count each event with Fed, then call Show after it and after each step: it redraws at most
// every ProgressLine::kRedrawPeriod and costs nothing when the line is disabled.
template <class Pose>
class ReplayProgress {
 public:
  ReplayProgress(const PoseGraph<Pose>& graph, std::string label, ProgressLine* line)
      : label_(std::move(label)),
        line_(line),
        poses_(graph.num_vertices()),
        start_(std::chrono::steady_clock::now()) {
    for (const Edge<Pose>& e : graph.edges()) loops_ += e.kind == EdgeKind::kLoop ? 1 : 0;
  }

  void Fed(const ArrivalEvent& event) {
    poses_in_ += event.kind == ArrivalEvent::Kind::kPose ? 1 : 0;
    loops_in_ += event.kind == ArrivalEvent::Kind::kLoop ? 1 : 0;
  }

  void Show(const Irrr<Pose>& irrr) {
    if (line_->Due()) line_->Update(Text(irrr));
  }

  int poses_in() const { return poses_in_; }

  std::string Text(const Irrr<Pose>& irrr) const {
    int accepted = 0;
    int rejected = 0;
    for (int e = 0; e < irrr.graph().num_edges(); ++e) {
      const LoopState state = irrr.decision(e).state;
      accepted += state == LoopState::kAccepted ? 1 : 0;
      rejected += state != LoopState::kAccepted && state != LoopState::kPending ? 1 : 0;
    }
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    return fmt::format("{}: pose {}/{}, {}/{} hypotheses, {} steps, {} accepted, {} rejected, {}",
                       label_,
                       poses_in_,
                       poses_,
                       loops_in_,
                       loops_,
                       irrr.num_steps(),
                       accepted,
                       rejected,
                       FormatElapsed(seconds));
  }

 private:
  std::string label_;
  ProgressLine* line_;
  int poses_ = 0;
  int loops_ = 0;
  int poses_in_ = 0;
  int loops_in_ = 0;
  std::chrono::steady_clock::time_point start_;
};

// RunIncrementalIrrr's replay of `graph` through `replay` into `irrr` (arrival order, every step
// run as soon as it is due, then a flush and its steps), drawn on `progress`; `on_step(step, ms)`
// after each step with its wall time returns whether to go on. Returns false when it stopped the
// replay (before the flush).
template <class Pose>
bool ReplayTimed(const PoseGraph<Pose>& graph,
                 Irrr<Pose>* irrr,
                 GraphReplay<Pose>* replay,
                 ReplayProgress<Pose>* progress,
                 const std::function<bool(const StepResult&, double)>& on_step) {
  bool going = true;
  auto run_steps = [&]() {
    while (going && irrr->HasPendingStep()) {
      const auto start = std::chrono::steady_clock::now();
      const StepResult step = irrr->RunStep();
      going = on_step(
          step,
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start)
              .count());
      progress->Show(*irrr);
    }
  };
  for (const ArrivalEvent& event : ArrivalOrder(graph)) {
    if (!going) return false;
    replay->Apply(event);
    progress->Fed(event);
    progress->Show(*irrr);
    run_steps();
  }
  if (!going) return false;
  irrr->Flush();
  run_steps();
  return going;
}

}  // namespace irrr

#endif  // IRRR_CLIENTS_COMMON_PROGRESS_LINE_H_
