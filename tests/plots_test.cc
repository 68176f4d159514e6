// The plots (clients/common/plots.h): well-formed SVG with one path per session and one line per
// loop of each kind, for SE(2) and SE(3) graphs, and irrr-plot / irrr-batch --plot end to end.

#include "clients/common/plots.h"

#include <cctype>
#include <regex>
#include <string>
#include <vector>

#include <catch2/catch.hpp>

#include "tests/synthetic_graph.h"
#include "tests/test_files.h"

namespace irrr {
namespace {

using testing::MakeSyntheticGraph;
using testing::SyntheticOptions;

// A small XML well-formedness check: every tag closed in order, attributes quoted, one root,
// text without a bare '<' or '&'. Returns "" or what is wrong.
std::string XmlProblem(const std::string& xml) {
  std::vector<std::string> open;
  size_t at = 0;
  int roots = 0;
  if (xml.compare(0, 5, "<?xml") == 0) at = xml.find("?>") + 2;
  while (at < xml.size()) {
    const size_t lt = xml.find('<', at);
    const std::string text = xml.substr(at, lt == std::string::npos ? std::string::npos : lt - at);
    for (size_t k = 0; k < text.size(); ++k) {
      if (text[k] == '&' &&
          !std::regex_search(text.substr(k), std::regex("^&(amp|lt|gt|quot|apos);"))) {
        return "a bare '&' in text";
      }
    }
    if (lt == std::string::npos) break;
    const size_t gt = xml.find('>', lt);
    if (gt == std::string::npos) return "a tag never closed";
    const std::string tag = xml.substr(lt + 1, gt - lt - 1);
    at = gt + 1;
    if (tag.empty()) return "an empty tag";
    if (tag[0] == '/') {
      if (open.empty() || open.back() != tag.substr(1)) return "</" + tag.substr(1) + "> unmatched";
      open.pop_back();
      continue;
    }
    static const std::regex element(R"(^([A-Za-z][\w:-]*)(\s+[\w:-]+="[^"<]*")*\s*(/?)$)");
    std::smatch m;
    if (!std::regex_match(tag, m, element)) return "a malformed tag: <" + tag + ">";
    if (open.empty()) ++roots;
    if (m[3].str().empty()) open.push_back(m[1]);
  }
  if (!open.empty()) return "<" + open.back() + "> never closed";
  return roots == 1 ? "" : "not one root element";
}

TEST_CASE("The well-formedness check itself tells good XML from bad", "[plots]") {
  CHECK(XmlProblem(R"(<svg a="1"><g><line x="2"/></g><text>a &amp; b</text></svg>)").empty());
  CHECK(!XmlProblem(R"(<svg><g></svg>)").empty());
  CHECK(!XmlProblem(R"(<svg a=1></svg>)").empty());
  CHECK(!XmlProblem(R"(<svg><text>a & b</text></svg>)").empty());
  CHECK(!XmlProblem(R"(<svg></svg><svg></svg>)").empty());
}

// Every other loop accepted, every third of the rest rejected, the others reversed.
template <class Pose>
std::vector<LoopDecision> SomeDecisions(const PoseGraph<Pose>& graph, int counts[3]) {
  std::vector<LoopDecision> decisions(graph.num_edges());
  int k = 0;
  for (int e = 0; e < graph.num_edges(); ++e) {
    if (graph.edge(e).kind != EdgeKind::kLoop) continue;
    const LoopState state = k % 2 == 0   ? LoopState::kAccepted
                            : k % 3 == 0 ? LoopState::kRejectedJointTest
                                         : LoopState::kReversed;
    decisions[e].state = state;
    ++counts[state == LoopState::kAccepted ? 0 : state == LoopState::kReversed ? 2 : 1];
    ++k;
  }
  return decisions;
}

TEMPLATE_TEST_CASE(
    "Each plot kind is well-formed SVG with one path per session and one line per "
    "loop of each kind",
    "[plots]",
    Pose2,
    Pose3) {
  SyntheticOptions options;
  options.num_poses = 120;
  options.num_sessions = 3;
  options.seed = 4;
  const auto synthetic = MakeSyntheticGraph<TestType>(options);
  const PoseGraph<TestType>& graph = synthetic.graph;
  int counts[3] = {0, 0, 0};  // accepted, rejected, reversed
  const std::vector<LoopDecision> decisions = SomeDecisions(graph, counts);
  REQUIRE(counts[0] > 0);
  REQUIRE(counts[1] > 0);
  REQUIRE(counts[2] > 0);
  // 3D maps have two views (top and side): everything twice.
  const int views = TestType::kTranslationDim == 3 ? 2 : 1;

  const MapPlot map = MakeMapPlot<TestType>(
      "a <map> & more", graph, synthetic.ground_truth, decisions, synthetic.ground_truth);
  const std::string svg = MapSvg(map);
  INFO(svg.substr(0, 2000));
  CHECK(XmlProblem(svg).empty());
  CHECK(Occurrences(svg, "class=\"session\"") == views * 3);
  CHECK(Occurrences(svg, "class=\"ground-truth\"") == views * 3);
  CHECK(Occurrences(svg, "class=\"loop accepted\"") == views * counts[0]);
  CHECK(Occurrences(svg, "class=\"loop rejected\"") == views * counts[1]);
  CHECK(Occurrences(svg, "class=\"loop reversed\"") == views * counts[2]);
  CHECK(Occurrences(svg, "class=\"loop pending\"") == 0);
  CHECK(Occurrences(svg, "class=\"legend\"") == 1);
  CHECK_THAT(svg, Catch::Contains("accepted loops (" + std::to_string(counts[0]) + ")"));
  CHECK_THAT(svg, Catch::Contains("a &lt;map&gt; &amp; more"));
  if (views == 2) CHECK_THAT(svg, Catch::Contains("side view (x-z)"));

  const MapPlot before =
      MakeMapPlot<TestType>("initial guess", graph, graph.initial_estimate(), {}, {});
  const std::string both = BeforeAfterSvg(before, map);
  CHECK(XmlProblem(both).empty());
  CHECK(Occurrences(both, "class=\"session\"") == 2 * 3);  // top views, before and after
  CHECK(Occurrences(both, "class=\"loop pending\"") == counts[0] + counts[1] + counts[2]);
  CHECK(Occurrences(both, "class=\"loop accepted\"") == counts[0]);

  const std::vector<double> step_ms = {1.5, 20.0, 3.0, 400.0};
  const std::string steps = StepTimeSvg("steps", step_ms);
  CHECK(XmlProblem(steps).empty());
  CHECK(Occurrences(steps, "class=\"step\"") == 4);
  CHECK(Occurrences(steps, "class=\"step-time\"") == 1);

  const std::vector<double> errors = {0.1, 0.2, 0.2, 0.9};
  const std::string ate = AteSvg("ate", errors);
  CHECK(XmlProblem(ate).empty());
  CHECK(Occurrences(ate, "class=\"bar\"") == 20);
  CHECK_THAT(ate, Catch::Contains("max 0.900 m (4 poses)"));
}

TEST_CASE("irrr-batch --plot and irrr-plot write every plot kind of a decided file",
          "[plots][tools]") {
  const std::string dir = TestDirectory("plots");
  const std::string input = dir + "/intel200.g2o";
  WriteIntelPrefix(200, input);
  const std::string batch = std::string(IRRR_BATCH) + " " + Quoted(input) +
                            " --method irrr --cluster-gap 10 --decisions " +
                            Quoted(dir + "/decisions.csv") + " --output " +
                            Quoted(dir + "/out.g2o") + " --ground-truth " + Quoted(input) +
                            " --plot " + Quoted(dir + "/batch.svg");
  REQUIRE(RunTool(batch, dir + "/batch.log") == 0);
  for (const char* name :
       {"batch.svg", "batch_before_after.svg", "batch_steps.svg", "batch_ate.svg"}) {
    INFO(name);
    const std::string svg = ReadText(dir + "/" + name);
    CHECK(XmlProblem(svg).empty());
  }
  const std::string map = ReadText(dir + "/batch.svg");
  CHECK(Occurrences(map, "class=\"session\"") == 1);
  CHECK(Occurrences(map, "class=\"loop accepted\"") > 0);

  WriteText(dir + "/steps.csv", "step,ms\n0,1.5\n1,2.5\n2,30\n");
  const std::string plot = std::string(IRRR_PLOT) + " " + Quoted(input) + " --decisions " +
                           Quoted(dir + "/decisions.csv") + " --optimized " +
                           Quoted(dir + "/out.g2o") + " --steps " + Quoted(dir + "/steps.csv") +
                           " --out " + Quoted(dir + "/plot.svg");
  REQUIRE(RunTool(plot, dir + "/plot.log") == 0);
  // Same decisions, same map: the same loop lines as irrr-batch drew.
  const std::string again = ReadText(dir + "/plot.svg");
  CHECK(Occurrences(again, "class=\"loop accepted\"") ==
        Occurrences(map, "class=\"loop accepted\""));
  CHECK(Occurrences(again, "class=\"loop rejected\"") ==
        Occurrences(map, "class=\"loop rejected\""));
  CHECK(Occurrences(ReadText(dir + "/plot_steps.svg"), "class=\"step\"") == 3);
  CHECK(RunTool(std::string(IRRR_PLOT) + " " + Quoted(input) + " --steps " +
                    Quoted(dir + "/none.csv") + " --out " + Quoted(dir + "/x.svg"),
                dir + "/bad.log") == 65);
}

TEST_CASE("irrr-plot --chart draws each --y column of a CSV against --x", "[plots][tools]") {
  const std::string dir = TestDirectory("plots_chart");
  WriteText(dir + "/samples.csv",
            "seconds,poses,rss_mb,cpu_s\n1,0,12,0.1\n2,500,20,0.9\n3,1000,-2,2\n");
  const std::string chart = std::string(IRRR_PLOT) + " --chart " + Quoted(dir + "/samples.csv") +
                            " --x poses --y rss_mb --y cpu_s --title memory --out " +
                            Quoted(dir + "/chart.svg");
  REQUIRE(RunTool(chart, dir + "/chart.log") == 0);
  const std::string svg = ReadText(dir + "/chart.svg");
  CHECK(XmlProblem(svg).empty());
  CHECK(Occurrences(svg, "class=\"point\"") == 6);   // 3 rows x 2 columns
  CHECK(Occurrences(svg, "class=\"legend\"") == 4);  // a name and a dot per column
  CHECK_THAT(svg, Catch::Contains(">rss_mb<") && Catch::Contains(">cpu_s<"));
  // The negative value lowers the axis: its label reads -2.
  CHECK_THAT(svg, Catch::Contains(">-2<"));
  // A column that is not there, and --chart without --y.
  CHECK(RunTool(std::string(IRRR_PLOT) + " --chart " + Quoted(dir + "/samples.csv") +
                    " --x poses --y memory --out " + Quoted(dir + "/x.svg"),
                dir + "/bad.log") == 65);
  CHECK_THAT(ReadText(dir + "/bad.log"), Catch::Contains("no \"memory\" column"));
  CHECK(RunTool(std::string(IRRR_PLOT) + " --chart " + Quoted(dir + "/samples.csv") +
                    " --x poses --out " + Quoted(dir + "/x.svg"),
                dir + "/usage.log") == 64);
}

}  // namespace
}  // namespace irrr
