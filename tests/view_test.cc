// irrr-view's live map in headless Chromium (Debian's chromium), against irrrd over UDP multicast
// inside a private network namespace (tools/netns-run runs the [udpm] cases).

#include <chrono>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include <catch2/catch.hpp>
#include <nlohmann/json.hpp>

#include "tests/processes.h"
#include "tests/test_files.h"

// After Eigen (through tests/processes.h): httplib.h brings <resolv.h>, whose _res macro breaks
// Eigen's headers.
#include <httplib.h>

namespace irrr {
namespace {

using Catch::Matchers::Contains;

// The map the page drew: its <svg id="map"> element.
std::string DrawnMap(const std::string& page) {
  const size_t begin = page.find("<svg id=\"map\"");
  const size_t end = page.find("</svg>", begin);
  return begin == std::string::npos || end == std::string::npos ? ""
                                                                : page.substr(begin, end - begin);
}

// Waits up to `seconds` for irrr-view's state (/state.json) to hold `sessions` sessions and more
// than `accepted` accepted loops, each drawn between poses it has: the page then shows it.
bool WaitForView(int port, size_t sessions, int accepted, int seconds) {
  httplib::Client client("127.0.0.1", port);
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(seconds);
  while (std::chrono::steady_clock::now() < deadline) {
    if (const auto res = client.Get("/state.json"); res && res->status == 200) {
      const nlohmann::json state = nlohmann::json::parse(res->body);
      int drawn = 0;
      for (const auto& loop : state["loops"]) drawn += loop["state"] == "accepted";
      if (state["sessions"].size() == sessions && drawn > accepted) return true;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  return false;
}

// irrr-view's event stream (/events) as a page receives it, until a map satisfies `done` or
// `seconds` pass: the maps received.
std::vector<nlohmann::json> ReadEvents(int port,
                                       const std::function<bool(const nlohmann::json&)>& done,
                                       int seconds) {
  httplib::Client client("127.0.0.1", port);
  client.set_read_timeout(seconds, 0);
  std::vector<nlohmann::json> maps;
  std::string pending;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(seconds);
  client.Get("/events", [&](const char* data, size_t size) {
    pending.append(data, size);
    // Events end with a blank line; a map's is "data: {json}", keep-alives are comments.
    for (size_t end = pending.find("\n\n"); end != std::string::npos; end = pending.find("\n\n")) {
      const std::string event = pending.substr(0, end);
      pending.erase(0, end + 2);
      if (event.rfind("data: ", 0) == 0) maps.push_back(nlohmann::json::parse(event.substr(6)));
    }
    return (maps.empty() || !done(maps.back())) && std::chrono::steady_clock::now() < deadline;
  });
  return maps;
}

// Chromium as the machine's notes say to run it here: headless, no sandbox (root), no GPU, and
// nothing of its own on the network. --virtual-time-budget lets the page's script run before
// --dump-dom prints the document (to the log, after what Chromium says on stderr).
std::string Chromium(const std::string& dir, const std::string& url) {
  return "chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
         "--disable-background-networking --disable-component-update --disable-sync "
         "--user-data-dir=" +
         Quoted(dir + "/chromium") + " --virtual-time-budget=30000 --dump-dom '" + url + "'";
}

TEST_CASE("udpm: the live map appears in headless Chromium, then updates as corrections arrive",
          "[.][udpm]") {
  REQUIRE(std::system("command -v chromium > /dev/null") == 0);  // tools/setup installs it
  const std::string dir = TestDirectory("view");
  const std::string config = dir + "/irrrd.json";
  WriteText(config,
            "{\"daemon\": {\"lcm_url\": \"udpm://239.255.76.67:7667?ttl=0&recv_buf_size=2097152\","
            " \"status_hz\": 5}, \"irrr\": {\"cluster_gap\": 10}}\n");
  const std::string first = dir + "/intel200.g2o";
  const std::string second = dir + "/intel150.g2o";
  WriteIntelPrefix(200, first);
  WriteIntelPrefix(150, second);

  auto daemon = StartDaemon(std::string(IRRRD) + " --config " + Quoted(config), dir + "/irrrd.log");
  Background view(std::string(IRRR_VIEW) + " --config " + Quoted(config) + " --port 18765",
                  dir + "/view.log");
  REQUIRE(WaitForText(dir + "/view.log", "the live map is on http://127.0.0.1:18765/", 10));
  const std::string inject =
      std::string(IRRR_INJECT) + " --config " + Quoted(config) + " --rate 0 --wait --timeout 120 ";
  REQUIRE(RunTool(inject + Quoted(first) + " --sender first", dir + "/inject1.log") == 0);
  // The injector waits for the daemon; the view hears it a moment later.
  REQUIRE(WaitForView(18765, 1, 50, 30));

  // The map appears: robot 0's session, its loops.
  REQUIRE(RunTool(Chromium(dir, "http://127.0.0.1:18765/?events=1"), dir + "/page1.html") == 0);
  const std::string page1 = ReadText(dir + "/page1.html");
  const std::string map1 = DrawnMap(page1);
  INFO(page1.substr(0, 3000));
  CHECK_THAT(page1, Contains("data-updates=\"1\""));
  CHECK(Occurrences(map1, "class=\"session\"") == 1);
  CHECK(Occurrences(map1, "class=\"loop accepted\"") > 50);
  CHECK_THAT(page1, Contains("1 session(s)"));

  // It updates: the event stream a page holds (open before robot 1 starts) brings robot 1's
  // session and its loops. The view sends one map per burst of messages, so the first map may
  // already hold them.
  const int accepted1 = Occurrences(map1, "class=\"loop accepted\"");
  const auto both_robots = [accepted1](const nlohmann::json& map) {
    return map["sessions"].size() == 2 && map["counts"]["accepted"] > accepted1;
  };
  std::vector<nlohmann::json> events;
  std::thread stream([&] { events = ReadEvents(18765, both_robots, 60); });
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (Occurrences(ReadText(dir + "/view.log"), "a page connected") < 2 &&
         std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  const bool connected = Occurrences(ReadText(dir + "/view.log"), "a page connected") == 2;
  const int injected = connected
                           ? RunTool(inject + Quoted(second) + " --first-robot 1 --sender second",
                                     dir + "/inject2.log")
                           : -1;
  stream.join();
  REQUIRE(connected);
  REQUIRE(injected == 0);
  REQUIRE_FALSE(events.empty());
  CHECK(events.front()["sessions"].size() >= 1);
  CHECK(both_robots(events.back()));

  // A page opened now draws both robots.
  REQUIRE(WaitForView(18765, 2, accepted1, 30));
  REQUIRE(RunTool(Chromium(dir, "http://127.0.0.1:18765/?events=1"), dir + "/page2.html") == 0);
  const std::string page2 = ReadText(dir + "/page2.html");
  const std::string map2 = DrawnMap(page2);
  INFO(page2.substr(0, 3000));
  CHECK(Occurrences(map2, "class=\"session\"") == 2);
  CHECK(Occurrences(map2, "class=\"loop accepted\"") > accepted1);
  CHECK_THAT(page2, Contains("2 session(s)"));
  CHECK(view.Stop(SIGINT) == 0);
  CHECK(daemon->Stop() == 0);
}

}  // namespace
}  // namespace irrr
