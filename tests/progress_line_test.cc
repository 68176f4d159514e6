// The tools' progress line (clients/common/progress_line.h): drawn in place and rate-limited on
// a terminal, nothing at all otherwise; and irrr-batch end to end, on a terminal (a pseudo-terminal
// made by script(1)) and not, with the same standard output.

#include "clients/common/progress_line.h"

#include <chrono>
#include <cstdio>
#include <string>
#include <thread>

#include <catch2/catch.hpp>

#include "core/irrr.h"
#include "tests/synthetic_graph.h"
#include "tests/test_files.h"

namespace irrr {
namespace {

using Catch::Matchers::Contains;
using Catch::Matchers::StartsWith;

// What was written to `file` since it was opened (a tmpfile()).
std::string Written(std::FILE* file) {
  std::fflush(file);
  std::rewind(file);
  std::string text;
  char buffer[4096];
  while (const size_t n = std::fread(buffer, 1, sizeof buffer, file)) text.append(buffer, n);
  return text;
}

TEST_CASE("A progress line off a terminal writes nothing at all", "[progress]") {
  std::FILE* file = std::tmpfile();
  REQUIRE(file != nullptr);
  {
    ProgressLine line(file);  // a regular file is not a terminal
    CHECK_FALSE(line.enabled());
    CHECK_FALSE(line.Due());
    line.Update("working", /*force=*/true);
    line.Finish("done");
    line.Clear();
  }
  CHECK(Written(file).empty());
  std::fclose(file);
}

TEST_CASE("On a terminal the line is redrawn in place at most every 100 ms, then erased",
          "[progress]") {
  std::FILE* file = std::tmpfile();
  REQUIRE(file != nullptr);
  {
    ProgressLine line(file, /*enabled=*/true);
    CHECK(line.Due());
    line.Update("first");
    CHECK_FALSE(line.Due());
    line.Update("skipped");  // within kRedrawPeriod of the first
    line.Update("forced", /*force=*/true);
    std::this_thread::sleep_for(ProgressLine::kRedrawPeriod + std::chrono::milliseconds(20));
    CHECK(line.Due());
    line.Update("later");
  }  // the destructor erases the line
  const std::string text = Written(file);
  CHECK(text == "\rfirst\033[K\rforced\033[K\rlater\033[K\r\033[K");
  CHECK(Occurrences(text, "skipped") == 0);
  std::fclose(file);
}

TEST_CASE("Finish leaves the last text on a line of its own", "[progress]") {
  std::FILE* file = std::tmpfile();
  REQUIRE(file != nullptr);
  {
    ProgressLine line(file, /*enabled=*/true);
    line.Update("half");
    line.Finish("all");
  }  // nothing left to erase
  CHECK(Written(file) == "\rhalf\033[K\rall\033[K\n");
  std::fclose(file);
}

TEST_CASE("Bars and elapsed times read as people expect", "[progress]") {
  CHECK(ProgressBar(0, 10, 10) == "[..........]");
  CHECK(ProgressBar(5, 10, 10) == "[#####.....]");
  CHECK(ProgressBar(10, 10, 4) == "[####]");
  CHECK(ProgressBar(12, 10, 4) == "[####]");  // more than the total: full, not past it
  CHECK(ProgressBar(0, 0, 3) == "[###]");
  CHECK(FormatElapsed(0.04) == "0.0 s");
  CHECK(FormatElapsed(12.34) == "12.3 s");
  CHECK(FormatElapsed(245.9) == "4 min 05 s");
}

TEST_CASE("A replay's progress counts poses, hypotheses, steps and decisions so far",
          "[progress]") {
  testing::SyntheticOptions options;
  options.num_poses = 120;
  const auto world = testing::MakeSyntheticGraph<Pose2>(options);
  const PoseGraph<Pose2>& graph = world.graph;
  const int loops = static_cast<int>(world.loop_edges.size());
  REQUIRE(loops > 0);
  IrrrOptions irrr_options;
  irrr_options.cluster_gap = 5.0;
  Irrr<Pose2> irrr(irrr_options);
  GraphReplay<Pose2> replay(graph, &irrr);
  std::FILE* file = std::tmpfile();
  REQUIRE(file != nullptr);
  ProgressLine line(file, /*enabled=*/true);
  ReplayProgress<Pose2> progress(graph, "iRRR", &line);
  CHECK_THAT(progress.Text(irrr),
             StartsWith(fmt::format("iRRR: pose 0/120, 0/{} hypotheses, 0 steps, 0 accepted, "
                                    "0 rejected, ",
                                    loops)));
  for (const ArrivalEvent& event : ArrivalOrder(graph)) {
    replay.Apply(event);
    progress.Fed(event);
    while (irrr.HasPendingStep()) irrr.RunStep();
  }
  irrr.Flush();
  while (irrr.HasPendingStep()) irrr.RunStep();
  int accepted = 0;
  for (const LoopDecision& d : replay.Decisions()) {
    accepted += d.state == LoopState::kAccepted ? 1 : 0;
  }
  CHECK(accepted > 0);
  CHECK_THAT(progress.Text(irrr),
             StartsWith(fmt::format("iRRR: pose 120/120, {}/{} hypotheses, {} steps, {} accepted, ",
                                    loops,
                                    loops,
                                    irrr.num_steps(),
                                    accepted)));
  progress.Show(irrr);
  line.Clear();
  CHECK_THAT(Written(file), Contains("iRRR: pose 120/120"));
  std::fclose(file);
}

TEST_CASE("irrr-batch shows progress on a terminal only, and prints the same results either way",
          "[progress][tools]") {
  const std::string dir = TestDirectory("progress");
  // Intel's first 300 poses keep the run short (it runs twice, and instrumented under the
  // sanitizers).
  const std::string input = dir + "/intel300.g2o";
  WriteIntelPrefix(300, input);
  const std::string command =
      std::string(IRRR_BATCH) + " " + input + " --method irrr --cluster-gap 10";
  // Not a terminal: stderr stays empty.
  const std::string out = dir + "/out.txt";
  const std::string err = dir + "/err.txt";
  REQUIRE(std::system((command + " > '" + out + "' 2> '" + err + "'").c_str()) == 0);
  CHECK(ReadText(err).empty());
  const std::string plain = ReadText(out);
  CHECK_THAT(plain, Contains("decide    irrr:"));

  // On a terminal (script(1) runs it on a pseudo-terminal and copies what it shows).
  const std::string shown = dir + "/terminal.txt";
  const std::string on_terminal =
      "script -qec " + Quoted(command) + " /dev/null > '" + shown + "' 2>&1";
  REQUIRE(std::system(on_terminal.c_str()) == 0);
  const std::string terminal = ReadText(shown);
  CHECK_THAT(terminal, Contains("\riRRR: pose "));
  CHECK_THAT(terminal, Contains(" hypotheses, "));
  CHECK_THAT(terminal, Contains(" steps, "));
  // The results: the same lines (the terminal ends lines with \r\n; time figures differ).
  CHECK_THAT(terminal, Contains("input     " + input));
  CHECK_THAT(terminal, Contains("decide    irrr:"));
}

}  // namespace
}  // namespace irrr
