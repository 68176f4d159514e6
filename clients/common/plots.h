#ifndef IRRR_CLIENTS_COMMON_PLOTS_H_
#define IRRR_CLIENTS_COMMON_PLOTS_H_

// Plots of a multi-session pose graph and of iRRR's decisions, as standalone SVG documents
// (irrr-plot, and --plot of irrr-batch and irrr-listen), after the paper's figures:
//  - the map: one path per session, each in its colour; accepted loops solid green, rejected ones
//    dashed red, reversed ones dotted orange; ground truth thin grey underneath; a legend. 3D maps
//    get a top-down (x-y) and a side (x-z) view.
//  - before / after: the input's initial guess beside the optimized map;
//  - the time of every iRRR step against the step number (Fig. 2(c));
//  - the distribution of the absolute trajectory error where ground truth exists (Fig. 1(e)).
// Elements carry classes a test (or a stylesheet) can select: "session", "ground-truth",
// "loop accepted" / "loop rejected" / "loop reversed" / "loop pending", "legend", "bar", "step".

#include <string>
#include <vector>

#include "core/irrr.h"
#include "core/pose_graph.h"

namespace irrr {

struct PlotPoint {
  double x = 0.0;
  double y = 0.0;
  double z = 0.0;
};

struct PlotLoop {
  PlotPoint from;
  PlotPoint to;
  LoopState state = LoopState::kPending;
};

struct MapPlot {
  std::string title;
  bool three_d = false;
  std::vector<std::string> session_names;
  std::vector<std::vector<PlotPoint>> sessions;      // poses in time order
  std::vector<std::vector<PlotPoint>> ground_truth;  // per session, or empty
  std::vector<PlotLoop> loops;
};

// Where a pose is, for a plot.
template <class Pose>
PlotPoint ToPlotPoint(const Pose& pose) {
  PlotPoint p;
  p.x = pose.translation()[0];
  p.y = pose.translation()[1];
  if constexpr (Pose::kTranslationDim == 3) p.z = pose.translation()[2];
  return p;
}

// A MapPlot of `graph` at `poses` (one per vertex): sessions by index, every loop edge with its
// decision (`decisions` per edge; empty: every loop pending), ground truth if not empty.
template <class Pose>
MapPlot MakeMapPlot(const std::string& title,
                    const PoseGraph<Pose>& graph,
                    const std::vector<Pose>& poses,
                    const std::vector<LoopDecision>& decisions,
                    const std::vector<Pose>& ground_truth);

std::string MapSvg(const MapPlot& map);
std::string BeforeAfterSvg(const MapPlot& before, const MapPlot& after);
// Milliseconds of each step, in step order.
std::string StepTimeSvg(const std::string& title, const std::vector<double>& step_ms);
// Per-pose absolute trajectory errors (m): a histogram.
std::string AteSvg(const std::string& title, const std::vector<double>& errors_m);

// Named (x, y) points: one series of a chart.
struct ChartSeries {
  std::string name;
  std::vector<std::pair<double, double>> points;
};
// y against x, one colour per series (named in a legend), each point a dot; both axes from 0
// (or below, for negative data).
std::string ChartSvg(const std::string& title,
                     const std::string& x_label,
                     const std::string& y_label,
                     const std::vector<ChartSeries>& series);

// Writes `svg` to `path`; when `path` ends in .png, writes the SVG beside it (same stem) and
// converts it with rsvg-convert (error if that is not installed).
Status WritePlot(const std::string& path, const std::string& svg);

// The files `--plot FILE` writes: FILE (the map), and beside it <stem>_before_after, <stem>_steps
// and <stem>_ate (each only when it has data), with FILE's extension.
struct PlotFiles {
  std::string map, before_after, steps, ate;
};
PlotFiles PlotFilesFor(const std::string& path);

// Every plot of a decided graph, to the files of PlotFilesFor(path): the map at `estimate` with
// `decisions` (and `ground_truth`, aligned at the first pose, when not empty), the initial guess
// beside it, the time per step (`step_ms`, when not empty) and the ATE histogram (with ground
// truth). `written` receives the paths.
template <class Pose>
Status WriteGraphPlots(const std::string& path,
                       const std::string& title,
                       const PoseGraph<Pose>& graph,
                       const std::vector<Pose>& estimate,
                       const std::vector<LoopDecision>& decisions,
                       const std::vector<Pose>& ground_truth,
                       const std::vector<double>& step_ms,
                       std::vector<std::string>* written);

extern template MapPlot MakeMapPlot(const std::string&,
                                    const PoseGraph<Pose2>&,
                                    const std::vector<Pose2>&,
                                    const std::vector<LoopDecision>&,
                                    const std::vector<Pose2>&);
extern template MapPlot MakeMapPlot(const std::string&,
                                    const PoseGraph<Pose3>&,
                                    const std::vector<Pose3>&,
                                    const std::vector<LoopDecision>&,
                                    const std::vector<Pose3>&);
extern template Status WriteGraphPlots(const std::string&,
                                       const std::string&,
                                       const PoseGraph<Pose2>&,
                                       const std::vector<Pose2>&,
                                       const std::vector<LoopDecision>&,
                                       const std::vector<Pose2>&,
                                       const std::vector<double>&,
                                       std::vector<std::string>*);
extern template Status WriteGraphPlots(const std::string&,
                                       const std::string&,
                                       const PoseGraph<Pose3>&,
                                       const std::vector<Pose3>&,
                                       const std::vector<LoopDecision>&,
                                       const std::vector<Pose3>&,
                                       const std::vector<double>&,
                                       std::vector<std::string>*);

}  // namespace irrr

#endif  // IRRR_CLIENTS_COMMON_PLOTS_H_
