#ifndef IRRR_TESTS_TEST_FILES_H_
#define IRRR_TESTS_TEST_FILES_H_

// Files and tools for the tests that run the command-line programs. The including target defines
// IRRR_SOURCE_DIR (the project) and IRRR_TEST_OUTPUT_DIR (where tests may write).

#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include <catch2/catch.hpp>

#include "core/graph_io.h"

namespace irrr {

// A folder of its own for each test's files, beside the test binary.
inline std::string TestDirectory(const std::string& name) {
  const std::filesystem::path dir = std::filesystem::path(IRRR_TEST_OUTPUT_DIR) / name;
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir.string();
}

inline std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

inline void WriteText(const std::string& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  REQUIRE(out.good());
}

// Runs a shell command; returns its exit code. Output goes to `log`, which INFO shows on failure.
inline int RunTool(const std::string& command, const std::string& log) {
  const int status = std::system((command + " > '" + log + "' 2>&1").c_str());
  REQUIRE(WIFEXITED(status));
  return WEXITSTATUS(status);
}

// How many times `what` occurs in `text` (overlaps counted).
inline int Occurrences(const std::string& text, const std::string& what) {
  int n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

inline std::string Quoted(const std::string& path) { return "'" + path + "'"; }

// The first `num_poses` poses of the shipped Intel file and the edges among them.
inline void WriteIntelPrefix(int num_poses, const std::string& path) {
  std::ifstream in(IRRR_SOURCE_DIR "/data/intel.g2o");
  GraphFile<Pose2> intel;
  REQUIRE(ReadGraphFile(in, FileFormat::kG2o, ReadOptions(), &intel).ok());
  GraphFile<Pose2> prefix;
  for (const FileVertex<Pose2>& v : intel.vertices) {
    if (v.id < num_poses) prefix.vertices.push_back(v);
  }
  for (const FileEdge<Pose2>& e : intel.edges) {
    if (e.from < num_poses && e.to < num_poses) prefix.edges.push_back(e);
  }
  std::ofstream out(path);
  REQUIRE(WriteGraphFile(out, FileFormat::kG2o, prefix).ok());
}

#ifdef IRRR_CORRUPT
// A two-session Intel prefix of 400 poses (split at 200) with 30 wrong inter-session loops in
// groups of 3, made by irrr-corrupt (labels in dir/labels.csv).
inline std::string MakeTwoSessionIntel(const std::string& dir) {
  const std::string clean = dir + "/intel400.g2o";
  WriteIntelPrefix(400, clean);
  const std::string corrupted = dir + "/intel400_2sessions.g2o";
  const std::string log = dir + "/corrupt.log";
  const std::string command = std::string(IRRR_CORRUPT) + " " + Quoted(clean) + " " +
                              Quoted(corrupted) +
                              " --split 200 --mode inter-session --count 30 --group-size 3 "
                              "--seed 3 --labels " +
                              Quoted(dir + "/labels.csv");
  const int code = RunTool(command, log);
  INFO(command << "\n" << ReadText(log));
  REQUIRE(code == 0);
  return corrupted;
}
#endif

}  // namespace irrr

#endif  // IRRR_TESTS_TEST_FILES_H_
