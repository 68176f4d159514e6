// The seed corpus of fuzz_daemon_input, from pose-graph files: for each file, one input holding
// the messages a front end would send for it (clients/common/replay_messages.h: keyframes, loop
// hypotheses and session ENDs in arrival order), then a PROGRESS, a FLUSH and a solution request,
// each applied as it arrives; one sender (MessageSequencer: seq from 0 over all channels), fixed
// utimes. The same bytes on every run, so that a check can tell when the message types (or the
// headers a sender writes) have changed under the committed seeds.
//
//   make_daemon_seeds OUT_DIR GRAPH_FILE...          writes OUT_DIR/<file name>.bin
//   make_daemon_seeds --check SEED_DIR GRAPH_FILE... exit 1 if a seed differs from those bytes

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <utility>
#include <vector>

#include "clients/common/graph_files.h"
#include "clients/common/replay_messages.h"
#include "core/graph_io.h"
#include "core/pose.h"
#include "daemon/common/irrr_config.h"
#include "daemon/wire.h"
#include "irrr/solution_request_t.hpp"
#include "tests/fuzz/daemon_records.h"

namespace irrr {
namespace {

constexpr int64_t kFirstUtime = 1700000000000000;  // 2023-11-14, any fixed time will do

template <class Pose>
Status SeedOf(const std::string& path, FileFormat format, std::vector<uint8_t>* seed) {
  GraphFile<Pose> file;
  PoseGraph<Pose> graph;
  std::vector<int> graph_edge_of_file_edge;
  if (Status s =
          LoadPoseGraph(path, format, ReadOptions(), &file, &graph, &graph_edge_of_file_edge);
      !s.ok()) {
    return s;
  }
  const DaemonChannels channels;
  MessageSequencer sender("fuzz/front-end", channels);
  std::vector<uint8_t> bytes;
  auto append = [&](const MessageSequencer::Encoded& encoded) {
    fuzz::AppendRecord(fuzz::ChannelIndex(channels, encoded.first), true, encoded.second, &bytes);
  };
  auto utime = [&] { return kFirstUtime + 1000 * (sender.last_seq() + 1); };
  for (ReplayMessage& m : ReplayMessages(graph, graph_edge_of_file_edge, 0)) {
    append(sender.Encode(std::move(m), utime()));
  }
  append(sender.Progress(0, 0, utime()));
  append(sender.Encode(FlushMessage(), utime()));
  // A listener asks for the whole solution.
  solution_request_t request{};
  request.header.utime = utime();
  request.header.sender = "fuzz/listener";
  request.reason = "fuzz seed";
  append({channels.solution_request, EncodeMessage(request)});
  *seed = std::move(bytes);
  return Status::Ok();
}

Status Seed(const std::string& path, std::vector<uint8_t>* seed) {
  FileFormat format = FileFormat::kG2o;
  int dimension = 0;
  if (Status s = InspectGraphFile(path, &format, &dimension); !s.ok()) return s;
  return dimension == 2 ? SeedOf<Pose2>(path, format, seed) : SeedOf<Pose3>(path, format, seed);
}

std::vector<uint8_t> ReadBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  const bool check = argc > 1 && std::string(argv[1]) == "--check";
  const int first = check ? 2 : 1;
  if (argc < first + 2) {
    std::fprintf(stderr,
                 "usage: %s [--check] DIR GRAPH_FILE...\n"
                 "  writes (or, with --check, compares with) DIR/<file name>.bin for each file\n",
                 argv[0]);
    return 64;
  }
  const fs::path dir = argv[first];
  int stale = 0;
  for (int k = first + 1; k < argc; ++k) {
    std::vector<uint8_t> seed;
    if (irrr::Status s = irrr::Seed(argv[k], &seed); !s.ok()) {
      std::fprintf(stderr, "%s\n", s.message().c_str());
      return 1;
    }
    const fs::path out = dir / fs::path(argv[k]).filename().replace_extension(".bin");
    if (check) {
      if (irrr::ReadBytes(out) != seed) {
        std::fprintf(
            stderr, "%s: not the seed of %s for the current message types\n", out.c_str(), argv[k]);
        ++stale;
      }
      continue;
    }
    std::ofstream file(out, std::ios::binary);
    file.write(reinterpret_cast<const char*>(seed.data()),
               static_cast<std::streamsize>(seed.size()));
    if (!file.flush()) {
      std::fprintf(stderr, "%s: cannot write\n", out.c_str());
      return 1;
    }
    std::printf("%s: %zu bytes\n", out.c_str(), seed.size());
  }
  if (stale > 0) {
    std::fprintf(stderr,
                 "regenerate them (cmake --build build-fuzz --target fuzz_daemon_seeds) and commit "
                 "them\n");
    return 1;
  }
  return 0;
}
