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

}  // namespace irrr

#endif  // IRRR_TESTS_TEST_FILES_H_
