// The seed of fuzz_snapshot: the body it reads for its two-session graph (two_sessions.h) after
// the graph's steps: an options text, a record count, anchors, the SE(2) and the SE(3) Irrr's step
// states, then their inputs as a base holds them (daemon/snapshot.h). The same bytes on every run,
// so that a check can tell when the snapshot format has changed under the committed seed.
//
//   make_snapshot_seeds FILE           writes it
//   make_snapshot_seeds --check FILE   exit 1 if FILE holds other bytes

#include <cstdio>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "core/irrr.h"
#include "daemon/snapshot.h"
#include "tests/fuzz/two_sessions.h"

namespace irrr {
namespace {

template <class Pose>
void Run(Irrr<Pose>* irrr) {
  fuzz::FeedTwoSessions(irrr);
  while (irrr->HasPendingStep()) irrr->RunStep();
}

std::vector<uint8_t> Seed() {
  Irrr<Pose2> se2(fuzz::TwoSessionsOptions());
  Irrr<Pose3> se3(fuzz::TwoSessionsOptions());
  Run(&se2);
  Run(&se3);
  SnapshotWriter w;
  w.String("two sessions");
  w.I64(0);
  w.Ints({0, 1});
  w.StepState(se2.StepState());
  w.StepState(se3.StepState());
  w.Inputs(se2);
  w.Inputs(se3);
  return w.bytes();
}

}  // namespace
}  // namespace irrr

int main(int argc, char** argv) {
  const bool check = argc == 3 && std::string(argv[1]) == "--check";
  if (argc != 2 && !check) {
    std::fprintf(stderr, "usage: %s [--check] FILE\n", argv[0]);
    return 64;
  }
  const std::string path = argv[argc - 1];
  const std::vector<uint8_t> seed = irrr::Seed();
  if (check) {
    std::ifstream in(path, std::ios::binary);
    const std::vector<uint8_t> committed{std::istreambuf_iterator<char>(in),
                                         std::istreambuf_iterator<char>()};
    if (committed == seed) return 0;
    std::fprintf(stderr,
                 "%s: not the seed of the current snapshot format; regenerate it (cmake --build "
                 "build-fuzz --target fuzz_snapshot_seeds) and commit it\n",
                 path.c_str());
    return 1;
  }
  std::ofstream file(path, std::ios::binary);
  file.write(reinterpret_cast<const char*>(seed.data()), static_cast<std::streamsize>(seed.size()));
  if (!file.flush()) {
    std::fprintf(stderr, "%s: cannot write\n", path.c_str());
    return 1;
  }
  std::printf("%s: %zu bytes\n", path.c_str(), seed.size());
  return 0;
}
