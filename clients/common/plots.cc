#include "clients/common/plots.h"

#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <limits>
#include <utility>

#include <fmt/core.h>

#include "clients/common/graph_files.h"
#include "core/trajectory_metrics.h"

namespace irrr {
namespace {

// Sessions: blues, purples and browns, so that green, red and orange stay the loops' own.
const char* const kSessionColours[] = {"#1f77b4",
                                       "#9467bd",
                                       "#8c564b",
                                       "#e377c2",
                                       "#17becf",
                                       "#393b79",
                                       "#bcbd22",
                                       "#7b4173",
                                       "#637939",
                                       "#843c39"};

struct LoopStyle {
  const char* name;  // class and legend
  const char* colour;
  const char* dash;
  double width;
};

LoopStyle StyleOf(LoopState state) {
  switch (state) {
    case LoopState::kAccepted:
      return {"accepted", "#2ca02c", "", 1.2};
    case LoopState::kReversed:
      return {"reversed", "#ff7f0e", "2,2", 1.2};
    case LoopState::kPending:
      return {"pending", "#aaaaaa", "1,3", 0.6};
    case LoopState::kRejectedLinkTest:
    case LoopState::kRejectedClusterTest:
    case LoopState::kRejectedJointTest:
      break;
  }
  return {"rejected", "#d62728", "5,3", 0.9};
}

std::string Escape(const std::string& text) {
  std::string out;
  for (char c : text) {
    switch (c) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

// A document built element by element.
class Svg {
 public:
  Svg(double width, double height) : width_(width), height_(height) {}
  void Add(const std::string& element) { body_ += element + "\n"; }
  void Text(double x,
            double y,
            const std::string& text,
            double size = 12,
            const char* anchor = "start",
            const char* cls = "label") {
    Add(fmt::format(
        R"(<text class="{}" x="{:.1f}" y="{:.1f}" font-size="{}" text-anchor="{}">{}</text>)",
        cls,
        x,
        y,
        size,
        anchor,
        Escape(text)));
  }
  std::string Finish() const {
    return fmt::format(
               R"(<?xml version="1.0" encoding="UTF-8"?>
<svg xmlns="http://www.w3.org/2000/svg" width="{0:.0f}" height="{1:.0f}" viewBox="0 0 {0:.0f} {1:.0f}" font-family="sans-serif">
<rect x="0" y="0" width="{0:.0f}" height="{1:.0f}" fill="white"/>
)",
               width_,
               height_) +
           body_ + "</svg>\n";
  }

 private:
  double width_;
  double height_;
  std::string body_;
};

// Data coordinates (y up) to a pixel box (y down).
struct Frame {
  double left = 0, top = 0, width = 1, height = 1;
  double min_x = 0, min_y = 0, scale_x = 1, scale_y = 1;

  // Fits [min_x, max_x] x [min_y, max_y] into the box, with the same scale on both axes when
  // `equal` (maps), centred.
  static Frame Fit(double min_x,
                   double max_x,
                   double min_y,
                   double max_y,
                   double left,
                   double top,
                   double width,
                   double height,
                   bool equal) {
    Frame f{left, top, width, height, min_x, min_y, 1, 1};
    const double span_x = std::max(max_x - min_x, 1e-9);
    const double span_y = std::max(max_y - min_y, 1e-9);
    f.scale_x = width / span_x;
    f.scale_y = height / span_y;
    if (equal) {
      const double s = std::min(f.scale_x, f.scale_y);
      f.min_x -= 0.5 * (width / s - span_x);
      f.min_y -= 0.5 * (height / s - span_y);
      f.scale_x = f.scale_y = s;
    }
    return f;
  }
  double X(double x) const { return left + (x - min_x) * scale_x; }
  double Y(double y) const { return top + height - (y - min_y) * scale_y; }
};

std::string Polyline(const std::vector<std::pair<double, double>>& points,
                     const std::string& cls,
                     const std::string& colour,
                     double width,
                     const std::string& extra = "") {
  std::string d;
  for (size_t k = 0; k < points.size(); ++k) {
    d += fmt::format("{}{:.1f},{:.1f}", k == 0 ? "M" : " L", points[k].first, points[k].second);
  }
  return fmt::format(R"(<path class="{}" d="{}" fill="none" stroke="{}" stroke-width="{}"{}/>)",
                     cls,
                     d,
                     colour,
                     width,
                     extra);
}

enum class View { kTop, kSide };  // x-y, or x-z

std::pair<double, double> Project(const PlotPoint& p, View view) {
  return {p.x, view == View::kTop ? p.y : p.z};
}

// One view of a map in the box (left, top, width, height).
void DrawMap(const MapPlot& map,
             View view,
             double left,
             double top,
             double width,
             double height,
             const std::string& caption,
             Svg* svg) {
  double min_x = std::numeric_limits<double>::infinity(), max_x = -min_x, min_y = min_x,
         max_y = -min_x;
  auto extend = [&](const PlotPoint& p) {
    const auto [x, y] = Project(p, view);
    min_x = std::min(min_x, x), max_x = std::max(max_x, x);
    min_y = std::min(min_y, y), max_y = std::max(max_y, y);
  };
  for (const auto& session : map.sessions) std::for_each(session.begin(), session.end(), extend);
  for (const auto& session : map.ground_truth) {
    std::for_each(session.begin(), session.end(), extend);
  }
  if (!(min_x <= max_x)) min_x = max_x = min_y = max_y = 0.0;
  const double margin = 10;
  const Frame f = Frame::Fit(min_x,
                             max_x,
                             min_y,
                             max_y,
                             left + margin,
                             top + margin + 16,
                             width - 2 * margin,
                             height - 2 * margin - 16,
                             true);
  svg->Text(left + width / 2, top + 14, caption, 13, "middle", "caption");
  svg->Add(fmt::format(
      R"(<rect x="{:.1f}" y="{:.1f}" width="{:.1f}" height="{:.1f}" fill="none" stroke="#cccccc"/>)",
      left,
      top,
      width,
      height));
  auto pixels = [&](const std::vector<PlotPoint>& points) {
    std::vector<std::pair<double, double>> out;
    for (const PlotPoint& p : points) {
      const auto [x, y] = Project(p, view);
      out.emplace_back(f.X(x), f.Y(y));
    }
    return out;
  };
  for (const auto& session : map.ground_truth) {
    if (!session.empty()) svg->Add(Polyline(pixels(session), "ground-truth", "#bbbbbb", 2.5));
  }
  for (size_t s = 0; s < map.sessions.size(); ++s) {
    const std::string name = s < map.session_names.size() ? map.session_names[s] : "";
    svg->Add(Polyline(pixels(map.sessions[s]),
                      "session",
                      kSessionColours[s % std::size(kSessionColours)],
                      1.2,
                      " data-session=\"" + Escape(name) + "\""));
  }
  // Pending and rejected under reversed under accepted.
  for (LoopState first : {LoopState::kPending,
                          LoopState::kRejectedJointTest,
                          LoopState::kReversed,
                          LoopState::kAccepted}) {
    for (const PlotLoop& loop : map.loops) {
      const LoopStyle style = StyleOf(loop.state);
      if (std::string(style.name) != StyleOf(first).name) continue;
      const auto [x1, y1] = Project(loop.from, view);
      const auto [x2, y2] = Project(loop.to, view);
      svg->Add(fmt::format(
          R"(<line class="loop {}" x1="{:.1f}" y1="{:.1f}" x2="{:.1f}" y2="{:.1f}" stroke="{}" stroke-width="{}"{}/>)",
          style.name,
          f.X(x1),
          f.Y(y1),
          f.X(x2),
          f.Y(y2),
          style.colour,
          style.width,
          *style.dash ? fmt::format(R"( stroke-dasharray="{}")", style.dash) : ""));
    }
  }
}

// Sessions and loop kinds with their counts, top left of the box.
void DrawLegend(const MapPlot& map, double left, double top, Svg* svg) {
  std::vector<std::pair<std::string, std::string>> entries;  // colour|dash, label
  svg->Add(R"(<g class="legend">)");
  double y = top;
  auto entry = [&](const std::string& colour,
                   const std::string& dash,
                   double width,
                   const std::string& label) {
    svg->Add(fmt::format(
        R"(<line class="legend-swatch" x1="{:.1f}" y1="{:.1f}" x2="{:.1f}" y2="{:.1f}" stroke="{}" stroke-width="{}"{}/>)",
        left,
        y - 4,
        left + 24,
        y - 4,
        colour,
        width + 1,
        dash.empty() ? "" : fmt::format(R"( stroke-dasharray="{}")", dash)));
    svg->Text(left + 30, y, label, 11);
    y += 15;
  };
  for (size_t s = 0; s < map.sessions.size(); ++s) {
    entry(kSessionColours[s % std::size(kSessionColours)],
          "",
          1.2,
          s < map.session_names.size() ? map.session_names[s] : "session " + std::to_string(s));
  }
  if (!map.ground_truth.empty()) entry("#bbbbbb", "", 2.5, "ground truth");
  for (LoopState state : {LoopState::kAccepted,
                          LoopState::kRejectedJointTest,
                          LoopState::kReversed,
                          LoopState::kPending}) {
    const LoopStyle style = StyleOf(state);
    int count = 0;
    for (const PlotLoop& loop : map.loops)
      count += std::string(StyleOf(loop.state).name) == style.name;
    if (count == 0 && state == LoopState::kPending) continue;
    entry(style.colour, style.dash, style.width, fmt::format("{} loops ({})", style.name, count));
  }
  svg->Add("</g>");
}

// Axes for a chart in the box: frame, ticks at the ends and the middle, labels.
void DrawAxes(const Frame& f,
              double max_x,
              double max_y,
              const std::string& x_label,
              const std::string& y_label,
              Svg* svg) {
  svg->Add(fmt::format(
      R"(<rect class="axes" x="{:.1f}" y="{:.1f}" width="{:.1f}" height="{:.1f}" fill="none" stroke="black"/>)",
      f.left,
      f.top,
      f.width,
      f.height));
  for (double t : {0.0, 0.5, 1.0}) {
    svg->Text(f.X(f.min_x + t * (max_x - f.min_x)),
              f.top + f.height + 16,
              fmt::format("{:.4g}", f.min_x + t * (max_x - f.min_x)),
              11,
              "middle");
    svg->Text(f.left - 6,
              f.Y(f.min_y + t * (max_y - f.min_y)) + 4,
              fmt::format("{:.4g}", f.min_y + t * (max_y - f.min_y)),
              11,
              "end");
  }
  svg->Text(f.left + f.width / 2, f.top + f.height + 36, x_label, 12, "middle");
  svg->Add(fmt::format(
      R"svg(<text class="label" x="{0:.1f}" y="{1:.1f}" font-size="12" text-anchor="middle" transform="rotate(-90 {0:.1f} {1:.1f})">{2}</text>)svg",
      f.left - 50,
      f.top + f.height / 2,
      Escape(y_label)));
}

}  // namespace

template <class Pose>
MapPlot MakeMapPlot(const std::string& title,
                    const PoseGraph<Pose>& graph,
                    const std::vector<Pose>& poses,
                    const std::vector<LoopDecision>& decisions,
                    const std::vector<Pose>& ground_truth) {
  MapPlot map;
  map.title = title;
  map.three_d = Pose::kTranslationDim == 3;
  for (int s = 0; s < graph.num_sessions(); ++s) {
    map.session_names.push_back("session " + std::to_string(graph.session(s).id));
    std::vector<PlotPoint> path;
    std::vector<PlotPoint> truth;
    for (int v : graph.session(s).vertices) {
      path.push_back(ToPlotPoint(poses[v]));
      if (!ground_truth.empty()) truth.push_back(ToPlotPoint(ground_truth[v]));
    }
    map.sessions.push_back(std::move(path));
    if (!ground_truth.empty()) map.ground_truth.push_back(std::move(truth));
  }
  for (int e = 0; e < graph.num_edges(); ++e) {
    const Edge<Pose>& edge = graph.edge(e);
    if (edge.kind != EdgeKind::kLoop) continue;
    PlotLoop loop;
    loop.from = ToPlotPoint(poses[edge.from]);
    loop.to = ToPlotPoint(poses[edge.to]);
    loop.state = decisions.empty() ? LoopState::kPending : decisions[e].state;
    map.loops.push_back(loop);
  }
  return map;
}

std::string MapSvg(const MapPlot& map) {
  const double panel = 700;
  const int views = map.three_d ? 2 : 1;
  Svg svg(panel * views, panel + 30);
  svg.Text(panel * views / 2, 20, map.title, 15, "middle", "title");
  DrawMap(map, View::kTop, 0, 30, panel, panel, map.three_d ? "top view (x-y)" : "", &svg);
  if (map.three_d) DrawMap(map, View::kSide, panel, 30, panel, panel, "side view (x-z)", &svg);
  DrawLegend(map, 16, 66, &svg);
  return svg.Finish();
}

std::string BeforeAfterSvg(const MapPlot& before, const MapPlot& after) {
  const double panel = 600;
  Svg svg(2 * panel, panel + 30);
  svg.Text(panel, 20, after.title, 15, "middle", "title");
  DrawMap(before, View::kTop, 0, 30, panel, panel, "before: " + before.title, &svg);
  DrawMap(after, View::kTop, panel, 30, panel, panel, "after: " + after.title, &svg);
  DrawLegend(after, panel + 16, 66, &svg);
  return svg.Finish();
}

std::string StepTimeSvg(const std::string& title, const std::vector<double>& step_ms) {
  Svg svg(800, 460);
  svg.Text(400, 20, title, 15, "middle", "title");
  const double max_ms = step_ms.empty() ? 1.0 : *std::max_element(step_ms.begin(), step_ms.end());
  const double last = std::max<double>(1.0, static_cast<double>(step_ms.size()) - 1.0);
  const Frame f = Frame::Fit(0, last, 0, std::max(max_ms, 1e-3), 80, 40, 690, 360, false);
  DrawAxes(f, last, std::max(max_ms, 1e-3), "iRRR step", "time per step (ms)", &svg);
  std::vector<std::pair<double, double>> points;
  for (size_t k = 0; k < step_ms.size(); ++k) {
    points.emplace_back(f.X(static_cast<double>(k)), f.Y(step_ms[k]));
  }
  if (!points.empty()) svg.Add(Polyline(points, "step-time", "#1f77b4", 1.0));
  for (const auto& [x, y] : points) {
    svg.Add(fmt::format(
        R"(<circle class="step" cx="{:.1f}" cy="{:.1f}" r="2" fill="#1f77b4"/>)", x, y));
  }
  return svg.Finish();
}

std::string AteSvg(const std::string& title, const std::vector<double>& errors_m) {
  Svg svg(800, 460);
  constexpr int kBins = 20;
  double max_error = 0.0, sum_sq = 0.0, sum = 0.0;
  for (double e : errors_m) max_error = std::max(max_error, e), sum_sq += e * e, sum += e;
  const double n = std::max<double>(1.0, static_cast<double>(errors_m.size()));
  svg.Text(400,
           20,
           fmt::format("{}: ATE rmse {:.3f} m, mean {:.3f} m, max {:.3f} m ({} poses)",
                       title,
                       std::sqrt(sum_sq / n),
                       sum / n,
                       max_error,
                       errors_m.size()),
           14,
           "middle",
           "title");
  const double width = std::max(max_error, 1e-9) / kBins;
  std::vector<int> counts(kBins, 0);
  for (double e : errors_m) ++counts[std::min(kBins - 1, static_cast<int>(e / width))];
  const int highest = std::max(1, *std::max_element(counts.begin(), counts.end()));
  const Frame f = Frame::Fit(0, kBins * width, 0, highest, 80, 40, 690, 360, false);
  DrawAxes(f, kBins * width, highest, "absolute trajectory error (m)", "poses", &svg);
  for (int b = 0; b < kBins; ++b) {
    svg.Add(fmt::format(
        R"(<rect class="bar" x="{:.1f}" y="{:.1f}" width="{:.1f}" height="{:.1f}" fill="#1f77b4" stroke="white"/>)",
        f.X(b * width),
        f.Y(counts[b]),
        f.X((b + 1) * width) - f.X(b * width),
        f.Y(0) - f.Y(counts[b])));
  }
  return svg.Finish();
}

std::string ChartSvg(const std::string& title,
                     const std::string& x_label,
                     const std::string& y_label,
                     const std::vector<ChartSeries>& series) {
  static const char* const kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e", "#9467bd"};
  Svg svg(800, 460);
  svg.Text(400, 20, title, 15, "middle", "title");
  double min_x = 0, max_x = 1e-3, min_y = 0, max_y = 1e-3;
  for (const ChartSeries& s : series) {
    for (const auto& [x, y] : s.points) {
      min_x = std::min(min_x, x), max_x = std::max(max_x, x);
      min_y = std::min(min_y, y), max_y = std::max(max_y, y);
    }
  }
  const Frame f = Frame::Fit(min_x, max_x, min_y, max_y, 80, 40, 690, 360, false);
  DrawAxes(f, max_x, max_y, x_label, y_label, &svg);
  for (size_t k = 0; k < series.size(); ++k) {
    const char* colour = kColours[k % std::size(kColours)];
    for (const auto& [x, y] : series[k].points) {
      svg.Add(fmt::format(R"(<circle class="point" cx="{:.1f}" cy="{:.1f}" r="1.5" fill="{}"/>)",
                          f.X(x),
                          f.Y(y),
                          colour));
    }
    svg.Text(90, 56 + 16 * static_cast<double>(k), series[k].name, 12, "start", "legend");
    svg.Add(fmt::format(
        R"(<circle class="legend" cx="84" cy="{:.1f}" r="4" fill="{}"/>)", 52 + 16.0 * k, colour));
  }
  return svg.Finish();
}

Status WritePlot(const std::string& path, const std::string& svg) {
  const bool png = path.size() > 4 && path.compare(path.size() - 4, 4, ".png") == 0;
  const std::string svg_path = png ? path.substr(0, path.size() - 4) + ".svg" : path;
  if (Status s = WriteFileAtomically(svg_path,
                                     [&](std::ostream& out) {
                                       out << svg;
                                       return out ? Status::Ok() : Status::Error("write failed");
                                     });
      !s.ok()) {
    return s;
  }
  if (!png) return Status::Ok();
  const std::string command =
      "rsvg-convert -o '" + path + "' '" + svg_path + "' 2>/dev/null";  // librsvg2-bin
  const int status = std::system(command.c_str());
  if (status != 0) {
    return Status::Error(path + ": rsvg-convert failed or is not installed (librsvg2-bin); the " +
                         "SVG is in " + svg_path);
  }
  return Status::Ok();
}

PlotFiles PlotFilesFor(const std::string& path) {
  const size_t dot = path.rfind('.');
  const size_t slash = path.rfind('/');
  const bool has_extension =
      dot != std::string::npos && (slash == std::string::npos || dot > slash);
  const std::string stem = has_extension ? path.substr(0, dot) : path;
  const std::string extension = has_extension ? path.substr(dot) : ".svg";
  return {path,
          stem + "_before_after" + extension,
          stem + "_steps" + extension,
          stem + "_ate" + extension};
}

template <class Pose>
Status WriteGraphPlots(const std::string& path,
                       const std::string& title,
                       const PoseGraph<Pose>& graph,
                       const std::vector<Pose>& estimate,
                       const std::vector<LoopDecision>& decisions,
                       const std::vector<Pose>& ground_truth,
                       const std::vector<double>& step_ms,
                       std::vector<std::string>* written) {
  const PlotFiles files = PlotFilesFor(path);
  // Ground truth drawn in the estimate's frame: both aligned at the first pose.
  std::vector<Pose> truth;
  if (!ground_truth.empty() && !estimate.empty()) {
    const Pose align = estimate[0] * ground_truth[0].Inverse();
    for (const Pose& p : ground_truth) truth.push_back(align * p);
  }
  const MapPlot after = MakeMapPlot(title, graph, estimate, decisions, truth);
  auto write = [&](const std::string& file, const std::string& svg) {
    Status s = WritePlot(file, svg);
    if (s.ok()) written->push_back(file);
    return s;
  };
  if (Status s = write(files.map, MapSvg(after)); !s.ok()) return s;
  const MapPlot before = MakeMapPlot("initial guess", graph, graph.initial_estimate(), {}, {});
  if (Status s = write(files.before_after, BeforeAfterSvg(before, after)); !s.ok()) return s;
  if (!step_ms.empty()) {
    if (Status s = write(files.steps, StepTimeSvg(title + ": time per iRRR step", step_ms));
        !s.ok()) {
      return s;
    }
  }
  if (!ground_truth.empty()) {
    const TrajectoryError ate = AbsoluteTrajectoryError(estimate, ground_truth);
    if (Status s = write(files.ate, AteSvg(title, ate.errors_m)); !s.ok()) return s;
  }
  return Status::Ok();
}

template Status WriteGraphPlots(const std::string&,
                                const std::string&,
                                const PoseGraph<Pose2>&,
                                const std::vector<Pose2>&,
                                const std::vector<LoopDecision>&,
                                const std::vector<Pose2>&,
                                const std::vector<double>&,
                                std::vector<std::string>*);
template Status WriteGraphPlots(const std::string&,
                                const std::string&,
                                const PoseGraph<Pose3>&,
                                const std::vector<Pose3>&,
                                const std::vector<LoopDecision>&,
                                const std::vector<Pose3>&,
                                const std::vector<double>&,
                                std::vector<std::string>*);

template MapPlot MakeMapPlot(const std::string&,
                             const PoseGraph<Pose2>&,
                             const std::vector<Pose2>&,
                             const std::vector<LoopDecision>&,
                             const std::vector<Pose2>&);
template MapPlot MakeMapPlot(const std::string&,
                             const PoseGraph<Pose3>&,
                             const std::vector<Pose3>&,
                             const std::vector<LoopDecision>&,
                             const std::vector<Pose3>&);

}  // namespace irrr
